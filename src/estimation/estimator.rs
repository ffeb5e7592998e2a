//! The filter on a stream of stamped measurements and applied inputs, as a controller (or a
//! log replay) sees them: measurements are queued as they arrive and fused at the next
//! sample, the filter steps on the model's grid with the input applied over each step (each
//! thruster output reported held from its report to the next, weighted by how long it held
//! within the step; else the command sent), and it starts itself
//! once heading, yaw rate and depth have been seen.

use super::ekf::{Ekf, Estimate, FilterCounts, HorizontalDisturbance, Update};
use super::measurement::{Measurement, NoiseSettings};
use super::navigation::{DEFAULT_DEAD_RECKONING_BOUND_M, Navigation, larger_variance};
use super::smoother::{ForwardStep, Prediction, Smoothed, rts, std_of};
use crate::runtime::RuntimeError;
use crate::traits::DiscreteModel;
use crate::types::{Input, NS, SimState};

/// The longest gap (s) the filter bridges by prediction alone; past it, it restarts from the
/// next measurements.
pub const MAX_GAP_S: f64 = 2.0;
/// Horizontal motion counts as observed while a position or velocity was fused this recently
/// (s).
pub const HORIZONTAL_FRESH_S: f64 = 1.0;
/// How late (s) a position fix may come and still be fused at the time it was measured.
pub const MAX_FIX_LATENCY_S: f64 = 2.0;
/// Past estimated positions kept for late fixes: [`MAX_FIX_LATENCY_S`] at 12.5 Hz and more.
const PAST: usize = 32;
/// Capacity of the queues, enough for several samples' worth of every stream; beyond it the
/// oldest are fused early rather than allocating.
const QUEUE: usize = 256;

/// The state estimator of a vehicle: an [`Ekf`] fed in time.
pub struct Estimator<M: DiscreteModel> {
    ekf: Ekf<M>,
    started: bool,
    pending: Vec<Measurement>,
    /// Inputs reported by the vehicle (its thruster outputs) since the last step.
    reported: Vec<(f64, Input)>,
    /// The input last commanded: used where no output was reported.
    commanded: Input,
    /// The newest reported input, and whether a command came after it: a step without a
    /// report holds the newer of the two (a log replay has reports only).
    last_reported: Option<Input>,
    commanded_since_report: bool,
    /// The reported output in force at the filter's time: the last report at or before it.
    in_force: Option<Input>,
    last_horizontal: Option<f64>,
    /// Whether a position (the autopilot's, or a fix) placed the estimate yet: until one did,
    /// the first fix defines its frame rather than fixing an offset to an unplaced estimate.
    placed: bool,
    /// When a velocity (a DVL's, the autopilot's) was last fused.
    last_velocity: Option<f64>,
    /// The larger variance of the horizontal position at the last horizontal fusion.
    horizontal_variance_then: f64,
    dead_reckoning_bound: f64,
    /// The estimated `(t, north, east)` of the last [`PAST`] steps, a ring: where a late fix
    /// is compared.
    past: [(f64, f64, f64); PAST],
    past_next: usize,
    late_fixes: u64,
    late: u64,
    restarts: u64,
    /// The last depth reading, and how many exact repeats of it were left out.
    last_depth: Option<f64>,
    repeated: u64,
    /// The forward pass, kept for a smoother when asked for ([`Estimator::keep_history`]).
    history: Option<Vec<ForwardStep>>,
}

impl<M: DiscreteModel> Estimator<M> {
    /// An estimator on `model` with `noise`.
    pub fn new(model: M, noise: NoiseSettings) -> Self {
        Self {
            ekf: Ekf::new(model, noise),
            started: false,
            pending: Vec::with_capacity(QUEUE),
            reported: Vec::with_capacity(QUEUE),
            commanded: Input::zeros(),
            last_reported: None,
            commanded_since_report: false,
            in_force: None,
            last_horizontal: None,
            placed: false,
            last_velocity: None,
            horizontal_variance_then: 0.0,
            dead_reckoning_bound: DEFAULT_DEAD_RECKONING_BOUND_M,
            past: [(f64::NEG_INFINITY, 0.0, 0.0); PAST],
            past_next: 0,
            late_fixes: 0,
            late: 0,
            restarts: 0,
            last_depth: None,
            repeated: 0,
            history: None,
        }
    }

    /// Dead reckoning may add at most `bound` (m, one standard deviation) to the horizontal
    /// uncertainty before the horizontal estimate counts as lost (0: lost as soon as nothing
    /// horizontal is measured for [`HORIZONTAL_FRESH_S`]).
    pub fn with_dead_reckoning_bound(mut self, bound: f64) -> Self {
        self.dead_reckoning_bound = bound;
        self
    }

