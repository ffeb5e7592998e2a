//! ArduPilot's onboard dataflash logs (`.BIN`): a parser driven by the log's own `FMT`
//! records, so any firmware version reads. One pass over the bytes in memory; only the
//! fields the state and the inputs need are decoded, every other record is stepped over by
//! its length.
//!
//! A record is `0xA3 0x95 <type>` followed by the fields its `FMT` record (type 128)
//! describes: the total length, a 4-character name, one format character per field and the
//! comma-separated labels. Bytes that do not start a known record are skipped (counted) until
//! the next header; a record cut by the end of the file is noted and dropped.

use super::ImportError;
use super::ardupilot::{ArdupilotOptions, Decoded, build, wrap_pi};
use super::streams::{Series, StreamSet};
use std::path::Path;

const HEAD1: u8 = 0xA3;
const HEAD2: u8 = 0x95;
const FMT_TYPE: u8 = 128;
/// `FMT`'s own layout (`BBnNZ`, 89 bytes with the header): used until the log defines it.
const FMT_LEN: usize = 89;

/// Size in bytes of one field of format character `c` (ArduPilot's `AP_Logger` table).
fn field_size(c: u8) -> Option<usize> {
    Some(match c {
        b'b' | b'B' | b'M' => 1,
        b'h' | b'H' | b'c' | b'C' | b'g' => 2,
        b'i' | b'I' | b'f' | b'e' | b'E' | b'L' | b'n' => 4,
        b'd' | b'q' | b'Q' => 8,
        b'N' => 16,
        b'Z' | b'a' => 64,
        _ => return None,
    })
}

/// A numeric field at `off` (from the record's first byte) of format character `c`, in the
/// unit the character implies: `c C e E` are hundredths, `L` is 1e-7 degrees.
#[derive(Debug, Clone, Copy)]
struct Field {
    off: usize,
    c: u8,
}

impl Field {
    #[inline]
    fn get(self, rec: &[u8]) -> f64 {
        let b = &rec[self.off..];
        let a2 = || [b[0], b[1]];
        let a4 = || [b[0], b[1], b[2], b[3]];
        let a8 = || [b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]];
        match self.c {
            b'b' => b[0] as i8 as f64,
            b'B' | b'M' => b[0] as f64,
            b'h' => i16::from_le_bytes(a2()) as f64,
            b'H' => u16::from_le_bytes(a2()) as f64,
            b'c' => i16::from_le_bytes(a2()) as f64 * 0.01,
            b'C' => u16::from_le_bytes(a2()) as f64 * 0.01,
            b'g' => half_to_f64(u16::from_le_bytes(a2())),
            b'i' => i32::from_le_bytes(a4()) as f64,
            b'I' => u32::from_le_bytes(a4()) as f64,
            b'e' => i32::from_le_bytes(a4()) as f64 * 0.01,
            b'E' => u32::from_le_bytes(a4()) as f64 * 0.01,
            b'L' => i32::from_le_bytes(a4()) as f64 * 1e-7,
            b'f' => f32::from_le_bytes(a4()) as f64,
            b'd' => f64::from_le_bytes(a8()),
            b'q' => i64::from_le_bytes(a8()) as f64,
            b'Q' => u64::from_le_bytes(a8()) as f64,
            // Text and arrays are never asked for as numbers (`decode_fields` refuses them).
            _ => f64::NAN,
        }
    }
}

/// IEEE 754 half precision (format character `g`).
fn half_to_f64(h: u16) -> f64 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let frac = (h & 0x3ff) as f64;
    sign * match exp {
        0 => frac * 2f64.powi(-24),
        31 => {
            if frac == 0.0 {
                f64::INFINITY
            } else {
                f64::NAN
            }
        }
        _ => (1.0 + frac / 1024.0) * 2f64.powi(exp - 15),
    }
}

/// The messages this reader decodes.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Att,
    Xkf1,
    Baro,
    Rcou,
    Rcin,
    Orgn,
    Imu,
}

impl Kind {
    fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "ATT" => Self::Att,
            "XKF1" => Self::Xkf1,
            "BARO" => Self::Baro,
            "RCOU" => Self::Rcou,
            "RCIN" => Self::Rcin,
            "ORGN" => Self::Orgn,
            "IMU" => Self::Imu,
            _ => return None,
        })
    }

    /// Labels read, in order; for RCOU / RCIN the channels present are added.
    fn labels(self) -> &'static [&'static str] {
        match self {
            Self::Att => &["TimeUS", "Roll", "Pitch", "Yaw"],
            Self::Xkf1 => &["TimeUS", "C", "VN", "VE", "VD", "PN", "PE", "PD"],
            Self::Baro => &["TimeUS", "I", "Alt"],
            Self::Imu => &["TimeUS", "I", "GyrZ"],
            Self::Rcou | Self::Rcin | Self::Orgn => &["TimeUS"],
        }
    }
}

