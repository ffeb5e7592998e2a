//! QGroundControl / MAVProxy telemetry logs (`.tlog`): each MAVLink v1 or v2 frame follows an
//! 8-byte big-endian time stamp (µs since 1970, the ground station's receive time). Frames are
//! checked (CRC) and decoded by the `mavlink` crate (ArduPilot's dialect); a damaged frame
//! is skipped and counted, a file cut inside a frame is noted.
//!
//! Every series is on the autopilot's boot clock (`time_boot_ms`, `time_usec`), not the
//! receive time: the ground station's clock adds link latency and runs at a different rate
//! from a simulator's. A boot time going back by more than a second is a reboot: the series
//! end there (noted).

use super::ImportError;
use super::ardupilot::{ArdupilotOptions, Decoded, build};
use super::streams::{Series, StreamSet};
use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{MavlinkVersion, Message};
use std::ops::ControlFlow;
use std::path::Path;

const V1: u8 = 0xFE;
const V2: u8 = 0xFD;
const STAMP: usize = 8;
/// A boot time this far behind the latest one is a reboot, not reordering (s).
const REBOOT_STEP: f64 = 1.0;
/// Standard gravity (m/s^2), as ArduPilot's `GRAVITY_MSS`.
const G: f64 = 9.80665;

/// Ids of the messages read (MAVLink common set).
const WANTED: [u32; 7] = [30, 32, 29, 137, 36, 69, 33];

/// Where the frame at `buf[q..]` ends, or `None` if `buf[q]` is no start byte; `Some(Err(..))`
/// when the file ends inside it.
fn frame_len(buf: &[u8], q: usize) -> Option<Result<usize, ()>> {
    let magic = *buf.get(q)?;
    let (head, sig) = match magic {
        V1 => (6, 0),
        V2 => {
            let Some(&flags) = buf.get(q + 2) else { return Some(Err(())) };
            (10, if flags & 1 != 0 { 13 } else { 0 })
        }
        _ => return None,
    };
    let Some(&len) = buf.get(q + 1) else { return Some(Err(())) };
    let total = head + len as usize + 2 + sig;
    Some(if q + total <= buf.len() { Ok(total) } else { Err(()) })
}

/// Checks the frame's CRC (for every message the dialect knows) and decodes it if it is one
/// of the messages read; `Err(true)` for a frame not read, `Err(false)` for a damaged one.
/// A frame's version, message id, payload offset and system id.
fn header(frame: &[u8]) -> (MavlinkVersion, u32, usize, u8) {
    if frame[0] == V1 {
        (MavlinkVersion::V1, frame[5] as u32, 6, frame[3])
    } else {
        let id = frame[7] as u32 | (frame[8] as u32) << 8 | (frame[9] as u32) << 16;
        (MavlinkVersion::V2, id, 10, frame[5])
    }
}

fn decode(frame: &[u8]) -> Result<(u8, MavMessage), bool> {
    let (version, id, payload_at, sys) = header(frame);
    let len = frame[1] as usize;
    let wanted = WANTED.contains(&id);
    // A message the dialect does not know cannot be checked: it is stepped over as it is.
    if wanted || MavMessage::default_message_from_id(id).is_some() {
        let crc = u16::from_le_bytes([frame[payload_at + len], frame[payload_at + len + 1]]);
        if mavlink::calculate_crc(&frame[1..payload_at + len], MavMessage::extra_crc(id)) != crc {
            return Err(false);
        }
    }
    if !wanted {
        return Err(true);
    }
    MavMessage::parse(version, id, &frame[payload_at..payload_at + len]).map(|m| (sys, m)).map_err(|_| false)
}

/// Every frame of a telemetry log that the dialect decodes, in file order: `(receive time µs
/// since 1970, system id, message)`, and how many frames were damaged (bad checksum) and
/// whether the file ends inside a frame (a torn last frame, skipped).
pub struct TlogMessages {
    /// The messages.
    pub messages: Vec<(u64, u8, MavMessage)>,
    /// Frames with a bad checksum, skipped.
    pub damaged: usize,
    /// The file ends inside a frame.
    pub torn: bool,
    /// Where a cut-off MCAP recording ended (its whole records were read).
    pub cut: Option<super::mcap_cut::Cut>,
}

