//! The safety watchdog of every command session on a live vehicle (`pinc vehicle excite`,
//! `mpc_track --connect`): the triggers that end a session and what each limit is. On a
//! trigger the session sends the neutral command at once (and disarms if it armed), logs the
//! reason and exits non-zero; see `docs/VEHICLE.md`.

use std::fmt;
use std::time::{Duration, Instant};

/// The limits a session runs under.
#[derive(Debug, Clone, PartialEq)]
pub struct SafetyLimits {
    /// A state sample older than this (host time since the last fresh one arrived) stops the
    /// session.
    pub max_state_age: Duration,
    /// No autopilot heartbeat for this long stops the session (ArduSub sends one a second).
    pub heartbeat_timeout: Duration,
    /// Depth (m, down) beyond which the session stops; `None`: no limit.
    pub max_depth: Option<f64>,
    /// Yaw rate (rad/s, either way) beyond which the session stops.
    pub max_yaw_rate: f64,
    /// Frames that could not be parsed (a valid checksum around bad content) tolerated before
    /// the session stops.
    pub max_malformed: u64,
}

impl Default for SafetyLimits {
    fn default() -> Self {
        Self {
            // Three samples at the control rate of 12.5 Hz.
            max_state_age: Duration::from_millis(250),
            // Two and a half of ArduSub's 1 Hz heartbeats, well before its own 5 s GCS failsafe.
            heartbeat_timeout: Duration::from_millis(2500),
            max_depth: None,
            // Half a turn a second: a pilot rarely turns faster; a spinning vehicle stops.
            max_yaw_rate: std::f64::consts::PI,
            max_malformed: 0,
        }
    }
}

impl SafetyLimits {
    /// The limits as a sentence, for logs.
    pub fn describe(&self) -> String {
        let depth = self.max_depth.map_or_else(|| "no depth limit".to_string(), |d| format!("depth below {d:.2} m"));
        format!(
            "stop on a state older than {:.3} s, no autopilot heartbeat for {:.2} s, {depth}, yaw rate above {:.0} deg/s, \
             more than {} malformed frame(s)",
            self.max_state_age.as_secs_f64(),
            self.heartbeat_timeout.as_secs_f64(),
            self.max_yaw_rate.to_degrees(),
            self.max_malformed
        )
    }
}

/// Why a session stopped.
#[derive(Debug, Clone, PartialEq)]
pub enum Trigger {
    /// Ctrl-C (SIGINT).
    Interrupted,
    /// No fresh state for longer than the limit.
    StaleState {
        /// Seconds since the last fresh state.
        age: f64,
        /// The limit (s).
        limit: f64,
    },
    /// No autopilot heartbeat for longer than the limit.
    HeartbeatLost {
        /// Seconds since the last one.
        silence: f64,
        /// The limit (s).
        limit: f64,
    },
    /// The vehicle went deeper than the limit.
    Depth {
        /// Its depth (m).
        depth: f64,
        /// The limit (m).
        limit: f64,
    },
    /// The vehicle went farther from where control started than the limit.
    Distance {
        /// Its horizontal distance from the start (m).
        distance: f64,
        /// The limit (m).
        limit: f64,
    },
    /// The vehicle turned faster than the limit.
    YawRate {
        /// Its yaw rate (rad/s).
        rate: f64,
        /// The limit (rad/s).
        limit: f64,
    },
    /// A sensor the controller needs went silent (its measurements stopped coming) or froze
    /// (the same reading over and over, as ArduSub sends when its depth sensor is gone).
    SensorLost {
        /// Which (`depth`, `heading`).
        sensor: &'static str,
        /// Seconds since its last measurement, or since its reading last changed.
        age: f64,
        /// The limit (s).
        limit: f64,
        /// Whether the readings kept coming unchanged.
        frozen: bool,
    },
    /// The autopilot disarmed on its own (a failsafe, the pilot).
    Disarmed,
    /// The state estimate no longer follows what the vehicle measures (its measurements gated
    /// out, or far beyond the spread its model predicts): the controller would steer a
    /// vehicle it has lost.
    EstimateLost(String),
    /// The autopilot's configuration does not take the commands asked for (checked before
    /// anything is sent).
    Refused(String),
    /// The autopilot's own estimate did not become usable within the wait.
    NotReady(String),
    /// Frames that could not be parsed arrived.
    Malformed {
        /// How many so far.
        count: u64,
    },
    /// The link failed (closed, a send failed).
    Link(String),
    /// Anything else that went wrong (the controller, the log).
    Error(String),
}