    /// The dead reckoning bound (m).
    pub fn dead_reckoning_bound(&self) -> f64 {
        self.dead_reckoning_bound
    }

    /// Keeps every step of the forward pass (a recorded log's replay), for
    /// [`Estimator::smoothed`]. Allocates as it goes: not for a control loop.
    pub fn keep_history(mut self) -> Self {
        self.history = Some(Vec::new());
        self
    }

    /// The smoothed estimates of every step kept so far (each unbroken run smoothed on its
    /// own); empty without [`Estimator::keep_history`].
    pub fn smoothed(&self) -> Vec<Smoothed> {
        let Some(h) = &self.history else { return Vec::new() };
        let mut out = Vec::with_capacity(h.len());
        let mut start = 0;
        for k in 0..h.len() {
            if h[k].next.is_none() {
                out.extend(rts(&h[start..=k]));
                start = k + 1;
            }
        }
        out
    }

    /// The filter's own estimates of every step kept so far (what it knew at each step, before
    /// smoothing); empty without [`Estimator::keep_history`].
    pub fn filtered(&self) -> Vec<Smoothed> {
        let Some(h) = &self.history else { return Vec::new() };
        h.iter()
            .map(|s| Smoothed {
                t: s.t,
                state: s.filtered,
                std: std_of(&s.filtered_p),
                input: s.next.as_ref().map(|n| n.input),
            })
            .collect()
    }

    fn record_start(&mut self) {
        if let Some(h) = &mut self.history {
            let (x, p) = (*self.ekf.state(), *self.ekf.covariance());
            h.push(ForwardStep { t: self.ekf.t(), filtered: x, filtered_p: p, next: None });
        }
    }

    /// The filter.
    pub fn ekf(&self) -> &Ekf<M> {
        &self.ekf
    }

    /// Whether the filter has started.
    pub fn started(&self) -> bool {
        self.started
    }

    /// Queues a measurement. A depth reading exactly equal to the one before is left out
    /// (and counted): a sensor read faster than it updates repeats its last value under a new
    /// stamp (ArduSub's simulator sends its 10 Hz depth at 12.5 Hz, every fifth a repeat), and
    /// fused at that stamp the old value delays the heave estimate. A frozen sensor is the
    /// session's safety stop to catch, not the filter's.
    pub fn measure(&mut self, m: Measurement) {
        if let Measurement::Depth { z, .. } = m {
            if self.last_depth == Some(z) {
                self.repeated += 1;
                return;
            }
            self.last_depth = Some(z);
        }
        if self.pending.len() == QUEUE {
            self.pending.remove(0);
            self.late += 1;
        }
        self.pending.push(m);
    }

    /// The input the vehicle reported applying at `t` (its thruster outputs through the
    /// vehicle file's thrusters).
    pub fn applied(&mut self, t: f64, input: Input) {
        if self.reported.len() == QUEUE {
            self.reported.remove(0);
        }
        self.reported.push((t, input));
        self.last_reported = Some(input);
        self.commanded_since_report = false;
    }

    /// The input just commanded (held until the next command).
    pub fn commanded(&mut self, input: Input) {
        self.commanded = input;
        self.commanded_since_report = true;
    }

    /// Measurements that came later than the step they belonged to and were dropped.
    pub fn late(&self) -> u64 {
        self.late
    }

    /// Depth readings left out as repeats of the one before.
    pub fn repeated(&self) -> u64 {
        self.repeated
    }

    /// Times the filter restarted after a gap longer than [`MAX_GAP_S`].
    pub fn restarts(&self) -> u64 {
        self.restarts
    }

    /// The filter's counters.
    pub fn counts(&self) -> FilterCounts {
        self.ekf.counts()
    }

    /// Position fixes that came after the step they were measured in and were fused against
    /// the estimate of their own time.
    pub fn late_fixes(&self) -> u64 {
        self.late_fixes
    }

    /// Takes the DVL's velocity noise (m/s) as measured on its own readings.
    pub fn set_velocity_body_std(&mut self, std: f64) {
        self.ekf.set_velocity_body_std(std);
    }

    /// Sets the process noise on the horizontal position (m per step; see
    /// [`Ekf::set_position_process_std`]).
    pub fn set_position_process_std(&mut self, std: f64) {
        self.ekf.set_position_process_std(std);
    }

    /// The process noise on the horizontal position (m per step).
    pub fn position_process_std(&self) -> f64 {
        self.ekf.noise().process_std[0]
    }

    /// The DVL's mounting as measured (see [`Ekf::set_dvl_mounting`]).
    pub fn set_dvl_mounting(&mut self, yaw: f64, yaw_std: f64, scale: f64, scale_std: f64) {
        self.ekf.set_dvl_mounting(yaw, yaw_std, scale, scale_std);
    }

