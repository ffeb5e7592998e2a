//! The pilot's sticks reaching the live session (`mpc_track --connect --pilot`): one JSON
//! object per line from a file or stdin (what `pinc serve` passes its page's gamepad through),
//! read on a thread and stamped when each arrived; every cycle the session hands those that
//! came to the pilot assist at their own time.

use crate::pilot::{PilotAssist, StickError, Sticks};
use std::io::BufRead;
use std::sync::mpsc::{Receiver, TryRecvError, channel};
use std::time::Instant;

/// A reading as it arrived.
type Arrived = (Instant, Result<Sticks, StickError>);

/// The sticks' source and the assist they drive.
pub(super) struct PilotFeed {
    pub(super) assist: PilotAssist,
    readings: Receiver<Arrived>,
    /// Whether the source has ended (said once).
    ended: bool,
}

impl PilotFeed {
    /// Starts reading `source` (`-`: stdin; else a file or a named pipe).
    pub(super) fn open(source: &str, assist: PilotAssist) -> Result<Self, String> {
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
        Ok(Self { assist, readings, ended: false })
    }

    /// The readings that came since the last cycle into the assist, each at its own time on
    /// the session's clock (`t` is now); what was refused, and the source's end, in words.
    pub(super) fn take_readings(&mut self, t: f64) -> Vec<String> {
        let now = Instant::now();
        let mut said = Vec::new();
        loop {
            match self.readings.try_recv() {
                Ok((arrived, reading)) => {
                    let at = t - now.saturating_duration_since(arrived).as_secs_f64();
                    if let Err(e) = self.assist.take(at, reading) {
                        said.push(format!("{e}: refused, holding"));
                    }
                }
                Err(TryRecvError::Empty) => break,
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
