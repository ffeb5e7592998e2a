//! Recorded runs as CSV: header `t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz` (s, m, rad, m/s, rad/s, N,
//! N m), one row per sample, the inputs of a row held until the next row.

use super::csv_rows::{next_row, parse_field};
use super::{ImportError, Recording};
use crate::types::{Input, SimState};
use std::path::Path;

/// The required header, in order.
pub const CSV_COLUMNS: [&str; 13] = ["t", "x", "y", "z", "psi", "u", "v", "w", "r", "X", "Y", "Z", "Mz"];

/// Reads one run. An empty field or `nan` is kept as NaN (the windowing skips that row and
/// counts it); anything else that is not a number is an error naming the line and column.
///
/// A torn last line (fewer fields than the header: a logger cut off mid-write) is skipped and
/// noted; a damaged row anywhere else is an error.
///
/// # Errors
/// The file cannot be read, the header differs, a row before the last has the wrong number of
/// fields or a field is not a number.
pub fn read_csv(path: &Path) -> Result<Recording, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    let file = std::fs::File::open(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let mut reader =
        csv::ReaderBuilder::new().has_headers(true).trim(csv::Trim::Headers).buffer_capacity(1 << 16).from_reader(file);
    let header = reader.headers().map_err(|e| malformed(format!("line 1: {e}")))?.clone();
    if header.iter().ne(CSV_COLUMNS) {
        return Err(malformed(format!(
            "line 1: header must be {}, found {}",
            CSV_COLUMNS.join(","),
            header.iter().collect::<Vec<_>>().join(",")
        )));
    }
    let mut rec = Recording::empty(path);
    let mut record = csv::ByteRecord::new();
    let mut torn = None;
    while next_row(&mut reader, &mut record, CSV_COLUMNS.len(), &mut torn).map_err(malformed)? {
        let line = record.position().map_or(0, |p| p.line());
        let mut v = [0.0; 13];
        for (j, field) in record.iter().enumerate() {
            v[j] = parse_field(field).ok_or_else(|| {
                let field = String::from_utf8_lossy(field.trim_ascii());
                malformed(format!("line {line}: column {}: {field:?} is not a number", CSV_COLUMNS[j]))
            })?;
        }
        rec.t.push(v[0]);
        rec.states.push(SimState::from_column_slice(&v[1..9]));
        rec.inputs.push(Input::from_column_slice(&v[9..13]));
    }
    if rec.t.is_empty() {
        return Err(malformed("no rows after the header".into()));
    }
    rec.notes.extend(torn);
    Ok(rec)
}
