//! A ground station's joystick as the pilot's sticks: the `MANUAL_CONTROL` that station sends
//! the autopilot (Cockpit: system 255, component 240, 25 a second while a joystick is plugged
//! in), taken one of two ways, while pinc holds the autopilot's ground-station place
//! ([`crate::link::ground_station`]) so the autopilot ignores it:
//!
//! - `mavlink:SYSID`: seen on pinc's own link, where the vehicle's router hands it on. BlueOS's
//!   MAVLink Server hands every message to every link; mavlink-router (BlueOS 1.4's default)
//!   hands a message with a target only to the links that target was heard on, so pinc, a
//!   system of its own, never gets it there.
//! - `http://HOST/.../vehicles/SYSID/components/COMP/messages/MANUAL_CONTROL`: mavlink2rest's
//!   copy of the station's last one, polled. Cockpit sends through mavlink2rest, which keeps
//!   the last message of each sender with a count of those that came; a new count is a new
//!   reading, whatever the router.

use super::Arrived;
use crate::link::Received;
use crate::pilot::{StickError, Sticks};
use mavlink::dialects::ardupilotmega::MavMessage;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Sender;
use std::time::{Duration, Instant};

/// `--pilot`'s prefix for a ground station's joystick on pinc's link.
const LINK_PREFIX: &str = "mavlink:";
/// The least time between two joystick readings passed on: Cockpit sends one every 40 ms; a
/// router may hand on two at once. A faster joystick is thinned to this (more adds nothing to a
/// 12.5 Hz controller, and the assist takes the newest of those between two cycles anyway).
const MIN_GAP: Duration = Duration::from_millis(20);
/// How often mavlink2rest is asked (twice Cockpit's rate), and how long an answer may take.
const POLL: Duration = Duration::from_millis(20);
const ANSWER_TIMEOUT: Duration = Duration::from_millis(250);

/// Where a ground station's joystick is read.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Joystick {
    /// On pinc's link: that station's `MANUAL_CONTROL`.
    Link { ground: u8 },
    /// mavlink2rest's copy of that station's last `MANUAL_CONTROL`, at `url`.
    Rest { url: String, ground: u8 },
}

impl Joystick {
    /// The joystick `source` names, if it names one.
    ///
    /// # Errors
    /// `mavlink:` not followed by a system id 1..=255; an `http://` address that is not a
    /// mavlink2rest `MANUAL_CONTROL` of one sender.
    pub(super) fn of(source: &str) -> Result<Option<Self>, String> {
        if let Some(id) = source.strip_prefix(LINK_PREFIX) {
            return match id.parse::<u8>() {
                Ok(ground) if ground > 0 => Ok(Some(Self::Link { ground })),
                _ => Err(format!(
                    "--pilot {source}: a ground station's joystick is mavlink:SYSID, its system id 1..255 (Cockpit's: 255)"
                )),
            };
        }
        if !source.starts_with("http://") {
            return Ok(None);
        }
        let ids: Vec<&str> = source.trim_end_matches('/').rsplit('/').take(6).collect();
        match ids[..] {
            ["MANUAL_CONTROL", "messages", _, "components", id, "vehicles"] => match id.parse::<u8>() {
                Ok(ground) if ground > 0 => Ok(Some(Self::Rest { url: source.to_string(), ground })),
                _ => Err(format!("--pilot {source}: the vehicle id {id} is not a system id 1..255")),
            },
            _ => Err(format!(
                "--pilot {source}: a joystick through mavlink2rest is its address of one sender's MANUAL_CONTROL, \
                 .../v1/mavlink/vehicles/SYSID/components/COMP/messages/MANUAL_CONTROL (Cockpit: 255 and 240)"
            )),
        }
    }

    /// The ground station's system id.
    pub(super) fn ground_station(&self) -> u8 {
        match self {
            Self::Link { ground } | Self::Rest { ground, .. } => *ground,
        }
    }