/// Reads every decodable frame of a `.tlog` (not only those the streams use).
///
/// # Errors
/// The file cannot be read or holds no valid frame.
pub fn tlog_messages(path: &Path) -> Result<TlogMessages, ImportError> {
    let buf = std::fs::read(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let mut out = TlogMessages { messages: Vec::new(), damaged: 0, torn: false, cut: None };
    let mut p = 0;
    while p + STAMP < buf.len() {
        let q = p + STAMP;
        let len = match frame_len(&buf, q) {
            None => {
                p += 1;
                continue;
            }
            Some(Err(())) => {
                out.torn = true;
                break;
            }
            Some(Ok(len)) => len,
        };
        let frame = &buf[q..q + len];
        let received = u64::from_be_bytes(buf[p..q].try_into().expect("8 bytes"));
        let (version, id, payload_at, sys) = header(frame);
        let n = frame[1] as usize;
        let crc = u16::from_le_bytes([frame[payload_at + n], frame[payload_at + n + 1]]);
        let known = MavMessage::default_message_from_id(id).is_some();
        if known && mavlink::calculate_crc(&frame[1..payload_at + n], MavMessage::extra_crc(id)) != crc {
            out.damaged += 1;
            p += 1;
            continue;
        }
        if let (true, Ok(m)) = (known, MavMessage::parse(version, id, &frame[payload_at..payload_at + n])) {
            out.messages.push((received, sys, m));
        }
        p = q + len;
    }
    if out.messages.is_empty() {
        return Err(ImportError::Malformed { path: path.to_path_buf(), message: "no valid MAVLink frame".into() });
    }
    Ok(out)
}

/// A frame of a message read.
struct Frame {
    /// The byte the frame starts at (after its time stamp).
    at: usize,
    /// The ground station's receive time (µs since 1970).
    received: u64,
    /// The sender's system id.
    sys: u8,
    msg: MavMessage,
}

/// What a walk over a telemetry log steps over instead of a message read.
enum Skip {
    /// No frame starts after the time stamp here: one byte.
    Byte,
    /// A frame with a bad checksum (or that does not parse): one byte, its length byte may be
    /// wrong too.
    Damaged,
    /// A good frame of a message not read, whole.
    Other,
    /// The file ends inside the frame whose time stamp is at this byte.
    Torn(usize),
}

/// A walk over the frames of a telemetry log, each checked and, if it is one of the messages
/// read, decoded; it ends at the end of the file or after a torn frame.
struct Walk<'b> {
    buf: &'b [u8],
    p: usize,
}

impl Iterator for Walk<'_> {
    type Item = Result<Frame, Skip>;

    fn next(&mut self) -> Option<Self::Item> {
        let buf = self.buf;
        if self.p + STAMP >= buf.len() {
            return None;
        }
        let (p, q) = (self.p, self.p + STAMP);
        let len = match frame_len(buf, q) {
            None => {
                self.p += 1;
                return Some(Err(Skip::Byte));
            }
            Some(Err(())) => {
                self.p = buf.len();
                return Some(Err(Skip::Torn(p)));
            }
            Some(Ok(len)) => len,
        };
        let received = u64::from_be_bytes(buf[p..q].try_into().expect("8 bytes"));
        Some(match decode(&buf[q..q + len]) {
            Ok((sys, msg)) => {
                self.p = q + len;
                Ok(Frame { at: q, received, sys, msg })
            }
            Err(true) => {
                self.p = q + len;
                Err(Skip::Other)
            }
            Err(false) => {
                self.p += 1;
                Err(Skip::Damaged)
            }
        })
    }
}

/// What a telemetry log gave: the series, the thruster outputs and pilot commands, and the
/// counts the notes report.
struct Scan {
    att: Series<3>,
    rate: Series<1>,
    pos: Series<3>,
    vel: Series<3>,
    /// `SCALED_PRESSURE` and `SCALED_PRESSURE2` (Pa).
    press: [Series<1>; 2],
    out_t: Vec<f64>,
    out_pwm: Vec<Vec<f64>>,
    pilot: Series<4>,
    frames: usize,
    damaged: usize,
    other: usize,
    skipped_bytes: usize,
    out_of_order: usize,
    /// The system that sends `ATTITUDE`, once it has.
    autopilot: Option<u8>,
    /// Latest boot time (s) and the receive time (µs) it came with: MANUAL_CONTROL has no time
    /// of its own and is placed by the receive time elapsed since.
    latest: Option<(f64, u64)>,
    /// Where the file ends inside a frame.
    torn: Option<usize>,
    /// A reboot: the byte, the latest boot time before and the one after (s).
    reboot: Option<(usize, f64, f64)>,
}

