//! A session's recording: every message, the state samples with their inputs, the estimate
//! and the `/log` lines, for `record` and `excite`.

use crate::closed_loop::Level;
use crate::estimation::mavlink::Observation;
use crate::estimation::{Estimate, Estimator, NoiseSettings};
use crate::link::drive::{severity_level, statustext};
use crate::link::state::message_time;
use crate::link::{Autopilot, Capability, InputsFromOutputs, Received, Recorder, SubMode};
use crate::vehicle::{Rk4Vehicle, VehicleParams};
use mavlink::dialects::ardupilotmega::{HEARTBEAT_DATA, MavMessage};
use std::time::Instant;
/// The state estimator of a recording: the analytic vehicle of the vehicle file, fed what
/// every message measured; its estimate is written beside each raw state sample.
pub(super) fn recording_estimator(vehicle: &std::path::Path, dt: f64) -> Result<Estimator<Rk4Vehicle>, String> {
    let params = VehicleParams::load(vehicle).map_err(|e| e.to_string())?;
    Ok(Estimator::new(Rk4Vehicle { params, ..Rk4Vehicle::with_dt(dt) }, NoiseSettings::default()))
}

/// Writes a session into its recording: every message, the state samples with their body
/// input (from the thruster outputs when a vehicle file is given), the `/log` lines.
pub(super) struct Writer {
    pub(super) rec: Recorder,
    pub(super) estimation: Option<Estimator<Rk4Vehicle>>,
    notes: Session,
    autopilot: Autopilot,
    inputs: Option<InputsFromOutputs>,
    /// Messages before the autopilot's clock is known, written at their times once it is.
    pending: Vec<Received>,
    clock: Option<(f64, Instant)>,
}

impl Writer {
    pub(super) fn new(
        rec: Recorder,
        autopilot: Autopilot,
        inputs: Option<InputsFromOutputs>,
        pending: Vec<Received>,
    ) -> Self {
        let notes = Session { last_heartbeat: None, capability: None, log: Vec::new() };
        Self { rec, estimation: None, notes, autopilot, inputs, pending, clock: None }
    }

    /// One message received, at autopilot time `t` (meaningless until a stamped message came).
    pub(super) fn message(&mut self, r: &Received, t: f64) -> Result<(), String> {
        if self.clock.is_none() {
            if message_time(&r.message).is_none() || !self.autopilot.sent(r) {
                self.pending.push(r.clone());
                return Ok(());
            }
            self.clock = Some((t, r.at));
        }
        let (t0, at0) = self.clock.expect("set above");
        for p in std::mem::take(&mut self.pending) {
            let back = at0.saturating_duration_since(p.at).as_secs_f64();
            self.one(&p, (t0 - back).max(0.0))?;
        }
        self.one(r, t)
    }

    fn one(&mut self, r: &Received, t: f64) -> Result<(), String> {
        // A write error ends the session: the unfinished file is removed (`Recorder`'s drop).
        write_one(&mut self.rec, &mut self.notes, &self.autopilot, t, r)?;
        self.flush_log()
    }

    /// What the autopilot's messages measured and the inputs they say were applied (read
    /// once, by the state's assembler), up to autopilot time `now` (s).
    pub(super) fn observed(
        &mut self,
        now: f64,
        observations: impl IntoIterator<Item = Observation>,
    ) -> Result<(), String> {
        if self.clock.is_none() {
            return Ok(()); // nothing is on the autopilot's time line yet
        }
        let mut outputs = false;
        for o in observations {
            match o {
                Observation::Measured(m) => {
                    if let Some(e) = &mut self.estimation {
                        e.measure(m);
                    }
                }
                Observation::Applied(t, u) => {
                    outputs = true;
                    if let Some(e) = &mut self.estimation {
                        e.applied(t, u);
                    }
                    if let Some(p) = &mut self.inputs {
                        p.applied(t, u);
                    }
                }
                Observation::Unfused(_) => {}
            }
        }
        // New outputs may complete the input of states waiting for it (a state's own arrival
        // releases those whose outputs stopped).
        if let (true, Some(p)) = (outputs, &mut self.inputs) {
            for (s, u) in p.ready(now) {
                self.rec.state(&s, u.as_ref()).map_err(|e| e.to_string())?;
            }
        }
        Ok(())
    }