    /// Whether a position or velocity was fused within [`HORIZONTAL_FRESH_S`] of `t`.
    pub fn horizontal_observed(&self, t: f64) -> bool {
        self.last_horizontal.is_some_and(|l| t - l <= HORIZONTAL_FRESH_S)
    }

    /// A velocity over the ground (a DVL's) is measured now, fused here or through the
    /// autopilot's own estimate: the horizontal disturbance is a current observed directly
    /// ([`Ekf::ground_velocity_measured`]).
    pub fn ground_velocity_measured(&mut self) {
        self.ekf.ground_velocity_measured();
    }

    /// The horizontal position's standard deviation now (m): the larger of the `x y`
    /// covariance's axes.
    pub fn horizontal_std(&self) -> f64 {
        self.horizontal_variance().max(0.0).sqrt()
    }

    fn horizontal_variance(&self) -> f64 {
        let p = self.ekf.covariance();
        larger_variance(p[(0, 0)], p[(0, 1)], p[(1, 1)])
    }

    /// The horizontal estimate's standing at `t` (see [`Navigation`]).
    pub fn navigation(&self, t: f64) -> Navigation {
        match self.last_horizontal {
            None => Navigation::Lost,
            Some(_) if self.horizontal_observed(t) => Navigation::Measured,
            Some(since) => {
                let std = (self.horizontal_variance() - self.horizontal_variance_then).max(0.0).sqrt();
                if self.started && std <= self.dead_reckoning_bound {
                    Navigation::DeadReckoning { since, std }
                } else {
                    Navigation::Lost
                }
            }
        }
    }

    /// The estimated north and east at `t` (the nearest step kept), for a fix measured then.
    fn position_then(&self, t: f64) -> Option<(f64, f64)> {
        let dt = self.ekf.model().dt();
        self.past
            .iter()
            .filter(|(tp, ..)| (tp - t).abs() <= 0.5 * dt + 1e-9)
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
            .map(|&(_, n, e)| (n, e))
    }

    fn remember_position(&mut self) {
        let x = self.ekf.state();
        self.past[self.past_next] = (self.ekf.t(), x[0], x[1]);
        self.past_next = (self.past_next + 1) % PAST;
    }

    /// The applied input over the step from `t_end - dt` to `t_end`: each reported output
    /// held from its report's time to the next, weighted by how long it held within the step
    /// (the mean of the reports, as before, took the step's last output for the whole step:
    /// on the firmware's 50 Hz SERVO_OUTPUT_RAW, 20 ms early on average); else the newer of
    /// the last report (outputs hold) and the command.
    fn step_input(&mut self, t_end: f64, dt: f64) -> Input {
        let t_start = t_end - dt;
        let (mut held, mut from) = (self.in_force, t_start);
        let (mut sum, mut covered, mut n) = (Input::zeros(), 0.0, 0);
        self.reported.retain(|&(t, u)| {
            if t > t_end + 1e-9 {
                return true;
            }
            let t = t.clamp(t_start, t_end);
            if let Some(h) = held {
                sum += h * (t - from);
                covered += t - from;
            }
            (held, from) = (Some(u), t);
            n += 1;
            false
        });
        if let Some(h) = held {
            sum += h * (t_end - from);
            covered += t_end - from;
        }
        self.in_force = held;
        match (n, self.last_reported) {
            (0, Some(last)) if !self.commanded_since_report => last,
            (0, _) => self.commanded,
            // Reports all at the step's end (a log's coarse clock): their last.
            _ if covered <= 1e-9 => held.unwrap_or(self.commanded),
            _ => sum / covered,
        }
    }

