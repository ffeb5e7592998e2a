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
    /// `yaw_rate`, `sensor_lost`, `disarmed`, `malformed`, `link`, `error`.
    pub fn key(&self) -> &'static str {
        match self {
            Trigger::Interrupted => "interrupted",
            Trigger::StaleState { .. } => "stale_state",
            Trigger::HeartbeatLost { .. } => "heartbeat_lost",
            Trigger::Depth { .. } => "depth",
            Trigger::YawRate { .. } => "yaw_rate",
            Trigger::SensorLost { .. } => "sensor_lost",
            Trigger::Disarmed => "disarmed",
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
            Trigger::Malformed { count } => write!(f, "{count} malformed MAVLink frame(s) received"),
            Trigger::Link(e) => write!(f, "link error: {e}"),
            Trigger::Error(e) => write!(f, "error: {e}"),
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
}