impl Trigger {
    /// A short key for logs and tests: `interrupted`, `stale_state`, `heartbeat_lost`, `depth`,
    /// `distance`, `yaw_rate`, `sensor_lost`, `disarmed`, `estimate_lost`, `refused`, `not_ready`, `malformed`,
    /// `link`, `error`.
    pub fn key(&self) -> &'static str {
        match self {
            Trigger::Interrupted => "interrupted",
            Trigger::StaleState { .. } => "stale_state",
            Trigger::HeartbeatLost { .. } => "heartbeat_lost",
            Trigger::Depth { .. } => "depth",
            Trigger::Distance { .. } => "distance",
            Trigger::YawRate { .. } => "yaw_rate",
            Trigger::SensorLost { .. } => "sensor_lost",
            Trigger::Disarmed => "disarmed",
            Trigger::EstimateLost(_) => "estimate_lost",
            Trigger::Refused(_) => "refused",
            Trigger::NotReady(_) => "not_ready",
            Trigger::Malformed { .. } => "malformed",
            Trigger::Link(_) => "link",
            Trigger::Error(_) => "error",
        }
    }
}

impl fmt::Display for Trigger {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "safety stop [{}]: ", self.key())?;
        match self {
            Trigger::Interrupted => write!(f, "Ctrl-C"),
            Trigger::StaleState { age, limit } => write!(f, "no fresh state for {age:.3} s (limit {limit:.3} s)"),
            Trigger::HeartbeatLost { silence, limit } => {
                write!(f, "no autopilot heartbeat for {silence:.2} s (limit {limit:.2} s)")
            }
            Trigger::Depth { depth, limit } => write!(f, "depth {depth:.2} m beyond the limit {limit:.2} m"),
            Trigger::Distance { distance, limit } => {
                write!(f, "{distance:.2} m from the start, beyond --max-distance {limit:.2} m")
            }
            Trigger::YawRate { rate, limit } => {
                write!(f, "yaw rate {:.1} deg/s beyond the limit {:.1} deg/s", rate.to_degrees(), limit.to_degrees())
            }
            Trigger::SensorLost { sensor, age, limit, frozen: false } => {
                write!(f, "no {sensor} measurement for {age:.3} s (limit {limit:.3} s)")
            }
            Trigger::SensorLost { sensor, age, limit, frozen: true } => write!(
                f,
                "the {sensor} reading has not changed for {age:.3} s (limit {limit:.3} s): the sensor is frozen or gone"
            ),
            Trigger::Disarmed => write!(f, "the autopilot disarmed on its own"),
            Trigger::EstimateLost(why) | Trigger::Refused(why) | Trigger::NotReady(why) => write!(f, "{why}"),
            Trigger::Malformed { count } => write!(f, "{count} malformed MAVLink frame(s) received"),
            Trigger::Link(e) => write!(f, "link error: {e}"),
            Trigger::Error(e) => write!(f, "error: {e}"),
        }
    }
}

/// The sensors a controller cannot do without, watched for silence and for a frozen reading:
/// depth (its sensor, or a position source's depth) and heading.
#[derive(Debug, Clone, Default)]
pub struct SensorWatch {
    last_depth: Option<f64>,
    last_heading: Option<f64>,
    /// The depth reading and the autopilot time it last changed: a pressure sensor in water
    /// never repeats the same value for long; ArduSub repeats the last one when its sensor is
    /// gone.
    depth_changed: Option<(f64, f64)>,
    /// Which of the last 25 readings changed.
    depth_changes: u32,
    /// Whether the current run of repeats began on a live sensor (one whose readings changed
    /// on at least 20 of the 25 before): a simulator without sensor noise repeats its depth at
    /// rest and is not taken as frozen.
    frozen_from_live: bool,
}

const LIVE_WINDOW_MASK: u32 = (1 << 25) - 1;
/// Depth (m) at or above which a repeated reading is not taken as frozen.
const SURFACE_M: f64 = 0.05;
const LIVE_CHANGES: u32 = 20;