    /// Starts from the newest of each measured part, if heading, yaw rate and depth are among
    /// them.
    fn try_start(&mut self, t: f64) {
        let (mut psi, mut r, mut z, mut pos, mut vel, mut down) = (None, None, None, None, None, None);
        let mut on_fix = false;
        for m in &self.pending {
            match *m {
                Measurement::Heading { psi: p, .. } => psi = Some(p),
                Measurement::YawRate { r: v, .. } => r = Some(v),
                Measurement::Depth { z: d, .. } => z = Some(d),
                Measurement::Position { x, y, z: d, .. } => {
                    (pos, on_fix) = (Some((x, y)), false);
                    z = z.or(Some(d));
                }
                Measurement::Fix { x, y, .. } => (pos, on_fix) = (Some((x, y)), true),
                Measurement::VelocityNed { vn, ve, vd, .. } => vel = Some((vn, ve, vd)),
                Measurement::VerticalVelocity { vd, .. } => down = Some(vd),
                Measurement::VelocityBody { .. } => {}
            }
        }
        let (Some(psi), Some(r), Some(z)) = (psi, r, z) else { return };
        let (s, c) = psi.sin_cos();
        let (u, v, w) = vel.map_or((0.0, 0.0, 0.0), |(vn, ve, vd)| (c * vn + s * ve, -s * vn + c * ve, vd));
        let w = down.unwrap_or(w);
        // A fix is of the sensor's frame: the estimate's lies its offset away, once one is known
        // (a restart); with none known the fixes define the estimate's frame.
        if on_fix && !self.ekf.fix_offset_known() {
            self.ekf.define_frame_by_fixes();
        }
        let offset = self.ekf.estimate().fix_offset.0;
        let (x, y) = match pos {
            Some((x, y)) if on_fix => (x - offset[0], y - offset[1]),
            Some(p) => p,
            None => (0.0, 0.0),
        };
        let sim = SimState::from([x, y, z, psi, u, v, w, r]);
        // Unknown horizontal position: a wide prior; velocities at rest within 0.3 m/s.
        let pos_std = if pos.is_some() { self.ekf.noise().position_std } else { 100.0 };
        let noise = self.ekf.noise().clone();
        let std: [f64; NS] = [pos_std, pos_std, noise.depth_std, noise.heading_std, 0.3, 0.3, 0.3, noise.yaw_rate_std];
        self.ekf.reset(t, &sim, &std);
        self.started = true;
        // Dead reckoning counts from a horizontal measurement of this run.
        self.last_horizontal = pos.map(|_| t);
        self.placed |= pos.is_some();
        self.last_velocity = vel.map(|_| t);
        self.horizontal_variance_then = self.horizontal_variance();
    }

