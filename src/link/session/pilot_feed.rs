//! The pilot's sticks reaching the live session (`mpc_track --connect --pilot`): one JSON
//! object per line from a file or stdin (what `pinc serve` passes its page's gamepad through),
//! read on a thread, or a ground station's joystick (`--pilot mavlink:SYSID`: the
//! `MANUAL_CONTROL` that station sends the autopilot, seen on pinc's link through the
//! vehicle's router); each stamped when it arrived, and every cycle the session hands those
//! that came to the pilot assist at their own time.

use crate::link::Received;
use crate::pilot::{PilotAssist, StickError, Sticks};
use mavlink::dialects::ardupilotmega::MavMessage;
use std::io::BufRead;
use std::sync::mpsc::{Receiver, Sender, TryRecvError, channel};
use std::time::{Duration, Instant};

/// `--pilot`'s prefix for a ground station's joystick.
const GROUND_STATION_PREFIX: &str = "mavlink:";
/// The least time between two joystick readings passed on: Cockpit sends one every 40 ms; a
/// router may hand on two at once, and the session's clock puts each reading at its arrival
/// within a few ms of jitter, which must not bring two under the assist's
/// [`MIN_INTERVAL_S`](crate::pilot::MIN_INTERVAL_S). A faster joystick is thinned to this (more adds nothing to a 12.5 Hz
/// controller).
const JOYSTICK_MIN_GAP_S: f64 = 0.02;
/// How long the first cycles may go without the ground station's joystick before the
/// session says so (Cockpit sends 25 a second while a joystick is plugged in).
const JOYSTICK_SILENCE_S: f64 = 3.0;

/// The ground station whose joystick `source` names (`mavlink:SYSID`), if it names one.
///
/// # Errors
/// `mavlink:` followed by anything but a system id 1..=255.
pub(super) fn ground_station_of(source: &str) -> Result<Option<u8>, String> {
    let Some(id) = source.strip_prefix(GROUND_STATION_PREFIX) else { return Ok(None) };
    match id.parse::<u8>() {
        Ok(id) if id > 0 => Ok(Some(id)),
        _ => Err(format!(
            "--pilot {source}: a ground station's joystick is mavlink:SYSID, its system id 1..255 (Cockpit's: 255)"
        )),
    }
}

/// Where the session passes a ground station's `MANUAL_CONTROL` on to the assist.
pub(super) struct JoystickTap {
    /// The ground station's system id, and the autopilot's its messages are for.
    ground: u8,
    autopilot: u8,
    readings: Sender<Arrived>,
    /// When the last reading was passed on: one sooner than [`JOYSTICK_MIN_GAP_S`] after it is
    /// left out, the next one carries the stick on.
    last: Option<Instant>,
}

impl JoystickTap {
    /// Passes `r` on if it is the ground station's joystick for the autopilot.
    pub(super) fn see(&mut self, r: &Received) {
        let MavMessage::MANUAL_CONTROL(m) = &r.message else { return };
        if r.header.system_id != u32::from(self.ground) || m.target != self.autopilot {
            return;
        }
        if self.last.is_some_and(|last| r.at.saturating_duration_since(last) < Duration::from_secs_f64(JOYSTICK_MIN_GAP_S)) {
            return;
        }
        self.last = Some(r.at);
        let _ = self.readings.send((r.at, Sticks::from_manual_control(m.x, m.y, m.z, m.r)));
    }
}

/// A reading as it arrived.
type Arrived = (Instant, Result<Sticks, StickError>);

/// The sticks' source and the assist they drive.
pub(super) struct PilotFeed {
    pub(super) assist: PilotAssist,
    readings: Receiver<Arrived>,
    /// Whether the source has ended (said once).
    ended: bool,
    /// A ground station's joystick's way in, until the session takes it.
    joystick: Option<JoystickTap>,
    /// That ground station's id; the first cycle's time and whether a reading came since
    /// (a joystick never heard is said once).
    ground: Option<u8>,
    first_t: Option<f64>,
    heard: bool,
}

impl PilotFeed {
    /// Starts reading `source` (`-`: stdin; `mavlink:SYSID`: that ground station's joystick,
    /// through [`PilotFeed::joystick_tap`]; else a file or a named pipe).
    pub(super) fn open(source: &str, assist: PilotAssist) -> Result<Self, String> {
        if let Some(ground) = ground_station_of(source)? {
            let (tx, readings) = channel();
            // The autopilot's id is known once the link finds it.
            let tap = JoystickTap { ground, autopilot: 0, readings: tx, last: None };
            return Ok(Self {
                assist,
                readings,
                ended: false,
                joystick: Some(tap),
                ground: Some(ground),
                first_t: None,
                heard: false,
            });
        }
        let input: Box<dyn BufRead + Send> = if source == "-" {
            Box::new(std::io::BufReader::new(std::io::stdin()))
        } else {
            let file = std::fs::File::open(source).map_err(|e| format!("--pilot {source}: {e}"))?;
            Box::new(std::io::BufReader::new(file))
        };
        let (tx, readings) = channel();
        std::thread::Builder::new()
            .name("pilot sticks".into())
            .spawn(move || {
                for line in input.lines() {
                    let reading = match line {
                        Ok(l) if l.trim().is_empty() => continue,
                        Ok(l) => Sticks::from_json(&l),
                        Err(e) => Err(StickError::Malformed(format!("could not be read: {e}"))),
                    };
                    if tx.send((Instant::now(), reading)).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| format!("cannot start the sticks' reader: {e}"))?;
        Ok(Self { assist, readings, ended: false, joystick: None, ground: None, first_t: None, heard: false })
    }

    /// The way in for a ground station's joystick's messages to the autopilot `autopilot`
    /// (once; `None` for sticks read from a file or stdin).
    pub(super) fn joystick_tap(&mut self, autopilot: u8) -> Option<JoystickTap> {
        self.joystick.take().map(|t| JoystickTap { autopilot, ..t })
    }

    /// The readings that came since the last cycle into the assist, each at its own time on
    /// the session's clock (`t` is now); what was refused, and the source's end, in words.
    pub(super) fn take_readings(&mut self, t: f64) -> Vec<String> {
        let now = Instant::now();
        let mut said = Vec::new();
        let first_t = *self.first_t.get_or_insert(t);
        loop {
            match self.readings.try_recv() {
                Ok((arrived, reading)) => {
                    self.heard = true;
                    let at = t - now.saturating_duration_since(arrived).as_secs_f64();
                    if let Err(e) = self.assist.take(at, reading) {
                        said.push(format!("{e}: refused, holding"));
                    }
                }
                Err(TryRecvError::Empty) => {
                    if let Some(ground) = self.ground
                        && !self.heard
                        && t - first_t >= JOYSTICK_SILENCE_S
                    {
                        self.heard = true;
                        said.push(format!(
                            "no MANUAL_CONTROL from system {ground} in {JOYSTICK_SILENCE_S:.0} s: is its joystick \
                             sending, and does the router pass it to pinc's link (docs/PILOT.md)? Holding"
                        ));
                    }
                    break;
                }
                Err(TryRecvError::Disconnected) => {
                    if !self.ended {
                        self.ended = true;
                        said.push("the sticks' source ended: centred sticks from now on (holding)".into());
                    }
                    break;
                }
            }
        }
        said
    }
}
