//! Any CSV log through a mapping file (TOML, docs/LOGS_CSV.md): which columns hold time,
//! position, heading, velocities, yaw rate and inputs, in which frames and units. The reader
//! converts everything to pinc's conventions (NED world, forward-right-down body, rad, s) and
//! returns the per-quantity streams.
//!
//! The stages, one module each: [`mapping`] the file's types and their checks (the TOML side),
//! [`resolve`] the mapping's columns found in one file's header, [`plan`] what each quantity
//! read becomes in pinc's frames ([`rotation`] the quaternion's part of it), [`rows`] the rows
//! read through the plan and the streams they filled returned. Each stage imports only those
//! before it.

mod mapping;
mod plan;
mod resolve;
mod rotation;
mod rows;

pub use mapping::{
    AngleUnit, CsvMapping, HeadingFrame, HeadingMapping, InputMapping, PositionMapping, QuaternionOrder, TimeMapping,
    TimeUnit, VelocityAxes, VelocityMapping, YawRateMapping,
};
pub use plan::QUATERNION_NORM_TOLERANCE;

use super::{CommandsToInput, ImportError, StreamSet};
use plan::Plan;
use rows::{Streams, open, read_rows};
use std::path::Path;

/// Reads and checks a mapping file.
///
/// # Errors
/// The file cannot be read, is not TOML, has a key the format does not know (named), a value
/// of the wrong kind, or an inconsistent section (see [`CsvMapping::check`]); one line, with
/// the line of the file where the TOML parser found the fault.
pub fn load_mapping(path: &Path) -> Result<CsvMapping, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    let text = std::fs::read_to_string(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let mapping: CsvMapping = toml::from_str(&text).map_err(|e: toml::de::Error| {
        let message = e.message().trim().replace('\n', " ");
        match e.span() {
            Some(span) => malformed(format!("line {}: {message}", text[..span.start].matches('\n').count() + 1)),
            None => malformed(message),
        }
    })?;
    mapping.check().map_err(malformed)?;
    Ok(mapping)
}

/// Reads one CSV file through `mapping`, converting every quantity to pinc's frames and units.
/// Only the columns the mapping names are parsed; an empty field or `nan` is a missing value
/// (NaN, skipped by the windowing). Thruster command columns go through `commands_to_input`
/// (commands by channel, index `c - 1` for channel `c`; channels the mapping does not name
/// are NaN); a row with a missing command gets a NaN input.
///
/// The stages: the mapping checked, the file opened and its header read, every column the
/// mapping names resolved against the header (`Plan`) before any row is read, the rows read
/// and converted, the streams returned with the notes.
///
/// # Errors
/// One line naming the file: the file cannot be read, a column the mapping names is not in
/// the header (the error lists the header), a row has the wrong number of fields, a field is
/// not a number (line and column), a quaternion is not of unit length within
/// [`QUATERNION_NORM_TOLERANCE`] (line and columns), thruster columns without a
/// `commands_to_input`, or no row after the header.
pub fn read_mapped_csv(
    path: &Path,
    mapping: &CsvMapping,
    commands_to_input: Option<CommandsToInput<'_>>,
) -> Result<StreamSet, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    mapping.check().map_err(|m| malformed(format!("mapping: {m}")))?;
    let (mut reader, header) = open(path, mapping)?;
    let plan = Plan::new(mapping, &header, commands_to_input.is_some()).map_err(malformed)?;
    let mut streams = Streams::new(&plan);
    let (rows, torn) = read_rows(&mut reader, &header, &plan, &mut streams, commands_to_input).map_err(malformed)?;
    streams.finish(plan, rows, torn).map_err(malformed)
}

/// The line of the file a record was read from.
fn line_of(record: &csv::ByteRecord) -> u64 {
    record.position().map_or(0, |p| p.line())
}
