//! The pilot's sticks reaching the live session (`mpc_track --connect --pilot`): one JSON
//! object per line from a file or stdin (what `pinc serve` passes its page's gamepad through),
//! read on a thread, or a ground station's joystick ([`super::joystick`]); each stamped when it
//! arrived, and every cycle the session hands those that came to the pilot assist at their own
//! time.

use super::Arrived;
use super::joystick::{Joystick, JoystickTap, Poller};
use crate::pilot::{PilotAssist, StickError, Sticks};
use std::io::BufRead;
use std::sync::mpsc::{Receiver, TryRecvError, channel};
use std::time::Instant;

/// How long the first cycles may go without the ground station's joystick before the
/// session says so (Cockpit sends 25 a second while a joystick is plugged in).
const JOYSTICK_SILENCE_S: f64 = 3.0;

/// The sticks' source and the assist they drive.
pub(super) struct PilotFeed {
    pub(super) assist: PilotAssist,
    readings: Receiver<Arrived>,
    /// Whether the source has ended (said once).
    ended: bool,
    /// A ground station's joystick's way in on pinc's link, until the session takes it; or
    /// the thread reading it from mavlink2rest (it stops with the feed).
    joystick: Option<JoystickTap>,
    _poller: Option<Poller>,
    /// That ground station's id; the first cycle's time and whether a reading came since
    /// (a joystick never heard is said once).
    ground: Option<u8>,
    first_t: Option<f64>,
    heard: bool,
}

impl PilotFeed {
    /// Starts reading `source` (`-`: stdin; a ground station's joystick as [`Joystick::of`]
    /// reads it; else a file or a named pipe).
    pub(super) fn open(source: &str, assist: PilotAssist) -> Result<Self, String> {
        if let Some(joystick) = Joystick::of(source)? {
            let (tx, readings) = channel();
            let ground = Some(joystick.ground_station());
            let (tap, poller) = joystick.start(tx)?;
            return Ok(Self::new(assist, readings, tap, poller, ground));
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
        Ok(Self::new(assist, readings, None, None, None))
    }

    fn new(
        assist: PilotAssist,
        readings: Receiver<Arrived>,
        joystick: Option<JoystickTap>,
        poller: Option<Poller>,
        ground: Option<u8>,
    ) -> Self {
        Self { assist, readings, ended: false, joystick, _poller: poller, ground, first_t: None, heard: false }
    }

    /// The way in for a ground station's joystick's messages to the autopilot `autopilot` on
    /// pinc's link (once; `None` for the other sources).
    pub(super) fn joystick_tap(&mut self, autopilot: u8) -> Option<JoystickTap> {
        self.joystick.take().map(|t| t.for_autopilot(autopilot))
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
                             sending, and does it reach pinc (docs/PILOT.md)? Holding"
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pilot::StickLimits;

    #[test]
    fn a_joystick_never_heard_is_said_once_and_the_vehicle_holds() {
        let limits = StickLimits { surge: 0.5, sway: 0.3, heave: 0.3, yaw_rate: 0.3 };
        let mut feed = PilotFeed::open("mavlink:255", PilotAssist::new(limits, (0.0, 10.0))).unwrap();
        // The session keeps the tap for its whole life.
        let _tap = feed.joystick_tap(1).unwrap();
        assert!(feed.take_readings(10.0).is_empty());
        assert!(feed.take_readings(12.9).is_empty());
        let said = feed.take_readings(13.0);
        assert_eq!(said.len(), 1, "{said:?}");
        assert!(said[0].starts_with("no MANUAL_CONTROL from system 255 in 3 s"), "{said:?}");
        assert!(feed.take_readings(20.0).is_empty());
        assert_eq!(feed.assist.commanded(20.0), Sticks::CENTRED);
    }
}
