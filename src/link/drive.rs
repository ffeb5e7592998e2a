//! A command session on a live vehicle, shared by `pinc vehicle excite` and
//! `mpc_track --connect`: the cycle is driven by the state's arrival (one command per fresh
//! state sample at most, so the command rate never exceeds the sample rate), every message
//! passes the [`Safety`] watchdog, and any trigger sends the neutral command at once and
//! disarms if the session armed.

use super::command::{Command, CommandWay, Commander};
use super::link::{Autopilot, LinkError, Received, SubMode, VehicleLink, is_ground_station};
use super::safety::{Safety, SafetyLimits, Trigger};
use super::state::{StateEstimate, StateEstimator, message_time};
use crate::types::Input;
use mavlink::dialects::ardupilotmega::MavMessage;
use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// One fresh state sample and when it arrived.
#[derive(Debug, Clone)]
pub struct Fresh {
    /// The state.
    pub state: StateEstimate,
    /// Host time it arrived.
    pub arrived: Instant,
}

/// What was sent for one cycle.
#[derive(Debug, Clone, Copy)]
pub struct Sent {
    /// The command.
    pub command: Command,
    /// Host time it went out.
    pub at: Instant,
    /// Autopilot time (s) it went out.
    pub autopilot_t: f64,
}

/// How a session stopped.
#[derive(Debug, Clone)]
pub struct Stopped {
    /// Why; `None`: the session ran to its end.
    pub trigger: Option<Trigger>,
    /// Autopilot time (s) of the trigger.
    pub t: f64,
    /// Autopilot time (s) the neutral command went out, if it could be sent.
    pub neutral_t: Option<f64>,
    /// Whether a disarm was sent (the session had armed).
    pub disarm_sent: bool,
}

/// A command session.
pub struct Drive {
    link: VehicleLink,
    autopilot: Autopilot,
    estimator: StateEstimator,
    commander: Commander,
    safety: Safety,
    stop: Arc<AtomicBool>,
    armed_by_us: bool,
    /// The newest autopilot stamp per message type, to count what arrives out of order.
    newest: HashMap<&'static str, f64>,
    /// Messages older than the newest of their type (dropped or reordered on the way).
    out_of_order: u64,
    last_sent: Option<f64>,
}

/// How long arming may take to show in a heartbeat.
const ARM_TIMEOUT: Duration = Duration::from_secs(5);
/// The longest one wait for a message lasts, so that a trigger is seen within it.
const POLL: Duration = Duration::from_millis(5);

impl Drive {
    /// Starts a session on an open link whose autopilot was found: MANUAL mode, then, with
    /// `arm`, arming (waiting for the heartbeat to say so). Every message received meanwhile
    /// goes to `seen` with its autopilot time.
    ///
    /// # Errors
    /// The vehicle is disarmed and `arm` is false; arming is not confirmed in 5 s; a trigger
    /// fires meanwhile (Ctrl-C, the link).
    #[allow(clippy::too_many_arguments)]
    pub fn start(
        link: VehicleLink,
        autopilot: Autopilot,
        estimator: StateEstimator,
        commander: Commander,
        limits: SafetyLimits,
        arm: bool,
        stop: Arc<AtomicBool>,
        mut seen: impl FnMut(&Received, f64),
    ) -> Result<Self, Stopped> {
        let now = Instant::now();
        let mut safety = Safety::new(limits, now);
        safety.heartbeat(now, Autopilot::armed(&autopilot.heartbeat));
        let mut d = Self {
            link,
            autopilot,
            estimator,
            commander,
            safety,
            stop,
            armed_by_us: false,
            newest: HashMap::new(),
            out_of_order: 0,
            last_sent: None,
        };
        if let Err(e) = d.link.set_mode(SubMode::Manual) {
            return Err(d.stop_with_trigger(Trigger::Link(e.to_string())));
        }
        if !d.safety.armed() {
            if !arm {
                return Err(d.stop_with_trigger(Trigger::Error(
                    "the vehicle is disarmed: arm it from the ground station, or pass --arm to let pinc arm it".into(),
                )));
            }
            if let Err(e) = d.link.arm(true) {
                return Err(d.stop_with_trigger(Trigger::Link(e.to_string())));
            }
            d.armed_by_us = true;
            let until = Instant::now() + ARM_TIMEOUT;
            while !d.safety.armed() {
                if Instant::now() > until {
                    return Err(d.stop_with_trigger(Trigger::Error(
                        "arming was not confirmed by a heartbeat within 5 s".into(),
                    )));
                }
                if let Err(t) = d.poll(&mut seen) {
                    return Err(d.stop_with_trigger(t));
                }
            }
        }
        Ok(d)
    }

    /// The link.
    pub fn link(&self) -> &VehicleLink {
        &self.link
    }

    /// The state estimator.
    pub fn estimator(&self) -> &StateEstimator {
        &self.estimator
    }

    /// The commander.
    pub fn commander(&self) -> &Commander {
        &self.commander
    }

    /// The way commands go.
    pub fn way(&self) -> CommandWay {
        self.commander.way()
    }

    /// Messages that arrived older than the newest of their type so far (and were dropped by
    /// the state's reconstruction).
    pub fn out_of_order(&self) -> u64 {
        self.out_of_order
    }

    /// Autopilot time now (s).
    pub fn now_t(&self) -> f64 {
        self.estimator.autopilot_time(Instant::now()).unwrap_or(0.0)
    }