impl SensorWatch {
    /// A depth reading at autopilot time `t` from the depth sensor (`from_sensor`; a position
    /// source's depth counts for silence only).
    pub fn depth(&mut self, t: f64, z: f64, from_sensor: bool) {
        self.last_depth = Some(self.last_depth.map_or(t, |l| l.max(t)));
        if !from_sensor {
            return;
        }
        // At the surface a reading may be pinned (a sensor in air, or a simulator that clamps
        // at the surface), and a frozen sensor there endangers nothing: it counts as changing.
        let changed = z <= SURFACE_M || self.depth_changed.is_none_or(|(value, _)| value != z);
        if changed {
            self.depth_changed = Some((z, t));
            self.frozen_from_live = false;
        } else if self.depth_changes.count_ones() >= LIVE_CHANGES {
            // The first repeat of a sensor that was changing on nearly every reading: if the
            // repeats go on, it froze.
            self.frozen_from_live = true;
        }
        self.depth_changes = (self.depth_changes << 1 | u32::from(changed)) & LIVE_WINDOW_MASK;
    }

    /// A heading at autopilot time `t`.
    pub fn heading(&mut self, t: f64) {
        self.last_heading = Some(self.last_heading.map_or(t, |l| l.max(t)));
    }

    /// At autopilot time `now`: a sensor seen before and silent for longer than `silence`, or
    /// a live depth reading unchanged for longer than `frozen`.
    pub fn check(&self, now: f64, silence: f64, frozen: f64) -> Option<Trigger> {
        for (sensor, last) in [("depth", self.last_depth), ("heading", self.last_heading)] {
            if let Some(l) = last
                && now - l > silence
            {
                return Some(Trigger::SensorLost { sensor, age: now - l, limit: silence, frozen: false });
            }
        }
        match self.depth_changed {
            Some((_, since)) if self.frozen_from_live && now - since > frozen => {
                Some(Trigger::SensorLost { sensor: "depth", age: now - since, limit: frozen, frozen: true })
            }
            _ => None,
        }
    }
}

/// The watchdog: fed every heartbeat and state sample, asked at every wake-up.
#[derive(Debug, Clone)]
pub struct Safety {
    limits: SafetyLimits,
    last_heartbeat: Instant,
    last_state: Option<Instant>,
    started: Instant,
    was_armed: bool,
}

impl Safety {
    /// A watchdog starting at `now` (the autopilot's first heartbeat arrived then).
    pub fn new(limits: SafetyLimits, now: Instant) -> Self {
        Self { limits, last_heartbeat: now, last_state: None, started: now, was_armed: false }
    }

    /// The limits.
    pub fn limits(&self) -> &SafetyLimits {
        &self.limits
    }

    /// An autopilot heartbeat at `at`; a disarm after it was seen armed is a trigger.
    pub fn heartbeat(&mut self, at: Instant, armed: bool) -> Option<Trigger> {
        self.last_heartbeat = self.last_heartbeat.max(at);
        let disarmed = self.was_armed && !armed;
        self.was_armed = armed;
        disarmed.then_some(Trigger::Disarmed)
    }

    /// Whether the last heartbeat said armed.
    pub fn armed(&self) -> bool {
        self.was_armed
    }

    /// A fresh state sample received at `at` with depth `z` and yaw rate `r` (NaN: unknown,
    /// not checked).
    pub fn state(&mut self, at: Instant, z: f64, r: f64) -> Option<Trigger> {
        self.last_state = Some(self.last_state.map_or(at, |l| l.max(at)));
        if let Some(limit) = self.limits.max_depth
            && z > limit
        {
            return Some(Trigger::Depth { depth: z, limit });
        }
        (r.abs() > self.limits.max_yaw_rate).then_some(Trigger::YawRate { rate: r, limit: self.limits.max_yaw_rate })
    }

    /// The checks of time: the state's age (once a first state arrived; before it, since the
    /// start), the heartbeat's silence, and the malformed frames counted so far.
    pub fn check(&self, now: Instant, malformed: u64) -> Option<Trigger> {
        let since = |t: Instant| now.saturating_duration_since(t);
        let age = since(self.last_state.unwrap_or(self.started));
        if self.last_state.is_some() && age > self.limits.max_state_age {
            return Some(Trigger::StaleState {
                age: age.as_secs_f64(),
                limit: self.limits.max_state_age.as_secs_f64(),
            });
        }
        let silence = since(self.last_heartbeat);
        if silence > self.limits.heartbeat_timeout {
            return Some(Trigger::HeartbeatLost {
                silence: silence.as_secs_f64(),
                limit: self.limits.heartbeat_timeout.as_secs_f64(),
            });
        }
        (malformed > self.limits.max_malformed).then_some(Trigger::Malformed { count: malformed })
    }