impl Scan {
    fn new() -> Self {
        Self {
            att: Series::new("ATTITUDE.roll,pitch,yaw"),
            rate: Series::new("ATTITUDE.yawspeed"),
            pos: Series::new("LOCAL_POSITION_NED.x,y,z"),
            vel: Series::new("LOCAL_POSITION_NED.vx,vy,vz"),
            press: [Series::new("SCALED_PRESSURE.press_abs"), Series::new("SCALED_PRESSURE2.press_abs")],
            out_t: Vec::new(),
            out_pwm: Vec::new(),
            pilot: Series::new("MANUAL_CONTROL.x,y,z,r"),
            frames: 0,
            damaged: 0,
            other: 0,
            skipped_bytes: 0,
            out_of_order: 0,
            autopilot: None,
            latest: None,
            torn: None,
            reboot: None,
        }
    }

    /// Walks the whole log (up to a torn frame or a reboot).
    fn read(&mut self, buf: &[u8]) {
        for step in (Walk { buf, p: 0 }) {
            match step {
                Err(Skip::Byte) => self.skipped_bytes += 1,
                Err(Skip::Damaged) => {
                    self.damaged += 1;
                    self.skipped_bytes += 1;
                }
                Err(Skip::Other) => self.other += 1,
                Err(Skip::Torn(at)) => self.torn = Some(at),
                Ok(frame) => {
                    self.frames += 1;
                    if self.message(frame).is_break() {
                        break;
                    }
                }
            }
        }
    }

    /// The boot time (s) of a message from the autopilot, `None` for one without a time of
    /// its own; `Err(())` for a message from another system, which is not read.
    fn boot_time(&self, sys: u8, msg: &MavMessage) -> Result<Option<f64>, ()> {
        let boot_ms = |ms: u32| ms as f64 * 1e-3;
        Ok(match msg {
            MavMessage::MANUAL_CONTROL(_) => None,
            _ if self.autopilot.is_some_and(|a| a != sys) => return Err(()),
            MavMessage::ATTITUDE(m) => Some(boot_ms(m.time_boot_ms)),
            MavMessage::LOCAL_POSITION_NED(m) => Some(boot_ms(m.time_boot_ms)),
            MavMessage::GLOBAL_POSITION_INT(m) => Some(boot_ms(m.time_boot_ms)),
            MavMessage::SCALED_PRESSURE(m) => Some(boot_ms(m.time_boot_ms)),
            MavMessage::SCALED_PRESSURE2(m) => Some(boot_ms(m.time_boot_ms)),
            MavMessage::SERVO_OUTPUT_RAW(m) => Some(m.time_usec as f64 * 1e-6),
            _ => None,
        })
    }

    /// One message: timed by the boot clock, appended to its series unless older than the
    /// series' last sample. A boot time going back by more than [`REBOOT_STEP`] ends the walk.
    fn message(&mut self, Frame { at, received, sys, msg }: Frame) -> ControlFlow<()> {
        let Ok(t) = self.boot_time(sys, &msg) else { return ControlFlow::Continue(()) };
        if let Some(t) = t {
            if let Some((l, _)) = self.latest
                && t < l - REBOOT_STEP
            {
                self.reboot = Some((at, l, t));
                return ControlFlow::Break(());
            }
            if self.latest.is_none_or(|(l, _)| t >= l) {
                self.latest = Some((t, received));
            }
        }
        let t = t.unwrap_or_default();
        match msg {
            MavMessage::ATTITUDE(m) => {
                self.autopilot.get_or_insert(sys);
                if self.att.t.last().is_some_and(|&l| t < l) {
                    self.out_of_order += 1;
                    return ControlFlow::Continue(());
                }
                self.att.push(t, [m.roll as f64, m.pitch as f64, m.yaw as f64]);
                self.rate.push(t, [m.yawspeed as f64]);
            }
            MavMessage::LOCAL_POSITION_NED(m) => {
                if self.pos.t.last().is_some_and(|&l| t < l) {
                    self.out_of_order += 1;
                    return ControlFlow::Continue(());
                }
                self.pos.push(t, [m.x as f64, m.y as f64, m.z as f64]);
                self.vel.push(t, [m.vx as f64, m.vy as f64, m.vz as f64]);
            }
            MavMessage::SCALED_PRESSURE(m) => self.pressure(0, t, m.press_abs),
            MavMessage::SCALED_PRESSURE2(m) => self.pressure(1, t, m.press_abs),
            MavMessage::SERVO_OUTPUT_RAW(m) => {
                if m.port != 0 || self.out_t.last().is_some_and(|&l| t < l) {
                    return ControlFlow::Continue(());
                }
                self.out_t.push(t);
                self.out_pwm.push(
                    [
                        m.servo1_raw,
                        m.servo2_raw,
                        m.servo3_raw,
                        m.servo4_raw,
                        m.servo5_raw,
                        m.servo6_raw,
                        m.servo7_raw,
                        m.servo8_raw,
                    ]
                    .map(f64::from)
                    .to_vec(),
                );
            }
            MavMessage::MANUAL_CONTROL(m) => {
                if let Some((l, r)) = self.latest {
                    // In integer µs: the stamps since 1970 have too many digits for an f64 in s.
                    let t = l + received.saturating_sub(r) as f64 * 1e-6;
                    if self.pilot.t.last().is_none_or(|&last| t >= last) {
                        self.pilot.push(t, [m.x, m.y, m.z, m.r].map(f64::from));
                    }
                }
            }
            _ => {}
        }
        ControlFlow::Continue(())
    }

