//! MCAP files cut off while they were written (the process killed, the power lost): the
//! whole records before the cut are read, and where the file ended is said.
//!
//! An MCAP file is its magic, then records each framed as an opcode byte and a little-endian
//! u64 length, and, when it was finished, a footer and the magic again. A file cut off has no
//! footer, and its last record (usually the chunk being written) runs past the end. The
//! framing alone finds the last whole record without decompressing anything; the reader is
//! then given the bytes up to it, told not to expect the closing magic.

use std::fmt;

/// The magic an MCAP file starts (and, finished, ends) with.
const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";
/// Opcode of the footer record.
const FOOTER: u8 = 0x02;

/// Where a cut-off file ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cut {
    /// Bytes of whole records read (the first byte of the record the cut went through).
    pub byte: u64,
    /// The file's length.
    pub length: u64,
    /// Log time (ns) of the last message read before the cut, once known.
    pub last_log_time: Option<u64>,
}

impl Cut {
    /// Notes a message read before the cut (its log time, ns): the last one is where it ended.
    pub fn saw(&mut self, log_time: u64) {
        self.last_log_time = Some(self.last_log_time.map_or(log_time, |t| t.max(log_time)));
    }
}

impl fmt::Display for Cut {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "the file was cut off: read up to byte {} of {}", self.byte, self.length)?;
        if let Some(t) = self.last_log_time {
            write!(f, ", the last whole record's message at log time {:.3} s", t as f64 * 1e-9)?;
        }
        write!(f, "; {} bytes of an unfinished record left out", self.length - self.byte)
    }
}

/// The part of `bytes` that an MCAP reader can read, and where the file was cut if it was:
/// the whole file when it is finished (a footer and the closing magic), else every whole
/// record up to the cut. `None` when `bytes` does not start as an MCAP file.
pub fn readable(bytes: &[u8]) -> Option<(&[u8], Option<Cut>)> {
    if !bytes.starts_with(MAGIC) {
        return None;
    }
    let mut at = MAGIC.len();
    while let Some(header) = bytes.get(at..at + 9) {
        let length = u64::from_le_bytes(header[1..9].try_into().expect("8 bytes"));
        let end = (at as u64 + 9).checked_add(length).filter(|&e| e <= bytes.len() as u64);
        let Some(end) = end else { break };
        if header[0] == FOOTER && bytes[end as usize..].starts_with(MAGIC) {
            return Some((bytes, None));
        }
        at = end as usize;
    }
    let cut = Cut { byte: at as u64, length: bytes.len() as u64, last_log_time: None };
    Some((&bytes[..at], Some(cut)))
}

/// The messages of an MCAP file, read up to its cut if it has one: the stream, and the cut
/// (its `last_log_time` is for the caller to fill from the messages it read).
///
/// # Errors
/// Not an MCAP file, or records the reader refuses before any cut.
pub fn message_stream(bytes: &[u8]) -> Result<(mcap::MessageStream<'_>, Option<Cut>), String> {
    let (part, cut) = readable(bytes).ok_or_else(|| "not an MCAP file (no MCAP magic at its start)".to_string())?;
    let stream = match cut {
        Some(_) => mcap::MessageStream::new_with_options(part, mcap::read::Options::IgnoreEndMagic.into()),
        None => mcap::MessageStream::new(part),
    }
    .map_err(|e| format!("not an MCAP file: {e}"))?;
    Ok((stream, cut))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcap::records::MessageHeader;
    use std::collections::BTreeMap;
    use std::io::Cursor;

    /// A finished file of `n` messages, one per 0.1 s, chunks closed every `per_chunk`.
    fn file(n: u64, per_chunk: u64) -> Vec<u8> {
        let mut buf = Cursor::new(Vec::new());
        {
            let mut w = mcap::WriteOptions::new().create(&mut buf).unwrap();
            let schema = w.add_schema("s", "jsonschema", b"{}").unwrap();
            let channel = w.add_channel(schema, "/t", "json", &BTreeMap::new()).unwrap();
            for k in 0..n {
                let h = MessageHeader {
                    channel_id: channel,
                    sequence: k as u32,
                    log_time: k * 100_000_000,
                    publish_time: 0,
                };
                w.write_to_known_channel(&h, format!("{{\"k\":{k}}}").as_bytes()).unwrap();
                if (k + 1) % per_chunk == 0 {
                    w.flush().unwrap();
                }
            }
            w.finish().unwrap();
        }
        buf.into_inner()
    }

    fn read_all(bytes: &[u8]) -> (Vec<u64>, Option<Cut>) {
        let (stream, cut) = message_stream(bytes).unwrap();
        (stream.map(|m| m.unwrap().log_time / 100_000_000).collect(), cut)
    }

    #[test]
    fn a_finished_file_is_read_whole_and_not_called_cut() {
        let bytes = file(50, 10);
        let (ks, cut) = read_all(&bytes);
        assert_eq!(ks, (0..50).collect::<Vec<_>>());
        assert_eq!(cut, None);
    }

    /// Cut anywhere inside the data, the file gives exactly the messages of the chunks that
    /// were whole before the cut, in order, and says where it ended.
    #[test]
    fn a_file_cut_anywhere_gives_the_chunks_before_the_cut() {
        let bytes = file(50, 10);
        let whole = readable(&bytes).unwrap().0.len();
        // Every cut point from just after the magic to just before the end.
        let mut seen_counts = std::collections::BTreeSet::new();
        for len in (9..whole - 1).step_by(7) {
            let (ks, cut) = read_all(&bytes[..len]);
            let cut = cut.expect("a cut file says so");
            assert_eq!(cut.length, len as u64);
            assert!(cut.byte <= len as u64);
            // Whole chunks of ten, never part of one.
            assert_eq!(ks.len() % 10, 0, "cut at {len}: {} messages", ks.len());
            assert_eq!(ks, (0..ks.len() as u64).collect::<Vec<_>>());
            seen_counts.insert(ks.len());
        }
        assert!(seen_counts.contains(&0) && seen_counts.contains(&50), "{seen_counts:?}");
    }

    #[test]
    fn what_is_not_mcap_is_refused_by_name() {
        let Err(e) = message_stream(b"hello, world") else { panic!("not MCAP, read") };
        assert!(e.contains("not an MCAP file"), "{e}");
        assert!(readable(b"").is_none());
    }
}