    /// When the state will be too old, if no fresh one comes: the latest a session may sleep.
    pub fn next_deadline(&self) -> Instant {
        let state = self.last_state.map(|l| l + self.limits.max_state_age);
        let beat = self.last_heartbeat + self.limits.heartbeat_timeout;
        state.map_or(beat, |s| s.min(beat))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_limit_triggers_just_past_it_and_not_before() {
        let t0 = Instant::now();
        let ms = |n: u64| t0 + Duration::from_millis(n);
        let limits = SafetyLimits { max_depth: Some(3.0), ..SafetyLimits::default() };
        let mut s = Safety::new(limits, t0);
        assert_eq!(s.check(ms(2000), 0), None, "no state yet: only the heartbeat counts");
        assert_eq!(s.state(ms(100), 2.9, 3.1), None);
        assert_eq!(s.check(ms(350), 0), None);
        assert_eq!(s.check(ms(351), 0).unwrap().key(), "stale_state");
        assert_eq!(s.state(ms(400), 3.1, 0.0).unwrap().key(), "depth");
        assert_eq!(s.state(ms(450), 1.0, -3.2).unwrap().key(), "yaw_rate");
        assert_eq!(s.heartbeat(ms(450), true), None);
        assert_eq!(s.check(ms(2950), 0).map(|t| t.key()), Some("stale_state"));
        s.state(ms(3000), 1.0, 0.0);
        assert_eq!(s.check(ms(3000), 0).unwrap().key(), "heartbeat_lost");
        assert_eq!(s.heartbeat(ms(3000), false), Some(Trigger::Disarmed));
        assert_eq!(s.check(ms(3100), 1).unwrap().key(), "malformed");
    }

    #[test]
    fn a_silent_sensor_and_a_live_depth_that_froze_trigger_and_a_still_noiseless_one_does_not() {
        let mut w = SensorWatch::default();
        assert_eq!(w.check(100.0, 0.5, 1.0), None, "nothing seen: nothing to miss");
        // A noisy live sensor at 12.5 Hz, then the same reading over and over.
        for k in 0..40 {
            let t = f64::from(k) * 0.08;
            w.depth(t, 1.0 + 0.01 * f64::from(k % 7), true);
            w.heading(t);
        }
        let last_change = 39.0 * 0.08;
        for k in 40..60 {
            let t = f64::from(k) * 0.08;
            w.depth(t, 1.0 + 0.01 * f64::from(39 % 7), true);
            w.heading(t);
            let frozen = w.check(t, 0.5, 1.0);
            if t - last_change > 1.0 + 1e-9 {
                assert!(matches!(frozen, Some(Trigger::SensorLost { frozen: true, .. })), "{t}: {frozen:?}");
            } else {
                assert_eq!(frozen, None, "{t}");
            }
        }
        // A depth that never changed (a simulator without noise, at rest) is not frozen.
        let mut still = SensorWatch::default();
        for k in 0..100 {
            still.depth(f64::from(k) * 0.08, 0.13, true);
            still.heading(f64::from(k) * 0.08);
        }
        assert_eq!(still.check(99.0 * 0.08, 0.5, 1.0), None);
        // A live sensor pinned at the surface is not frozen either.
        let mut surfaced = SensorWatch::default();
        for k in 0..100 {
            let z = if k < 40 { 0.5 - 0.01 * f64::from(k) } else { 0.0 };
            surfaced.depth(f64::from(k) * 0.08, z, true);
            surfaced.heading(f64::from(k) * 0.08);
        }
        assert_eq!(surfaced.check(99.0 * 0.08, 0.5, 1.0), None);
        let silent = still.check(99.0 * 0.08 + 0.6, 0.5, 1.0).expect("silent");
        assert!(matches!(silent, Trigger::SensorLost { sensor: "depth", frozen: false, .. }), "{silent:?}");
    }
}