    /// A fresh state sample; the state estimate at it, once the estimator runs.
    pub(super) fn state(&mut self, s: &crate::link::RawState) -> Result<Option<Estimate>, String> {
        self.notes.note_capability(s.t, s.capability);
        let mut out = None;
        if let Some(e) = &mut self.estimation {
            match e.advance(s.t) {
                Ok(Some(estimate)) => {
                    self.rec.estimate(&estimate).map_err(|e| e.to_string())?;
                    out = Some(estimate);
                }
                Ok(None) => {}
                Err(err) => self.notes.log.push((s.t, Level::Warning, format!("state estimator: {err}"))),
            }
        }
        match &mut self.inputs {
            None => self.rec.state(s, None).map_err(|e| e.to_string())?,
            Some(p) => {
                p.state(s.clone());
                for (s, u) in p.ready(s.t) {
                    self.rec.state(&s, u.as_ref()).map_err(|e| e.to_string())?;
                }
            }
        }
        self.flush_log()?;
        Ok(out)
    }

    fn flush_log(&mut self) -> Result<(), String> {
        for (t, level, line) in self.notes.log.drain(..) {
            self.rec.log(t, level, &line).map_err(|e| e.to_string())?;
        }
        Ok(())
    }

    pub(super) fn log(&mut self, t: f64, level: Level, line: &str) -> Result<(), String> {
        self.rec.log(t, level, line).map_err(|e| e.to_string())
    }

    /// Writes what is pending and the last line, and finishes the file.
    pub(super) fn finish(mut self, t: f64, level: Level, line: &str) -> Result<crate::link::RecordStats, String> {
        if let Some(p) = &mut self.inputs {
            for (s, u) in p.flush() {
                self.rec.state(&s, u.as_ref()).map_err(|e| e.to_string())?;
            }
        }
        self.flush_log()?;
        self.rec.log(t, level, line).map_err(|e| e.to_string())?;
        self.rec.finish().map_err(|e| e.to_string())
    }
}

/// What the recording logs about the session as it goes.
struct Session {
    last_heartbeat: Option<HEARTBEAT_DATA>,
    capability: Option<Capability>,
    log: Vec<(f64, Level, String)>,
}

impl Session {
    fn note_heartbeat(&mut self, t: f64, h: &HEARTBEAT_DATA) {
        let (mode, armed) = (SubMode::name_of(h.custom_mode), Autopilot::armed(h));
        let line = match &self.last_heartbeat {
            None => Some(format!("autopilot in {mode}, {}", if armed { "armed" } else { "disarmed" })),
            Some(old) => {
                let mut changes = Vec::new();
                if old.custom_mode != h.custom_mode {
                    changes.push(format!("mode {} -> {mode}", SubMode::name_of(old.custom_mode)));
                }
                if Autopilot::armed(old) != armed {
                    changes.push(if armed { "armed".to_string() } else { "disarmed".to_string() });
                }
                (!changes.is_empty()).then(|| changes.join(", "))
            }
        };
        if let Some(line) = line {
            self.log.push((t, Level::Info, line));
        }
        self.last_heartbeat = Some(h.clone());
    }

    fn note_capability(&mut self, t: f64, c: Capability) {
        if self.capability != Some(c) {
            let level = if c == Capability::Full { Level::Info } else { Level::Warning };
            self.log.push((t, level, format!("state: {c}")));
            self.capability = Some(c);
        }
    }
}

fn write_one(
    rec: &mut Recorder,
    session: &mut Session,
    autopilot: &Autopilot,
    t: f64,
    r: &Received,
) -> Result<(), String> {
    rec.mavlink(t, r).map_err(|e| e.to_string())?;
    if autopilot.sent(r) {
        match &r.message {
            MavMessage::SERVO_OUTPUT_RAW(o) => rec.outputs(t, o).map_err(|e| e.to_string())?,
            MavMessage::HEARTBEAT(h) => session.note_heartbeat(t, h),
            MavMessage::STATUSTEXT(s) => {
                let (level, name) = severity_level(s.severity);
                session.log.push((t, level, format!("autopilot {name}: {}", statustext(s))));
            }
            _ => {}
        }
    }
    Ok(())
}