    /// Handles one message (or a short silence): the watchdog, the state.
    fn poll(&mut self, seen: &mut impl FnMut(&Received, f64)) -> Result<Option<Fresh>, Trigger> {
        if self.stop.load(Ordering::Relaxed) {
            return Err(Trigger::Interrupted);
        }
        let wait = self.safety.next_deadline().saturating_duration_since(Instant::now()).clamp(Duration::ZERO, POLL);
        let r = self.link.recv_timeout(wait).map_err(|e: LinkError| Trigger::Link(e.to_string()))?;
        let mut fresh = None;
        if let Some(r) = r {
            let from_autopilot = r.header.system_id as u8 == self.autopilot.system_id
                && r.header.component_id == self.autopilot.component_id;
            let state = if from_autopilot {
                if let Some(t) = message_time(&r.message) {
                    let newest = self.newest.entry(mavlink::Message::message_name(&r.message)).or_insert(f64::MIN);
                    if t < *newest {
                        self.out_of_order += 1;
                    }
                    *newest = newest.max(t);
                }
                self.estimator.update(&r)
            } else {
                None
            };
            let t = self.estimator.autopilot_time(r.at).unwrap_or(0.0);
            seen(&r, t);
            if from_autopilot {
                if let MavMessage::HEARTBEAT(h) = &r.message
                    && !is_ground_station(h)
                    && let Some(trigger) = self.safety.heartbeat(r.at, Autopilot::armed(h))
                {
                    return Err(trigger);
                }
                if let Some(s) = state {
                    if let Some(trigger) = self.safety.state(r.at, s.sim[2], s.sim[7]) {
                        return Err(trigger);
                    }
                    fresh = Some(Fresh { state: s, arrived: r.at });
                }
            }
        }
        match self.safety.check(Instant::now(), self.link.malformed()) {
            Some(trigger) => Err(trigger),
            None => Ok(fresh),
        }
    }

    /// Waits for the next fresh state sample, passing every message to `seen` with its
    /// autopilot time.
    ///
    /// # Errors
    /// A safety trigger.
    pub fn next_state(&mut self, mut seen: impl FnMut(&Received, f64)) -> Result<Fresh, Trigger> {
        loop {
            if let Some(f) = self.poll(&mut seen)? {
                return Ok(f);
            }
        }
    }

    /// Sends the command for `input` (at most once per state sample: a second send for the
    /// same state is refused, so the command rate never exceeds the sample rate).
    ///
    /// # Errors
    /// Sending fails (a link trigger), or a command for this state was already sent.
    pub fn send(&mut self, fresh: &Fresh, input: &Input) -> Result<Sent, Trigger> {
        self.send_command(fresh, self.commander.command(input))
    }

    /// Sends the neutral command for this cycle (waiting for a state part, say).
    ///
    /// # Errors
    /// As [`Drive::send`].
    pub fn send_neutral(&mut self, fresh: &Fresh) -> Result<Sent, Trigger> {
        self.send_command(fresh, self.commander.neutral())
    }

    fn send_command(&mut self, fresh: &Fresh, command: Command) -> Result<Sent, Trigger> {
        if self.last_sent.is_some_and(|t| fresh.state.t <= t) {
            return Err(Trigger::Error(format!("a second command for the state at {:.3} s", fresh.state.t)));
        }
        self.commander.send(&self.link, &command).map_err(|e| Trigger::Link(e.to_string()))?;
        let at = Instant::now();
        self.last_sent = Some(fresh.state.t);
        Ok(Sent { command, at, autopilot_t: self.estimator.autopilot_time(at).unwrap_or(fresh.state.t) })
    }

    /// Stops on `trigger`: the neutral command at once, then a disarm if the session armed.
    pub fn abort(&mut self, trigger: Trigger) -> Stopped {
        self.stop(Some(trigger))
    }

    /// Ends a session that ran to its end: neutral, and a disarm if the session armed.
    pub fn finish(&mut self) -> Stopped {
        self.stop(None)
    }

    fn stop_with_trigger(&mut self, trigger: Trigger) -> Stopped {
        self.stop(Some(trigger))
    }

    fn stop(&mut self, trigger: Option<Trigger>) -> Stopped {
        let t = self.now_t();
        let neutral = self.commander.send(&self.link, &self.commander.neutral());
        let neutral_t = neutral.is_ok().then(|| self.now_t());
        let disarm_sent = self.armed_by_us && self.link.arm(false).is_ok();
        // Once more after a moment: UDP may lose one.
        std::thread::sleep(Duration::from_millis(20));
        let _ = self.commander.send(&self.link, &self.commander.neutral());
        if self.armed_by_us {
            let _ = self.link.arm(false);
        }
        Stopped { trigger, t, neutral_t, disarm_sent }
    }

    /// Waits `duration` while passing messages on (after a stop: the last messages into the
    /// recording).
    pub fn drain(&mut self, duration: Duration, mut seen: impl FnMut(&Received, f64)) {
        let until = Instant::now() + duration;
        while Instant::now() < until {
            match self.link.recv_timeout(POLL) {
                Ok(Some(r)) => {
                    let t = self.estimator.autopilot_time(r.at).unwrap_or(0.0);
                    seen(&r, t);
                }
                Ok(None) => {}
                Err(_) => break,
            }
        }
    }
}