    /// A pressure sample (hPa) into series `which` (Pa), unless older than its last one.
    fn pressure(&mut self, which: usize, t: f64, press_abs: f32) {
        let s = &mut self.press[which];
        if s.t.last().is_some_and(|&l| t < l) {
            self.out_of_order += 1;
        } else {
            s.push(t, [press_abs as f64 * 100.0]);
        }
    }

    /// The notes on the frames read and skipped, the time base and what ended the walk.
    fn notes(&self) -> Vec<String> {
        let (frames, other, damaged, skipped_bytes) = (self.frames, self.other, self.damaged, self.skipped_bytes);
        let mut notes = vec![format!(
            "tlog: {frames} frames read, {other} frames of other messages stepped over; time base: the autopilot's boot clock (time_boot_ms, time_usec), not the receive time stamps; frames: ATTITUDE and LOCAL_POSITION_NED are NED / forward-right-down already"
        )];
        if damaged > 0 || skipped_bytes > 0 {
            notes.push(format!(
                "tlog: {damaged} damaged frames (bad CRC) skipped, {skipped_bytes} bytes skipped in all"
            ));
        }
        if self.out_of_order > 0 {
            notes.push(format!("tlog: {} samples older than their series' last one dropped", self.out_of_order));
        }
        if let Some(at) = self.torn {
            notes.push(format!("tlog: the file ends inside a frame at byte {at}: dropped"));
        }
        if let Some((at, l, t)) = self.reboot {
            notes.push(format!(
                "tlog: the autopilot rebooted at byte {at} (boot time {l:.3} s -> {t:.3} s): the series end there"
            ));
        }
        notes
    }

    /// The series as the shared ArduPilot builder takes them: the depth from the better
    /// pressure sensor where it has samples, the outputs and the pilot's commands where there
    /// are any.
    fn into_decoded(self, opts: &ArdupilotOptions, notes: Vec<String>) -> Decoded {
        let mut d = Decoded { notes, ..Decoded::default() };
        d.attitude = Some(self.att);
        d.yaw_rate = Some(self.rate);
        d.position = Some(self.pos);
        d.velocity_ned = Some(self.vel);
        let [p1, p2] = self.press;
        if let Some(pr) = [p2, p1].into_iter().find(|s| !s.is_empty()) {
            d.depth = Some(depth_of(&pr, opts));
        }
        if !self.out_t.is_empty() {
            d.outputs = Some(("SERVO_OUTPUT_RAW.servo1_raw..servo8_raw (PWM us)".into(), self.out_t, self.out_pwm));
        }
        if !self.pilot.is_empty() {
            d.notes.push(
                "MANUAL_CONTROL: no time of its own; placed at the latest autopilot boot time plus the receive time elapsed since"
                    .into(),
            );
            d.pilot = Some(self.pilot);
        }
        d
    }
}