/// One type the log defined.
#[derive(Debug, Clone)]
struct Format {
    len: usize,
    name: String,
    /// Set when the reader decodes this type.
    decode: Option<(Kind, Vec<Field>)>,
}

/// Text of a fixed-size, NUL-padded field.
fn text(b: &[u8]) -> String {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    String::from_utf8_lossy(&b[..end]).into_owned()
}

/// Field offsets by label for the labels `kind` needs (channels `C1..` for RCOU / RCIN).
fn decode_fields(kind: Kind, name: &str, format: &[u8], labels: &str) -> Result<Vec<Field>, String> {
    let labels: Vec<&str> = labels.split(',').collect();
    if labels.len() != format.len() {
        return Err(format!("FMT of {name}: {} format characters but {} labels", format.len(), labels.len()));
    }
    let mut offsets = Vec::with_capacity(format.len());
    let mut off = 3;
    for &c in format {
        offsets.push(off);
        off += field_size(c).ok_or_else(|| format!("FMT of {name}: unknown format character {:?}", c as char))?;
    }
    let find = |label: &str| -> Result<Field, String> {
        let i = labels
            .iter()
            .position(|l| *l == label)
            .ok_or_else(|| format!("FMT of {name} has no field {label} (fields: {})", labels.join(",")))?;
        if matches!(format[i], b'n' | b'N' | b'Z' | b'a') {
            return Err(format!("{name}.{label} is not a number (format {:?})", format[i] as char));
        }
        Ok(Field { off: offsets[i], c: format[i] })
    };
    let mut fields = kind.labels().iter().map(|l| find(l)).collect::<Result<Vec<_>, _>>()?;
    if matches!(kind, Kind::Rcou | Kind::Rcin) {
        for ch in 1.. {
            match find(&format!("C{ch}")) {
                Ok(f) => fields.push(f),
                Err(_) => break,
            }
        }
    }
    Ok(fields)
}

/// Counts of what the pass saw, for the notes.
#[derive(Debug, Default)]
struct Tally {
    skipped_bytes: usize,
    records: usize,
    torn: Option<(usize, String, usize)>,
}

