//! The CSV contracts of the command line: input sequences (`X,Y,Z,Mz`, one row per held
//! sample interval) in, trajectories (`t,x,y,z,psi,u,v,w,r`) out.

use crate::{INPUT_NAMES, Input, NU, SIM_STATE_NAMES, SimState};
use std::io::{Read, Write};

/// What is wrong with an input CSV; every variant names the line (1-based, header = 1).
#[derive(Debug, thiserror::Error)]
pub enum CsvError {
    /// The file has no header line.
    #[error("empty file: expected a header line X,Y,Z,Mz")]
    Empty,
    /// The header lacks a required column.
    #[error("line 1: missing column {0:?} (header must name X,Y,Z,Mz)")]
    MissingColumn(&'static str),
    /// The header names a column twice.
    #[error("line 1: column {0:?} appears twice")]
    DuplicateColumn(String),
    /// A row has a different number of fields from the header.
    #[error("line {line}: {found} fields, header has {expected}")]
    FieldCount {
        /// Line number.
        line: u64,
        /// Fields in the header.
        expected: usize,
        /// Fields on this line.
        found: usize,
    },
    /// A field is not a number.
    #[error("line {line}: column {column}: {text:?} is not a number")]
    NotANumber {
        /// Line number.
        line: u64,
        /// Column name.
        column: &'static str,
        /// The offending text.
        text: String,
    },
    /// A field is NaN or infinite.
    #[error("line {line}: column {column}: {value} is not finite")]
    NonFinite {
        /// Line number.
        line: u64,
        /// Column name.
        column: &'static str,
        /// The value read.
        value: f64,
    },
    /// The header is there but no data row follows.
    #[error("no input rows after the header")]
    NoRows,
    /// The reader failed or the bytes are not UTF-8 CSV.
    #[error("line {line}: {message}")]
    Malformed {
        /// Line number (0 if unknown).
        line: u64,
        /// The parser's message.
        message: String,
    },
}

/// Reads an input sequence with header `X,Y,Z,Mz` (any order; other columns ignored).
pub fn read_inputs(reader: impl Read) -> Result<Vec<Input>, CsvError> {
    let mut rdr = csv::ReaderBuilder::new().trim(csv::Trim::All).flexible(true).from_reader(reader);
    let malformed =
        |e: csv::Error| CsvError::Malformed { line: e.position().map_or(0, |p| p.line()), message: e.to_string() };
    let header = rdr.headers().map_err(malformed)?.clone();
    if header.is_empty() || header.iter().all(str::is_empty) {
        return Err(CsvError::Empty);
    }
    let mut columns = [0usize; NU];
    for (c, name) in INPUT_NAMES.iter().enumerate() {
        let mut hits = header.iter().enumerate().filter(|(_, h)| h == name);
        columns[c] = hits.next().ok_or(CsvError::MissingColumn(name))?.0;
        if hits.next().is_some() {
            return Err(CsvError::DuplicateColumn(name.to_string()));
        }
    }
    let mut out = Vec::new();
    for record in rdr.records() {
        let record = record.map_err(malformed)?;
        let line = record.position().map_or(0, |p| p.line());
        if record.len() != header.len() {
            return Err(CsvError::FieldCount { line, expected: header.len(), found: record.len() });
        }
        let mut u = Input::zeros();
        for (c, &col) in columns.iter().enumerate() {
            let text = &record[col];
            let column = INPUT_NAMES[c];
            let value: f64 = text.parse().map_err(|_| CsvError::NotANumber { line, column, text: text.to_string() })?;
            if !value.is_finite() {
                return Err(CsvError::NonFinite { line, column, value });
            }
            u[c] = value;
        }
        out.push(u);
    }
    if out.is_empty() {
        return Err(CsvError::NoRows);
    }
    Ok(out)
}

/// Writes `t,x,y,z,psi,u,v,w,r` rows, `t = k dt`, with shortest round-trip float formatting.
pub fn write_trajectory(mut w: impl Write, dt: f64, states: &[SimState]) -> std::io::Result<()> {
    writeln!(w, "t,{}", SIM_STATE_NAMES.join(","))?;
    for (k, s) in states.iter().enumerate() {
        write!(w, "{}", k as f64 * dt)?;
        for v in s.iter() {
            write!(w, ",{v}")?;
        }
        writeln!(w)?;
    }
    w.flush()
}

/// Writes a recorded run for `pinc dataset import`: `t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz`, each
/// row's input the one held until the next row; the last state has no input after it, so
/// its input fields are empty (the import counts that row as skipped).
pub fn write_record(mut w: impl Write, dt: f64, states: &[SimState], inputs: &[Input]) -> std::io::Result<()> {
    writeln!(w, "t,{},{}", SIM_STATE_NAMES.join(","), INPUT_NAMES.join(","))?;
    for (k, s) in states.iter().enumerate() {
        write!(w, "{}", k as f64 * dt)?;
        for v in s.iter() {
            write!(w, ",{v}")?;
        }
        match inputs.get(k) {
            Some(u) => u.iter().try_for_each(|v| write!(w, ",{v}"))?,
            None => write!(w, ",,,,")?,
        }
        writeln!(w)?;
    }
    w.flush()
}

/// Writes an input sequence `X,Y,Z,Mz`, one row per sample interval.
pub fn write_inputs(mut w: impl Write, inputs: &[Input]) -> std::io::Result<()> {
    writeln!(w, "{}", INPUT_NAMES.join(","))?;
    for u in inputs {
        writeln!(w, "{},{},{},{}", u[0], u[1], u[2], u[3])?;
    }
    w.flush()
}

/// Parses a comma-separated state `x,y,z,psi,u,v,w,r` (all finite).
pub fn parse_sim_state(text: &str) -> Result<SimState, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != SIM_STATE_NAMES.len() {
        return Err(format!("expected 8 comma-separated values x,y,z,psi,u,v,w,r, got {}", parts.len()));
    }
    let mut s = SimState::zeros();
    for (i, p) in parts.iter().enumerate() {
        let v: f64 = p.parse().map_err(|_| format!("{}: {p:?} is not a number", SIM_STATE_NAMES[i]))?;
        if !v.is_finite() {
            return Err(format!("{}: {v} is not finite", SIM_STATE_NAMES[i]));
        }
        s[i] = v;
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn read_inputs_accepts_reordered_and_extra_columns() {
        let u = read_inputs("t, Mz ,X,Z,Y\n0,4,1,3,2\n".as_bytes()).unwrap();
        assert_eq!(u, vec![Input::new(1.0, 2.0, 3.0, 4.0)]);
    }
}
