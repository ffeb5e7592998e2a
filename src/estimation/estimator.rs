//! The filter on a stream of stamped measurements and applied inputs, as a controller (or a
//! log replay) sees them: measurements are queued as they arrive and fused at the next
//! sample, the filter steps on the model's grid with the input applied over each step (the
//! mean of the thruster outputs reported in it, else the command sent), and it starts itself
//! once heading, yaw rate and depth have been seen.

use super::ekf::{Ekf, Estimate, FilterCounts, Update};
use super::measurement::{Measurement, NoiseSettings};
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
    last_horizontal: Option<f64>,
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
            last_horizontal: None,
            late: 0,
            restarts: 0,
            last_depth: None,
            repeated: 0,
            history: None,
        }
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

    /// Whether a position or velocity was fused within [`HORIZONTAL_FRESH_S`] of `t`.
    pub fn horizontal_observed(&self, t: f64) -> bool {
        self.last_horizontal.is_some_and(|l| t - l <= HORIZONTAL_FRESH_S)
    }

    /// The applied input over the step ending at `t_end`: the mean of the reported inputs
    /// in it, else the newer of the last report (outputs hold) and the command.
    fn step_input(&mut self, t_end: f64) -> Input {
        let mut sum = Input::zeros();
        let mut n = 0;
        self.reported.retain(|(t, u)| {
            if *t <= t_end + 1e-9 {
                sum += u;
                n += 1;
                false
            } else {
                true
            }
        });
        match (n, self.last_reported) {
            (0, Some(held)) if !self.commanded_since_report => held,
            (0, _) => self.commanded,
            _ => sum / n as f64,
        }
    }

    /// Starts from the newest of each measured part, if heading, yaw rate and depth are among
    /// them.
    fn try_start(&mut self, t: f64) {
        let (mut psi, mut r, mut z, mut pos, mut vel, mut down) = (None, None, None, None, None, None);
        for m in &self.pending {
            match *m {
                Measurement::Heading { psi: p, .. } => psi = Some(p),
                Measurement::YawRate { r: v, .. } => r = Some(v),
                Measurement::Depth { z: d, .. } => z = Some(d),
                Measurement::Position { x, y, z: d, .. } => {
                    pos = Some((x, y));
                    z = z.or(Some(d));
                }
                Measurement::VelocityNed { vn, ve, vd, .. } => vel = Some((vn, ve, vd)),
                Measurement::VerticalVelocity { vd, .. } => down = Some(vd),
                Measurement::VelocityBody { .. } => {}
            }
        }
        let (Some(psi), Some(r), Some(z)) = (psi, r, z) else { return };
        let (s, c) = psi.sin_cos();
        let (u, v, w) = vel.map_or((0.0, 0.0, 0.0), |(vn, ve, vd)| (c * vn + s * ve, -s * vn + c * ve, vd));
        let w = down.unwrap_or(w);
        let (x, y) = pos.unwrap_or((0.0, 0.0));
        let sim = SimState::from([x, y, z, psi, u, v, w, r]);
        // Unknown horizontal position: a wide prior; velocities at rest within 0.3 m/s.
        let pos_std = if pos.is_some() { self.ekf.noise().position_std } else { 100.0 };
        let noise = self.ekf.noise().clone();
        let std: [f64; NS] = [pos_std, pos_std, noise.depth_std, noise.heading_std, 0.3, 0.3, 0.3, noise.yaw_rate_std];
        self.ekf.reset(t, &sim, &std);
        self.started = true;
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
            self.reported.clear();
            if self.started {
                self.record_start();
            }
            return Ok(self.started.then(|| self.ekf.estimate()));
        }
        while self.ekf.t() + 0.5 * dt <= t {
            let u = self.step_input(self.ekf.t() + dt);
            self.ekf.predict(&u)?;
            if let Some(h) = &mut self.history {
                let (x, p, f) = (*self.ekf.state(), *self.ekf.covariance(), *self.ekf.last_transition());
                if let Some(last) = h.last_mut() {
                    last.next = Some(Prediction { state: x, p, f, input: u });
                }
                h.push(ForwardStep { t: self.ekf.t(), filtered: x, filtered_p: p, next: None });
            }
        }
        let now = self.ekf.t();
        self.ekf.set_horizontal_disturbance(self.horizontal_observed(now));
        for i in 0..self.pending.len() {
            let m = self.pending[i];
            if m.t() < now - 1.5 * dt {
                self.late += 1;
                continue;
            }
            if self.ekf.update(&m) == Update::Fused && m.observes_horizontal() {
                self.last_horizontal = Some(now);
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
