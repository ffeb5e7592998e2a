//! What both CSV readers (pinc's own log format and any CSV by a mapping) share: a field as a
//! number, the message of a row the csv crate could not read, and reading the rows of a file
//! whose last line may be torn (a logger that lost power mid-write).

use std::io::Read;

/// A field as a number: empty or `nan` is NaN (a missing value), anything else not a number
/// is `None`.
#[inline]
pub(super) fn parse_field(field: &[u8]) -> Option<f64> {
    // Trimming here, on the fields read, is cheaper than the reader trimming every field.
    let field = field.trim_ascii();
    if field.is_empty() {
        return Some(f64::NAN);
    }
    // The standard parser (Eisel-Lemire with a slow-path fallback) is fast enough here: the
    // criterion bench `import_csv` measures it.
    std::str::from_utf8(field).ok()?.parse().ok()
}

/// `line N: what` for a row the csv crate could not read; a row with the wrong number of fields
/// (`width` expected) is a truncated or damaged one.
pub(super) fn row_error(e: &csv::Error, width: usize) -> String {
    let line = e.position().map_or(0, |p| p.line());
    match e.kind() {
        csv::ErrorKind::UnequalLengths { len, .. } => {
            format!("line {line}: {len} fields, the header has {width} (truncated or damaged row)")
        }
        _ => format!("line {line}: {e}"),
    }
}

/// Reads the next row into `record`: `Ok(true)` a row, `Ok(false)` the end. A row with the
/// wrong number of fields that is the file's last line is a torn last line, the normal end of
/// a log that lost power: it is skipped, the end reported, and `torn` says which line and what
/// it held. Anywhere else it is an error naming its line.
///
/// # Errors
/// A damaged row before the last line, or an unreadable file.
pub(super) fn next_row<R: Read>(
    reader: &mut csv::Reader<R>,
    record: &mut csv::ByteRecord,
    width: usize,
    torn: &mut Option<String>,
) -> Result<bool, String> {
    match reader.read_byte_record(record) {
        Ok(more) => Ok(more),
        Err(e) => {
            let is_short_row = matches!(e.kind(), csv::ErrorKind::UnequalLengths { .. });
            let mut after = csv::ByteRecord::new();
            if is_short_row && matches!(reader.read_byte_record(&mut after), Ok(false)) {
                *torn = Some(format!("{}: skipped, the file's last line", row_error(&e, width)));
                return Ok(false);
            }
            Err(row_error(&e, width))
        }
    }
}