/// Reads an ArduPilot dataflash log into the streams (see the module documentation and
/// docs/LOGS_ARDUPILOT.md): `ATT` (attitude), `XKF1` of core 0 (NED position and velocity),
/// `BARO` (depth, only where the EKF gives no position), `RCOU` (thruster outputs) or `RCIN`
/// (pilot axes), on the autopilot's boot clock (`TimeUS`).
///
/// # Errors
/// The file cannot be read, holds no dataflash record, or lacks a message the streams need
/// (`ImportError::Malformed`, naming the file and the message); inputs asked for without a
/// thruster conversion (`ImportError::Unusable`).
pub fn read_bin(path: &Path, opts: &ArdupilotOptions) -> Result<StreamSet, ImportError> {
    let bytes = std::fs::read(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let d = decode_bin(&bytes).map_err(|message| ImportError::Malformed { path: path.to_path_buf(), message })?;
    let d = assemble(d, opts).map_err(|message| ImportError::Malformed { path: path.to_path_buf(), message })?;
    build(path, d, opts, false)
}

/// The raw samples of the decoded messages (times in µs of boot).
#[derive(Debug, Default)]
pub(crate) struct BinSamples {
    att: Vec<[f64; 4]>,
    xkf1: Vec<[f64; 7]>,
    /// `[t, instance, alt]`.
    baro: Vec<[f64; 3]>,
    /// `[t, gyro z]` of the first IMU (rad/s, body frame: the yaw rate pinc's state holds).
    imu: Vec<[f64; 2]>,
    rcou: Vec<Vec<f64>>,
    rcin: Vec<Vec<f64>>,
    /// Time of the first `ORGN` record: the EKF's origin was set.
    origin: Option<f64>,
    tally: Tally,
    names_seen: usize,
}

/// One pass over the log: every record of a decoded type, field by field.
///
/// # Errors
/// No record at all, or a FMT that describes a needed type in a way that cannot be read.
pub(crate) fn decode_bin(buf: &[u8]) -> Result<BinSamples, String> {
    let mut formats: Vec<Option<Format>> = vec![None; 256];
    formats[FMT_TYPE as usize] = Some(Format { len: FMT_LEN, name: "FMT".into(), decode: None });
    let mut s = BinSamples::default();
    let n = buf.len();
    let mut p = 0;
    while p + 3 <= n {
        if buf[p] != HEAD1 || buf[p + 1] != HEAD2 {
            // Garbage: jump to the next possible header byte.
            let next = buf[p + 1..].iter().position(|&b| b == HEAD1).map_or(n, |i| p + 1 + i);
            s.tally.skipped_bytes += next - p;
            p = next;
            continue;
        }
        let id = buf[p + 2];
        let Some(fmt) = &formats[id as usize] else {
            s.tally.skipped_bytes += 1;
            p += 1;
            continue;
        };
        let len = fmt.len;
        if p + len > n {
            s.tally.torn = Some((p, fmt.name.clone(), n - p));
            break;
        }
        let rec = &buf[p..p + len];
        s.tally.records += 1;
        if id == FMT_TYPE {
            let ty = rec[3] as usize;
            let rlen = rec[4] as usize;
            let name = text(&rec[5..9]);
            let format = text(&rec[9..25]);
            let labels = text(&rec[25..89]);
            s.names_seen += 1;
            let decode = match Kind::from_name(&name) {
                // The gyro is a bonus (the estimator's yaw rate): an IMU record of another
                // layout is left undecoded rather than failing the log.
                Some(Kind::Imu) => {
                    decode_fields(Kind::Imu, &name, format.as_bytes(), &labels).ok().map(|f| (Kind::Imu, f))
                }
                Some(kind) => Some((kind, decode_fields(kind, &name, format.as_bytes(), &labels)?)),
                None => None,
            };
            if rlen >= 3 && ty != FMT_TYPE as usize {
                formats[ty] = Some(Format { len: rlen, name, decode });
            }
        } else if let Some((kind, fields)) = &fmt.decode {
            let g = |i: usize| fields[i].get(rec);
            match kind {
                Kind::Att => s.att.push([g(0), g(1), g(2), g(3)]),
                Kind::Xkf1 => {
                    if g(1) == 0.0 {
                        s.xkf1.push([g(0), g(2), g(3), g(4), g(5), g(6), g(7)]);
                    }
                }
                Kind::Baro => s.baro.push([g(0), g(1), g(2)]),
                Kind::Imu => {
                    if g(1) == 0.0 {
                        s.imu.push([g(0), g(2)]);
                    }
                }
                Kind::Rcou => s.rcou.push(fields.iter().map(|f| f.get(rec)).collect()),
                Kind::Rcin => s.rcin.push(fields.iter().map(|f| f.get(rec)).collect()),
                Kind::Orgn => {
                    s.origin.get_or_insert(g(0));
                }
            }
        }
        p += len;
    }
    if s.tally.records == 0 || s.names_seen == 0 {
        return Err(format!("not an ArduPilot dataflash log: no FMT record in its {n} bytes"));
    }
    Ok(s)
}

/// The decoded samples as series in pinc's units (s, rad, m, m/s) and notes.
fn assemble(s: BinSamples, opts: &ArdupilotOptions) -> Result<Decoded, String> {
    let mut d = Decoded::default();
    let us = 1e-6;
    d.notes.push(format!(
        "dataflash: {} records read; time base: the autopilot's boot clock (TimeUS); frames: ATT and XKF1 are NED / forward-right-down already",
        s.tally.records
    ));
    if s.tally.skipped_bytes > 0 {
        d.notes.push(format!("dataflash: {} bytes outside any known record skipped", s.tally.skipped_bytes));
    }
    if let Some((at, name, have)) = &s.tally.torn {
        d.notes.push(format!(
            "dataflash: the file ends inside a {name} record at byte {at} ({have} bytes of it): dropped"
        ));
    }
    if s.att.is_empty() {
        return Err(if s.tally.torn.is_some() {
            "truncated before any ATT record (attitude)".into()
        } else {
            "no ATT record (attitude)".into()
        });
    }
    let mut att = Series::new("ATT.Roll,Pitch,Yaw (deg)");
    for a in &s.att {
        att.push(a[0] * us, [a[1].to_radians(), a[2].to_radians(), wrap_pi(a[3].to_radians())]);
    }
    d.attitude = Some(att);
    // Before the EKF has an origin its position is zeros, not a position.
    let from = s.origin.unwrap_or(f64::NEG_INFINITY);
    match s.origin {
        Some(t) => d.notes.push(format!("XKF1: the EKF's origin was set (ORGN) at boot time {:.3} s: position and velocity from then on", t * us)),
        None => d.notes.push("XKF1: no ORGN record (no EKF origin): PN, PE are relative to where the EKF started, zero without a horizontal position source".into()),
    }
    if s.xkf1.iter().any(|x| x[0] >= from) {
        let mut pos = Series::new("XKF1[C=0].PN,PE,PD");
        let mut vel = Series::new("XKF1[C=0].VN,VE,VD");
        for x in s.xkf1.iter().filter(|x| x[0] >= from) {
            pos.push(x[0] * us, [x[4], x[5], x[6]]);
            vel.push(x[0] * us, [x[1], x[2], x[3]]);
        }
        d.position = Some(pos);
        d.velocity_ned = Some(vel);
    }
    if !s.baro.is_empty() {
        let highest = s.baro.iter().map(|b| b[1] as u8).max().unwrap_or(0);
        let inst = opts.baro_instance.unwrap_or(highest);
        let mut depth = Series::new(format!("BARO[I={inst}].Alt (depth = -Alt, the firmware's calibration)"));
        for b in s.baro.iter().filter(|b| b[1] as u8 == inst) {
            depth.push(b[0] * us, [-b[2]]);
        }
        if depth.is_empty() {
            return Err(format!("no BARO record of instance {inst} (the highest is {highest})"));
        }
        d.depth = Some(depth);
    }
    if !s.imu.is_empty() {
        let mut rate = Series::new("IMU[I=0].GyrZ (rad/s)");
        for i in &s.imu {
            rate.push(i[0] * us, [i[1]]);
        }
        d.yaw_rate = Some(rate);
    }
    if !s.rcou.is_empty() {
        let t = s.rcou.iter().map(|r| r[0] * us).collect();
        let pwm = s.rcou.iter().map(|r| r[1..].to_vec()).collect();
        d.outputs = Some((format!("RCOU.C1..C{} (PWM us)", s.rcou[0].len() - 1), t, pwm));
    }
    // ArduSub's RC channels: 3 throttle, 4 yaw, 5 forward, 6 lateral; the joystick gain is
    // already in them (the RC override is 1500 + 0.4 g x).
    if let Some(r0) = s.rcin.first()
        && r0.len() > 6
    {
        let mut pilot = Series::new("RCIN.C5,C6,C3,C4 (forward, lateral, throttle, yaw)");
        for r in &s.rcin {
            let ax = |c: usize| (r[c] - 1500.0) / 400.0;
            pilot.push(r[0] * us, [ax(5), ax(6), ax(3), ax(4)]);
        }
        d.pilot = Some(pilot);
    }
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_precision() {
        assert_eq!(half_to_f64(0x3c00), 1.0);
        assert_eq!(half_to_f64(0xc000), -2.0);
        assert_eq!(half_to_f64(0x3555), 0.333251953125);
    }

    /// A log written by hand: FMT of FMT, FMT of ATT, garbage, two ATT records.
    #[test]
    fn formats_drive_decoding_and_garbage_is_skipped() {
        fn fmt(ty: u8, len: u8, name: &str, format: &str, labels: &str) -> Vec<u8> {
            let mut r = vec![HEAD1, HEAD2, FMT_TYPE, ty, len];
            let mut pad = |s: &str, n: usize| {
                let mut b = s.as_bytes().to_vec();
                b.resize(n, 0);
                r.extend(b);
            };
            pad(name, 4);
            pad(format, 16);
            pad(labels, 64);
            r
        }
        let mut log = fmt(128, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns");
        log.extend(fmt(7, 3 + 8 + 2 + 4 + 2, "ATT", "Qcfc", "TimeUS,Roll,Yaw,Pitch"));
        log.extend([1, 2, 3, HEAD1, 9]);
        for (t, roll, yaw, pitch) in [(1_000_000u64, -150i16, 350.5f32, 20i16), (1_100_000, 10, 10.0, -20)] {
            log.extend([HEAD1, HEAD2, 7]);
            log.extend(t.to_le_bytes());
            log.extend(roll.to_le_bytes());
            log.extend(yaw.to_le_bytes());
            log.extend(pitch.to_le_bytes());
        }
        log.extend([HEAD1, HEAD2, 7, 0, 0]);
        let s = decode_bin(&log).unwrap();
        assert_eq!(s.att, vec![[1e6, -1.5, 0.2, 350.5], [1.1e6, 0.1, -0.2, 10.0]]);
        assert_eq!(s.tally.skipped_bytes, 5);
        assert_eq!(s.tally.torn.as_ref().map(|t| t.2), Some(5));
    }
}