    /// Starts reading into `readings`: the tap the session hands its link's messages to, or the
    /// thread polling mavlink2rest (it ends with the [`Poller`]).
    ///
    /// # Errors
    /// The thread cannot start.
    pub(super) fn start(self, readings: Sender<Arrived>) -> Result<(Option<JoystickTap>, Option<Poller>), String> {
        match self {
            Self::Link { ground } => Ok((Some(JoystickTap { ground, autopilot: 0, readings, last: None }), None)),
            Self::Rest { url, .. } => {
                let stop = Arc::new(AtomicBool::new(false));
                let stopped = stop.clone();
                std::thread::Builder::new()
                    .name("joystick (mavlink2rest)".into())
                    .spawn(move || poll(&url, &readings, &stopped))
                    .map_err(|e| format!("cannot start the joystick's reader: {e}"))?;
                Ok((None, Some(Poller { stop })))
            }
        }
    }
}

/// The ground station whose joystick `source` (as `--pilot` takes it) names, if it names one:
/// `mavlink:SYSID`, or a mavlink2rest address of one sender's `MANUAL_CONTROL`.
///
/// # Errors
/// `mavlink:` not followed by a system id 1..=255; an `http://` address that is not such an
/// address.
pub fn ground_station_of(source: &str) -> Result<Option<u8>, String> {
    Ok(Joystick::of(source)?.map(|j| j.ground_station()))
}

/// Where the session passes a ground station's `MANUAL_CONTROL` on its link to the assist.
pub(super) struct JoystickTap {
    /// The ground station's system id, and the autopilot's its messages are for.
    ground: u8,
    autopilot: u8,
    readings: Sender<Arrived>,
    /// When the last reading was passed on: one sooner than [`MIN_GAP`] after it is left out,
    /// the next one carries the stick on.
    last: Option<Instant>,
}

impl JoystickTap {
    /// The tap for the station's messages to `autopilot` (its id is known once the link found it).
    pub(super) fn for_autopilot(self, autopilot: u8) -> Self {
        Self { autopilot, ..self }
    }

    /// Passes `r` on if it is the ground station's joystick for the autopilot.
    pub(super) fn see(&mut self, r: &Received) {
        let MavMessage::MANUAL_CONTROL(m) = &r.message else { return };
        if r.header.system_id != u32::from(self.ground) || m.target != self.autopilot {
            return;
        }
        if self.last.is_some_and(|last| r.at.saturating_duration_since(last) < MIN_GAP) {
            return;
        }
        self.last = Some(r.at);
        let _ = self.readings.send((r.at, Sticks::from_manual_control(m.x, m.y, m.z, m.r)));
    }
}

/// Stops the mavlink2rest poller when dropped.
pub(super) struct Poller {
    stop: Arc<AtomicBool>,
}