/// Depth (m) from absolute pressure (Pa): `(p - surface) / (rho g)`, the surface pressure
/// given or the first sample's.
fn depth_of(pr: &Series<1>, opts: &ArdupilotOptions) -> Series<1> {
    let surface = opts.surface_pressure.unwrap_or(pr.v[0][0]);
    let rho = opts.water_density;
    let mut depth = Series::new(format!(
        "{} (depth = (p - {surface:.0} Pa) / ({rho} kg/m^3 * {G} m/s^2), surface pressure {})",
        pr.source,
        if opts.surface_pressure.is_some() { "given" } else { "the first sample" }
    ));
    for (t, v) in pr.t.iter().zip(&pr.v) {
        depth.push(*t, [(v[0] - surface) / (rho * G)]);
    }
    depth
}

/// Reads a telemetry log into the streams (see the module documentation and
/// docs/LOGS_ARDUPILOT.md): `ATTITUDE` (attitude, yaw rate), `LOCAL_POSITION_NED` (the EKF's
/// NED position and velocity), `SCALED_PRESSURE2` or else `SCALED_PRESSURE` (depth, only
/// where there is no position), `SERVO_OUTPUT_RAW` (thruster outputs), `MANUAL_CONTROL`
/// (pilot commands), from the system that sends `ATTITUDE`.
///
/// The stages: the file read, its frames walked into series (`Scan`), the notes, the series
/// handed to the builder the .BIN reader shares.
///
/// # Errors
/// The file cannot be read, holds no valid MAVLink frame, or lacks a message the streams need
/// (`ImportError::Malformed`, naming the file and the message); inputs asked for without a
/// thruster conversion (`ImportError::Unusable`).
pub fn read_tlog(path: &Path, opts: &ArdupilotOptions) -> Result<StreamSet, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    let buf = std::fs::read(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let mut scan = Scan::new();
    scan.read(&buf);
    if scan.frames == 0 {
        return Err(malformed(format!(
            "not a MAVLink telemetry log: no valid frame after an 8-byte time stamp in its {} bytes",
            buf.len()
        )));
    }
    let notes = scan.notes();
    if scan.att.is_empty() {
        let what = if scan.torn.is_some() { "truncated before any ATTITUDE message" } else { "no ATTITUDE message" };
        return Err(malformed(what.into()));
    }
    build(path, scan.into_decoded(opts, notes), opts, true)
}

/// The MAVLink messages a `pinc vehicle record` / `excite` MCAP holds (`/mavlink/<NAME>`,
/// JSON with the sender in `header`), in log order, as [`tlog_messages`] gives a `.tlog`'s. A
/// message this build's dialect cannot read back is counted as damaged, not fatal.
///
/// # Errors
/// The file cannot be read, is not MCAP, or holds no `/mavlink/*` message.
#[cfg(feature = "vehicle")]
pub fn mcap_messages(path: &Path) -> Result<TlogMessages, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    let bytes = std::fs::read(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let (stream, cut) = super::mcap_cut::message_stream(&bytes).map_err(malformed)?;
    let mut out = TlogMessages { messages: Vec::new(), damaged: 0, torn: false, cut };
    for m in stream {
        let m = m.map_err(|e| malformed(e.to_string()))?;
        if let Some(c) = &mut out.cut {
            c.saw(m.log_time);
        }
        if !m.channel.topic.starts_with("/mavlink/") {
            continue;
        }
        let Ok(value) = serde_json::from_slice::<serde_json::Value>(&m.data) else {
            out.damaged += 1;
            continue;
        };
        let sys = value["header"]["system_id"].as_u64().unwrap_or(0) as u8;
        match serde_json::from_value::<MavMessage>(value) {
            Ok(message) => out.messages.push((m.log_time / 1000, sys, message)),
            Err(_) => out.damaged += 1,
        }
    }
    if out.messages.is_empty() {
        return Err(malformed("no /mavlink/* messages (record it with `pinc vehicle record`)".into()));
    }
    Ok(out)
}

/// The MAVLink messages of a `.tlog`, or of a pinc MCAP (by the `.mcap` extension).
///
/// # Errors
/// As [`tlog_messages`] and [`mcap_messages`]; an MCAP in a build without the `vehicle`
/// feature.
pub fn mavlink_log(path: &Path) -> Result<TlogMessages, ImportError> {
    if super::log_extension(path).as_deref() == Some("mcap") {
        #[cfg(feature = "vehicle")]
        return mcap_messages(path);
        #[cfg(not(feature = "vehicle"))]
        return Err(ImportError::Malformed {
            path: path.to_path_buf(),
            message: "reading MAVLink from MCAP needs the `vehicle` feature".into(),
        });
    }
    tlog_messages(path)
}