    /// Brings the estimate to time `t` (s): whole model steps from the filter's time, then
    /// every queued measurement. `None` until the filter could start.
    ///
    /// # Errors
    /// The model failed on the estimate (non-finite values).
    pub fn advance(&mut self, t: f64) -> Result<Option<Estimate>, RuntimeError> {
        let dt = self.ekf.model().dt();
        if self.started && (t - self.ekf.t() > MAX_GAP_S || t < self.ekf.t() - MAX_GAP_S) {
            self.started = false;
            self.restarts += 1;
        }
        if !self.started {
            self.try_start(t);
            self.pending.retain(|m| m.t() > t); // what the start used
            // The output in force at the start: the last reported before it.
            if let Some(&(_, u)) = self.reported.iter().rev().find(|(tr, _)| *tr <= t + 1e-9) {
                self.in_force = Some(u);
            }
            self.reported.clear();
            if self.started {
                self.record_start();
                self.past = [(f64::NEG_INFINITY, 0.0, 0.0); PAST];
                self.remember_position();
            }
            return Ok(self.started.then(|| self.ekf.estimate()));
        }
        while self.ekf.t() + 0.5 * dt <= t {
            let u = self.step_input(self.ekf.t() + dt, dt);
            self.ekf.predict(&u)?;
            self.remember_position();
            if let Some(h) = &mut self.history {
                let (x, p, f) = (*self.ekf.state(), *self.ekf.covariance(), *self.ekf.last_transition());
                if let Some(last) = h.last_mut() {
                    last.next = Some(Prediction { state: x, p, f, input: u });
                }
                h.push(ForwardStep { t: self.ekf.t(), filtered: x, filtered_p: p, next: None });
            }
        }
        let now = self.ekf.t();
        // A velocity measured before and lost (a DVL's gap) while positions still come (a
        // USBL's fixes): the current estimated on the velocities is held, as in dead reckoning;
        // the fixes alone move it by their noise.
        let velocity_lost = self.last_velocity.is_some_and(|l| now - l > HORIZONTAL_FRESH_S);
        self.ekf.set_horizontal_disturbance(match self.navigation(now) {
            Navigation::Measured if velocity_lost => HorizontalDisturbance::Held,
            Navigation::Measured => HorizontalDisturbance::Estimated,
            Navigation::DeadReckoning { .. } => HorizontalDisturbance::Held,
            Navigation::Lost => HorizontalDisturbance::Off,
        });
        for i in 0..self.pending.len() {
            let mut m = self.pending[i];
            if m.t() < now - 1.5 * dt {
                // A late fix is compared with the estimate of its own time: moved by how far
                // the estimate went since, it is a fix of now.
                let then = self.position_then(m.t()).filter(|_| m.t() >= now - MAX_FIX_LATENCY_S);
                let s = self.ekf.state();
                match (m, then) {
                    (Measurement::Position { t, x, y, z }, Some((n, e))) => {
                        m = Measurement::Position { t, x: x + s[0] - n, y: y + s[1] - e, z };
                        self.late_fixes += 1;
                    }
                    (Measurement::Fix { t, x, y, std }, Some((n, e))) => {
                        m = Measurement::Fix { t, x: x + s[0] - n, y: y + s[1] - e, std };
                        self.late_fixes += 1;
                    }
                    _ => {
                        self.late += 1;
                        continue;
                    }
                }
            }
            // The first fix of an estimate no position placed: where a DVL carried it, its frame
            // stands (the point held lies in it) and the fixes' offset to it is estimated; with
            // nothing horizontal measured before, the fixes define the frame.
            if let Measurement::Fix { .. } = m
                && !self.placed
                && !self.ekf.fix_offset_known()
            {
                if self.last_velocity.is_some() {
                    self.ekf.place_here();
                } else {
                    self.ekf.define_frame_by_fixes();
                }
                self.placed = true;
            }
            let fused = self.ekf.update(&m) == Update::Fused;
            self.placed |= fused && matches!(m, Measurement::Position { .. } | Measurement::Fix { .. });
            if fused && m.observes_horizontal() {
                self.last_horizontal = Some(now);
                self.horizontal_variance_then = self.horizontal_variance();
                if matches!(m, Measurement::VelocityBody { .. } | Measurement::VelocityNed { .. }) {
                    self.last_velocity = Some(now);
                }
            }
        }
        self.pending.clear();
        if let Some(last) = self.history.as_mut().and_then(|h| h.last_mut()) {
            last.filtered = *self.ekf.state();
            last.filtered_p = *self.ekf.covariance();
        }
        Ok(Some(self.ekf.estimate()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimation::ekf::FIX_REACQUIRE_AFTER;
    use crate::estimation::navigation::Navigation;
    use crate::vehicle::{Rk4Vehicle, to_network, to_simulator};

    /// A depth reading repeated exactly (a sensor read faster than it updates) is left out
    /// and counted; a new value is fused again.
    #[test]
    fn an_exactly_repeated_depth_reading_is_left_out() {
        let mut tr = Estimator::new(Rk4Vehicle::with_dt(0.08), NoiseSettings::default());
        for (k, z) in [2.0, 2.0, 2.0, 2.01, 2.01, 2.0].into_iter().enumerate() {
            tr.measure(Measurement::Depth { t: 0.08 * k as f64, z });
        }
        assert_eq!(tr.repeated(), 3);
        assert_eq!(tr.pending.len(), 3);
    }

    /// Feeds a vehicle drifting at rest in the water with a 0.3 m/s current (its velocity over
    /// the ground is the current's), a DVL measuring that velocity for `dvl_s` seconds and then
    /// nothing horizontal until `end_s`; returns the estimator and the truth's north and east
    /// at the end.
    fn drift_in_a_current(bound: f64, dvl_s: f64, end_s: f64) -> (Estimator<Rk4Vehicle>, (f64, f64)) {
        let dt = 0.08;
        let mut tr = Estimator::new(Rk4Vehicle::with_dt(dt), NoiseSettings::default()).with_dead_reckoning_bound(bound);
        let (current, psi) = ([0.26, 0.15], 0.4_f64);
        let (s, c) = psi.sin_cos();
        let (u, v) = (c * current[0] + s * current[1], -s * current[0] + c * current[1]);
        let hover = Input::new(0.0, 0.0, -Rk4Vehicle::with_dt(dt).params.net_buoyancy(), 0.0);
        tr.measure(Measurement::Position { t: 0.0, x: 0.0, y: 0.0, z: f64::NAN });
        let steps = (end_s / dt).round() as usize;
        for k in 0..=steps {
            let t = k as f64 * dt;
            tr.measure(Measurement::Heading { t, psi });
            tr.measure(Measurement::YawRate { t, r: 0.0 });
            tr.measure(Measurement::Depth { t, z: 2.0 + 1e-6 * k as f64 });
            if t <= dvl_s + 1e-9 {
                tr.measure(Measurement::VelocityBody { t, u, v, w: 0.0 });
            }
            tr.applied(t, hover);
            tr.advance(t).unwrap();
        }
        let t = steps as f64 * dt;
        (tr, (current[0] * t, current[1] * t))
    }

    /// Dead reckoning through a 20 s DVL gap: the current estimated while the DVL measured is
    /// held, so the estimate drifts with the vehicle (measured: 0.15 m from the truth after
    /// 20 s, against 6 m of drift), and says it dead reckons within its bound. With a bound of zero
    /// the estimate counts as lost at once, as before dead reckoning.
    #[test]
    fn a_dvl_gap_is_dead_reckoned_with_the_current_estimated_before() {
        let (tr, (n, e)) = drift_in_a_current(DEFAULT_DEAD_RECKONING_BOUND_M, 30.0, 50.0);
        let est = tr.ekf().estimate();
        let miss = (est.sim[0] - n).hypot(est.sim[1] - e);
        assert!(miss < 0.25, "{miss} m from the truth ({n:.2}, {e:.2}) after 20 s of dead reckoning");
        let Navigation::DeadReckoning { since, std } = tr.navigation(est.t) else {
            panic!("{:?}", tr.navigation(est.t))
        };
        assert!((since - 30.0).abs() < 0.1 && std > 0.0 && std < DEFAULT_DEAD_RECKONING_BOUND_M, "{since} {std}");
        let (tr, (n, e)) = drift_in_a_current(0.0, 30.0, 50.0);
        assert_eq!(tr.navigation(tr.ekf().t()), Navigation::Lost);
        let est = tr.ekf().estimate();
        assert!((est.sim[0] - n).hypot(est.sim[1] - e) > 3.0, "without dead reckoning the current is dropped");
    }

    /// A late position fix is compared with the estimate of the time it was measured: a
    /// vehicle moving north at 0.3 m/s, fixes of its true position arriving 0.5 s late, ends
    /// within 2 cm of the truth, where each fix lies 0.144 m behind the vehicle when it arrives.
    #[test]
    fn late_fixes_are_fused_at_the_time_they_were_measured() {
        let dt = 0.08;
        let mut tr =
            Estimator::new(Rk4Vehicle::with_dt(dt), NoiseSettings { position_std: 0.05, ..Default::default() });
        let hover = Input::new(0.0, 0.0, -Rk4Vehicle::with_dt(dt).params.net_buoyancy(), 0.0);
        let speed = 0.3;
        for k in 0..=500 {
            let t = k as f64 * dt;
            tr.measure(Measurement::Heading { t, psi: 0.0 });
            tr.measure(Measurement::YawRate { t, r: 0.0 });
            tr.measure(Measurement::Depth { t, z: 2.0 + 1e-6 * k as f64 });
            tr.measure(Measurement::VelocityBody { t, u: speed, v: 0.0, w: 0.0 });
            // A fix every 0.24 s, 0.48 s late (six samples).
            if k % 3 == 0 && k >= 6 {
                let tf = t - 0.48;
                tr.measure(Measurement::Position { t: tf, x: speed * tf + 1.0, y: 0.0, z: f64::NAN });
            }
            tr.applied(t, hover);
            tr.advance(t).unwrap();
        }
        let est = tr.ekf().estimate();
        assert!(tr.late_fixes() > 100, "{}", tr.late_fixes());
        assert!((est.sim[0] - (speed * est.t + 1.0)).abs() < 0.02, "{} against {}", est.sim[0], speed * est.t + 1.0);
    }

    /// A USBL's fixes (0.25 m of noise, 4 Hz, 0.5 s late, that accuracy stated) beside a DVL
    /// (1 cm/s of noise): the estimate of a vehicle moving north at 0.3 m/s keeps within a
    /// fifth of the fixes' own scatter of the truth.
    #[test]
    fn noisy_late_fixes_beside_a_dvl_are_steadied() {
        let dt = 0.08;
        let mut tr = Estimator::new(Rk4Vehicle::with_dt(dt), NoiseSettings::default());
        let hover = Input::new(0.0, 0.0, -Rk4Vehicle::with_dt(dt).params.net_buoyancy(), 0.0);
        let mut gauss = gaussian(12345);
        let (speed, fix_std) = (0.3, 0.25);
        let (mut sq, mut n, mut fix_sq) = (0.0, 0, 0.0);
        for k in 0..=1500 {
            let t = k as f64 * dt;
            tr.measure(Measurement::Heading { t, psi: 0.0 });
            tr.measure(Measurement::YawRate { t, r: 0.0 });
            tr.measure(Measurement::Depth { t, z: 2.0 + 1e-6 * k as f64 });
            tr.measure(Measurement::VelocityBody { t, u: speed + 0.01 * gauss(), v: 0.01 * gauss(), w: 0.0 });
            // 4 Hz on the 12.5 Hz grid: every third sample and then the fourth, 0.48-0.56 s late.
            if k % 25 % 3 == 0 && k % 25 != 24 && k >= 7 {
                let tf = t - 0.5;
                let (ex, ey) = (fix_std * gauss(), fix_std * gauss());
                fix_sq += ex * ex + ey * ey;
                tr.measure(Measurement::Fix { t: tf, x: speed * tf + ex, y: ey, std: fix_std });
            }
            tr.applied(t, hover);
            let est = tr.advance(t).unwrap();
            if let Some(e) = est.filter(|_| t > 30.0) {
                sq += (e.sim[0] - speed * e.t).powi(2) + e.sim[1].powi(2);
                n += 1;
            }
        }
        let rms = (sq / n as f64).sqrt();
        let fix_rms = (fix_sq / tr.late_fixes() as f64).sqrt();
        assert!(tr.late_fixes() > 400, "{}", tr.late_fixes());
        assert!(rms < 0.2 * fix_rms, "estimate {rms:.3} m RMS from the truth, the fixes {fix_rms:.3} m");
    }

    /// Gaussian draws from a fixed linear congruential sequence (Box-Muller).
    fn gaussian(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            let mut uniform = || {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((seed >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (a, b) = (uniform(), uniform());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        }
    }

    /// What a flight with a USBL gives the estimator, sample by sample: a vehicle at heading 0
    /// moving north at `speed` (m/s), a DVL reading its body velocity as mounted (turned `yaw`
    /// rad to starboard, `1 + scale` times it; 1 cm/s of noise), the autopilot's position (its
    /// own frame, the truth's) until `fixes_from` s, and from then 4 Hz fixes of 0.25 m 0.5 s
    /// late, `fix_frame(t)` (m) away from the truth's frame. Calls `each(estimator, truth
    /// north)` after every sample until `end` s.
    #[allow(clippy::too_many_arguments)]
    fn fly_with_fixes(
        speed: f64,
        (yaw, scale): (f64, f64),
        fixes_from: f64,
        end: f64,
        mut fix_frame: impl FnMut(f64) -> (f64, f64),
        mut each: impl FnMut(&Estimator<Rk4Vehicle>, f64),
    ) -> Estimator<Rk4Vehicle> {
        let dt = 0.08;
        let mut tr = Estimator::new(Rk4Vehicle::with_dt(dt), NoiseSettings::default());
        tr.set_position_process_std(0.001);
        let hover = Input::new(0.0, 0.0, -Rk4Vehicle::with_dt(dt).params.net_buoyancy(), 0.0);
        let mut gauss = gaussian(777);
        let (c, s) = (yaw.cos(), yaw.sin());
        for k in 0..=(end / dt).round() as usize {
            let t = k as f64 * dt;
            tr.measure(Measurement::Heading { t, psi: 0.0 });
            tr.measure(Measurement::YawRate { t, r: 0.0 });
            tr.measure(Measurement::Depth { t, z: 2.0 + 1e-6 * k as f64 });
            let (u, v) = ((1.0 + scale) * c * speed, -(1.0 + scale) * s * speed);
            tr.measure(Measurement::VelocityBody { t, u: u + 0.01 * gauss(), v: v + 0.01 * gauss(), w: 0.0 });
            if t < fixes_from {
                tr.measure(Measurement::Position { t, x: speed * t, y: 0.0, z: f64::NAN });
            } else if k % 25 % 3 == 0 && k % 25 != 24 {
                let tf = t - 0.5;
                let (dn, de) = fix_frame(tf);
                let (x, y) = (speed * tf + dn + 0.25 * gauss(), de + 0.25 * gauss());
                tr.measure(Measurement::Fix { t: tf, x, y, std: 0.25 });
            }
            tr.applied(t, hover);
            tr.advance(t).unwrap();
            each(&tr, speed * t);
        }
        tr
    }

    /// Fixes taken up 10 s after the start, their frame 3 m north and 2 m west of the one the
    /// estimate started in (an EKF origin set by hand): the offset is estimated and the estimate
    /// of the vehicle does not move (opening the position to the fixes moved it 3.6 m).
    #[test]
    fn fixes_in_another_frame_move_the_offset_not_the_estimate() {
        let mut worst: f64 = 0.0;
        let tr = fly_with_fixes(
            0.0,
            (0.0, 0.0),
            10.0,
            60.0,
            |_| (3.0, -2.0),
            |tr, north| {
                let s = tr.ekf().state();
                worst = worst.max((s[0] - north).hypot(s[1]));
            },
        );
        let (offset, std) = tr.ekf().estimate().fix_offset;
        assert!(worst < 0.1, "the estimate moved {worst:.3} m");
        assert!((offset[0] - 3.0).hypot(offset[1] + 2.0) < 0.1 && std < 0.1, "{offset:?} +- {std}");
    }

    /// A fix 3 m off (multipath) is left out and moves nothing; eight in a row 4 m off (the
    /// topside GPS on a new fix) move the frame's offset, and the estimate stays with the truth.
    #[test]
    fn an_outlier_is_left_out_and_a_frame_that_moved_is_taken_up() {
        // One fix 3 m east at 30 s, every fix 4 m north from 40 s.
        let mut outlier_sent = false;
        let frame = move |t: f64| match t {
            t if t >= 40.0 => (4.0, 0.0),
            t if t >= 30.0 && !outlier_sent => {
                outlier_sent = true;
                (0.0, 3.0)
            }
            _ => (0.0, 0.0),
        };
        let mut worst: f64 = 0.0;
        let tr = fly_with_fixes(0.1, (0.0, 0.0), 0.0, 60.0, frame, |tr, north| {
            let s = tr.ekf().state();
            if tr.ekf().t() > 10.0 {
                worst = worst.max((s[0] - north).hypot(s[1]));
            }
        });
        let counts = tr.counts();
        let (offset, _) = tr.ekf().estimate().fix_offset;
        assert_eq!(counts.fix_frame_moves, 1, "{counts:?}");
        assert_eq!(counts.fixes_rejected, 1 + FIX_REACQUIRE_AFTER as u64 - 1, "{counts:?}");
        // After the move the vehicle is known in the new frame only as well as the offset is
        // (0.075 m here): within 0.2 m, where following the fixes it went 4 m.
        assert!(worst < 0.2, "the estimate went {worst:.3} m from the truth");
        assert!((offset[0] - 4.0).hypot(offset[1]) < 0.15, "{offset:?}");
    }

    /// A DVL mounted 2 deg to starboard reading 1 % fast, on a vehicle moving north at
    /// 0.3 m/s for 110 s beside a USBL: the misalignment is estimated within 0.5 deg and the
    /// scale within 0.5 %, and the estimate keeps with the truth.
    #[test]
    fn a_dvl_misalignment_and_scale_are_estimated_from_fixes() {
        let mut worst: f64 = 0.0;
        let tr = fly_with_fixes(
            0.3,
            (2f64.to_radians(), 0.01),
            0.0,
            110.0,
            |_| (0.0, 0.0),
            |tr, north| {
                let s = tr.ekf().state();
                if tr.ekf().t() > 20.0 {
                    worst = worst.max((s[0] - north).hypot(s[1]));
                }
            },
        );
        let e = tr.ekf().estimate();
        assert!((e.dvl_yaw.0.to_degrees() - 2.0).abs() < 0.5, "{:?} deg", e.dvl_yaw.0.to_degrees());
        assert!((e.dvl_scale.0 - 0.01).abs() < 0.005, "{:?}", e.dvl_scale);
        assert!(worst < 0.15, "{worst}");
    }

    #[test]
    fn starts_on_heading_yaw_rate_and_depth_then_steps_on_the_grid() {
        let model = Rk4Vehicle::with_dt(0.08);
        let mut tr = Estimator::new(model, NoiseSettings::default());
        tr.measure(Measurement::Heading { t: 10.0, psi: 0.5 });
        assert!(tr.advance(10.0).unwrap().is_none(), "no depth yet");
        tr.measure(Measurement::Heading { t: 10.08, psi: 0.5 });
        tr.measure(Measurement::YawRate { t: 10.08, r: 0.0 });
        tr.measure(Measurement::Depth { t: 10.05, z: 2.0 });
        let e = tr.advance(10.08).unwrap().expect("started");
        assert_eq!((e.t, e.sim[2], e.sim[3]), (10.08, 2.0, 0.5));
        assert!(e.std[0] > 50.0, "x is unknown without a position");
        // Three samples later with the thrusters reporting a dive: the filter is three steps on
        // and predicts the model's own response to the reported input.
        let dive = Input::new(0.0, 0.0, 20.0, 0.0);
        tr.commanded(Input::zeros());
        for k in 1..=3 {
            tr.applied(10.08 + 0.08 * k as f64 - 0.01, dive);
        }
        let e = tr.advance(10.08 + 0.24).unwrap().unwrap();
        assert!((e.t - 10.32).abs() < 1e-9);
        let mut want = to_network(&SimState::from([0.0, 0.0, 2.0, 0.5, 0.0, 0.0, 0.0, 0.0]));
        for _ in 0..3 {
            let mut next = want;
            model.step(&mut (), &want, &dive, &mut next).unwrap();
            want = next;
        }
        let want = to_simulator(&want);
        assert!((e.sim[6] - want[6]).abs() < 1e-12 && e.sim[6] > 0.0, "w {} vs {}", e.sim[6], want[6]);
        // A silence longer than the gap restarts the filter.
        tr.measure(Measurement::Heading { t: 20.0, psi: 0.1 });
        assert!(tr.advance(20.0).unwrap().is_none());
        assert_eq!(tr.restarts(), 1);
    }
}