impl Drop for Poller {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// One message as mavlink2rest keeps it: how many of its kind came, and its sticks, checked.
type Counted = (i64, Result<Sticks, StickError>);

/// What one answer of mavlink2rest holds (`None`: no such message yet, mavlink2rest's `None`).
fn reading_of(body: &str) -> Result<Option<Counted>, String> {
    if body.trim() == "None" {
        return Ok(None);
    }
    let v: serde_json::Value = serde_json::from_str(body).map_err(|e| format!("not JSON: {e}"))?;
    let count =
        v.pointer("/status/time/counter").and_then(serde_json::Value::as_i64).ok_or("no status.time.counter")?;
    let m = v.get("message").ok_or("no message")?;
    if m.get("type").and_then(serde_json::Value::as_str) != Some("MANUAL_CONTROL") {
        return Err(format!("not a MANUAL_CONTROL: {}", m.get("type").unwrap_or(&serde_json::Value::Null)));
    }
    let axis = |name: &str| {
        m.get(name)
            .and_then(serde_json::Value::as_i64)
            .and_then(|a| i16::try_from(a).ok())
            .ok_or_else(|| format!("MANUAL_CONTROL.{name} is not a 16-bit integer"))
    };
    Ok(Some((count, Sticks::from_manual_control(axis("x")?, axis("y")?, axis("z")?, axis("r")?))))
}

/// Asks `url` every [`POLL`] until `stop`, passing each new message on as it is first seen.
/// What goes wrong is passed on once as a refused reading (the assist holds), until an answer
/// is good again.
fn poll(url: &str, readings: &Sender<Arrived>, stop: &AtomicBool) {
    let agent: ureq::Agent =
        ureq::Agent::config_builder().timeout_global(Some(ANSWER_TIMEOUT)).http_status_as_error(false).build().into();
    let (mut last_count, mut failing) = (None, false);
    let mut next = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        let answer = match agent.get(url).call() {
            Ok(mut r) if r.status() == 200 => r.body_mut().read_to_string().map_err(|e| e.to_string()),
            Ok(r) => Err(format!("HTTP {}", r.status())),
            Err(e) => Err(e.to_string()),
        };
        let at = Instant::now();
        let sent = match answer.and_then(|body| reading_of(&body)) {
            Ok(Some((count, sticks))) => {
                failing = false;
                // The first answer is the station's last message, however old: only a new one is a reading.
                let new = last_count.is_some_and(|c| c != count);
                last_count = Some(count);
                !new || readings.send((at, sticks)).is_ok()
            }
            Ok(None) => true,
            Err(why) if !failing => {
                failing = true;
                readings.send((at, Err(StickError::Source(format!("the joystick at {url}: {why}"))))).is_ok()
            }
            Err(_) => true,
        };
        if !sent {
            return;
        }
        // A slow answer is not made up for with a burst of requests.
        next = (next + POLL).max(Instant::now());
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_joystick_is_named_by_its_station_on_the_link_or_at_mavlink2rest() {
        assert_eq!(Joystick::of("mavlink:255"), Ok(Some(Joystick::Link { ground: 255 })));
        assert_eq!(Joystick::of("-"), Ok(None));
        assert_eq!(Joystick::of("sticks.jsonl"), Ok(None));
        assert!(Joystick::of("mavlink:0").unwrap_err().contains("1..255"));
        assert!(Joystick::of("mavlink:cockpit").is_err());
        let url = "http://127.0.0.1:6040/v1/mavlink/vehicles/255/components/240/messages/MANUAL_CONTROL";
        assert_eq!(Joystick::of(url), Ok(Some(Joystick::Rest { url: url.into(), ground: 255 })));
        assert!(Joystick::of("http://127.0.0.1:6040/v1/mavlink/vehicles/255").unwrap_err().contains("MANUAL_CONTROL"));
        assert!(Joystick::of(&url.replace("/255/", "/300/")).unwrap_err().contains("300"));
    }

    #[test]
    fn mavlink2rests_answer_gives_the_count_and_the_sticks() {
        // The shape mavlink2rest keeps a message in (its data.rs): the message tagged with its
        // type, and how many came.
        let body = r#"{"message": {"type": "MANUAL_CONTROL", "target": 1, "x": 500, "y": -1000, "z": 750,
            "r": 0, "buttons": 0}, "status": {"time": {"first_update": "2026-11-28T16:00:00+00:00",
            "last_update": "2026-11-28T16:00:01+00:00", "counter": 27, "frequency": 25.0}}}"#;
        let (count, sticks) = reading_of(body).unwrap().unwrap();
        assert_eq!(count, 27);
        assert_eq!(sticks.map(|s| s.axes()), Ok([0.5, -1.0, -0.5, 0.0]));
        assert_eq!(reading_of("None"), Ok(None));
        assert!(reading_of(&body.replace("MANUAL_CONTROL", "HEARTBEAT")).unwrap_err().contains("HEARTBEAT"));
        assert!(reading_of(&body.replace("\"x\": 500", "\"x\": 40000")).unwrap_err().contains("MANUAL_CONTROL.x"));
        let (_, past) = reading_of(&body.replace("\"x\": 500", "\"x\": 1500")).unwrap().unwrap();
        assert!(matches!(past, Err(StickError::OutOfRange { axis: "surge", .. })));
    }
}
