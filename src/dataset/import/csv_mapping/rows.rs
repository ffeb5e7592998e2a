//! The rows read: the file opened as the mapping's CSV dialect, every row's planned columns
//! parsed and converted into the streams. Apart because it is the only part that touches the
//! file after its header.

use super::line_of;
use super::mapping::{CsvMapping, VelocityAxes};
use super::plan::{Heading, InputPlan, Plan};
use crate::dataset::import::csv_rows::{next_row, parse_field};
use crate::dataset::import::{CommandsToInput, ImportError, Series, StreamSet};
use std::path::Path;

/// The series a file fills, one per section its plan reads.
pub(super) struct Streams {
    pub(super) position: Option<Series<3>>,
    pub(super) attitude: Option<Series<3>>,
    pub(super) velocity: Option<Series<3>>,
    pub(super) yaw_rate: Option<Series<1>>,
    pub(super) input: Option<Series<4>>,
    /// A row's thruster commands by channel (NaN on channels the mapping does not name).
    commands: Vec<f64>,
}

impl Streams {
    /// Empty series named after their columns.
    pub(super) fn new(plan: &Plan) -> Self {
        Self {
            position: plan.position.as_ref().map(|p| Series::new(p.source.clone())),
            attitude: plan.heading.as_ref().map(|h| {
                Series::new(match h {
                    Heading::Yaw { slot, .. } => plan.cols.name[*slot].clone(),
                    Heading::Quaternion { columns, .. } => columns.clone(),
                })
            }),
            velocity: plan.velocity.as_ref().map(|v| Series::new(v.source.clone())),
            yaw_rate: plan.yaw_rate.as_ref().map(|y| Series::new(y.source.clone())),
            input: plan.input.as_ref().map(|i| Series::new(i.1.clone())),
            commands: vec![
                f64::NAN;
                plan.input.as_ref().map_or(0, |i| match &i.0 {
                    InputPlan::Thrusters { n_channels, .. } => *n_channels,
                    InputPlan::Wrench { .. } => 0,
                })
            ],
        }
    }

    /// Appends one row, each quantity converted as the plan says.
    ///
    /// # Errors
    /// A quaternion off unit length.
    pub(super) fn push(
        &mut self,
        plan: &Plan,
        vals: &[f64],
        record: &csv::ByteRecord,
        row: usize,
        commands_to_input: Option<CommandsToInput<'_>>,
    ) -> Result<(), String> {
        let t = plan.time.at(vals, row);
        if let (Some(p), Some(series)) = (&plan.position, &mut self.position) {
            series.push(t, p.of(vals));
        }
        if let (Some(h), Some(series)) = (&plan.heading, &mut self.attitude) {
            series.push(t, h.attitude(vals, record, row)?);
        }
        if let (Some(v), Some(series)) = (&plan.velocity, &mut self.velocity) {
            series.push(t, v.of(vals));
        }
        if let (Some(y), Some(series)) = (&plan.yaw_rate, &mut self.yaw_rate) {
            series.push(t, [vals[y.slot] * y.scale]);
        }
        if let (Some((i, _)), Some(series)) = (&plan.input, &mut self.input) {
            series.push(t, i.of(vals, &mut self.commands, commands_to_input));
        }
        Ok(())
    }
}

/// Opens the file as the mapping's CSV dialect and reads its header.
pub(super) fn open(
    path: &Path,
    mapping: &CsvMapping,
) -> Result<(csv::Reader<std::fs::File>, Vec<String>), ImportError> {
    let file = std::fs::File::open(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let delimiter = mapping.delimiter.as_deref().map_or(b',', |d| d.as_bytes()[0]);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .delimiter(delimiter)
        .trim(csv::Trim::Headers)
        .buffer_capacity(1 << 16)
        .from_reader(file);
    let header: Vec<String> = reader
        .headers()
        .map_err(|e| ImportError::Malformed { path: path.to_path_buf(), message: format!("line 1: {e}") })?
        .iter()
        .map(str::to_string)
        .collect();
    Ok((reader, header))
}

/// Reads every row into `streams`, parsing only the plan's columns; returns the number of rows
/// and the note of a torn last line.
///
/// # Errors
/// A damaged row before the last line, a field that is not a number, a quaternion off unit
/// length.
pub(super) fn read_rows(
    reader: &mut csv::Reader<std::fs::File>,
    header: &[String],
    plan: &Plan,
    streams: &mut Streams,
    commands_to_input: Option<CommandsToInput<'_>>,
) -> Result<(usize, Option<String>), String> {
    let mut record = csv::ByteRecord::new();
    let mut vals = vec![0.0; plan.cols.index.len()];
    let mut row = 0usize;
    let mut torn: Option<String> = None;
    while next_row(reader, &mut record, header.len(), &mut torn)? {
        for (v, &idx) in vals.iter_mut().zip(&plan.cols.index) {
            let field = &record[idx];
            *v = parse_field(field).ok_or_else(|| {
                format!(
                    "line {}: column {}: {:?} is not a number",
                    line_of(&record),
                    header[idx],
                    String::from_utf8_lossy(field.trim_ascii())
                )
            })?;
        }
        streams.push(plan, &vals, &record, row, commands_to_input)?;
        row += 1;
    }
    Ok((row, torn))
}

impl Streams {
    /// The streams read through `plan`, with its notes, the row count (and a torn last line),
    /// as the reader returns them; velocities go to the body or the world stream by their axes.
    ///
    /// # Errors
    /// No row after the header.
    pub(super) fn finish(self, plan: Plan, rows: usize, torn: Option<String>) -> Result<StreamSet, String> {
        if rows == 0 {
            return Err("no rows after the header".into());
        }
        let mut notes = plan.notes;
        notes.push(format!("{rows} rows"));
        notes.extend(torn);
        let (mut velocity_body, mut velocity_ned) = (None, None);
        match plan.velocity.as_ref().map(|v| v.axes) {
            Some(VelocityAxes::BodyFrd | VelocityAxes::BodyFlu) => velocity_body = self.velocity,
            Some(VelocityAxes::WorldNed | VelocityAxes::WorldEnu) => velocity_ned = self.velocity,
            None => {}
        }
        Ok(StreamSet {
            position: self.position,
            depth: None,
            attitude: self.attitude,
            velocity_ned,
            velocity_body,
            yaw_rate: self.yaw_rate,
            input: self.input,
            notes,
        })
    }
}
