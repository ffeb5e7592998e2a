//! The closed loop: the analytic vehicle as the plant (inputs held over each sample, RK4
//! with 16 sub-steps), an [`Mpc`] on any model, the tracking scenarios, and the summary of a
//! run (tracking errors, overshoot, settling, solver timing, fallbacks, bound violations).

use crate::mpc::{CycleReport, Mpc, Reference};
use crate::traits::DiscreteModel;
use crate::types::{Input, NU, SimState, State};
use crate::vehicle::{Rk4Vehicle, VehicleParams, to_network, wrap_angle};
use serde::Serialize;

/// A closed-loop scenario: references over time and the plant they run against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Scenario {
    /// 60 s from rest at the surface; depth 0 -> 1 m (2 s) -> 2 m (20 s) -> 0.5 m (40 s);
    /// heading 0 -> 45 deg (10 s) -> -30 deg (30 s) -> 0 (50 s). The plant is the nominal vehicle.
    Default,
    /// The same references; the plant's damping is 20 % higher and a 0.1 m/s current flows
    /// along the world x axis.
    Disturbed,
}

/// Depth reference steps `(time s, depth m)`.
const DEPTH_STEPS: [(f64, f64); 4] = [(0.0, 0.0), (2.0, 1.0), (20.0, 2.0), (40.0, 0.5)];
/// Heading reference steps `(time s, heading deg)`.
const HEADING_STEPS: [(f64, f64); 4] = [(0.0, 0.0), (10.0, 45.0), (30.0, -30.0), (50.0, 0.0)];

fn piecewise(steps: &[(f64, f64)], t: f64) -> f64 {
    steps.iter().rev().find(|(t0, _)| t >= *t0 - 1e-9).map_or(steps[0].1, |s| s.1)
}

impl Scenario {
    /// The name used on the command line and in logs.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Default => "default",
            Scenario::Disturbed => "disturbed",
        }
    }

    /// Length of the run (s).
    pub fn duration(self) -> f64 {
        60.0
    }

    /// The reference at time `t`.
    pub fn reference(self, t: f64) -> Reference {
        Reference { depth: piecewise(&DEPTH_STEPS, t), heading: piecewise(&HEADING_STEPS, t).to_radians() }
    }

    /// The plant of this scenario, sampled at `dt`.
    pub fn plant(self, dt: f64) -> Plant {
        let mut vehicle = Rk4Vehicle::with_dt(dt);
        match self {
            Scenario::Default => Plant { vehicle, current: [0.0, 0.0] },
            Scenario::Disturbed => {
                vehicle.params = VehicleParams::default().with_damping_scaled(1.2);
                Plant { vehicle, current: [0.1, 0.0] }
            }
        }
    }
}

/// The simulated vehicle: body velocities are relative to the water, which moves with a
/// constant world-frame `current`; with no position dependence in the dynamics that adds
/// exactly `current * dt` to the position each sample.
#[derive(Debug, Clone)]
pub struct Plant {
    /// The vehicle and its integrator.
    pub vehicle: Rk4Vehicle,
    /// Water velocity in the world frame `(x, y)` (m/s).
    pub current: [f64; 2],
}

impl Plant {
    /// One sample period under the held input `u`.
    pub fn step(&self, s: &SimState, u: &Input) -> SimState {
        let mut next = self.vehicle.step_sim(s, u);
        next[0] += self.current[0] * self.vehicle.dt;
        next[1] += self.current[1] * self.vehicle.dt;
        next
    }
}

/// One sample of a run.
#[derive(Debug, Clone)]
pub struct Sample {
    /// Time (s).
    pub t: f64,
    /// The measured (true) state before the input is applied.
    pub state: SimState,
    /// The reference at `t`.
    pub reference: Reference,
    /// What the controller did.
    pub cycle: CycleReport,
    /// The controller's predicted states `x_0 .. x_N`.
    pub prediction: Vec<State>,
    /// Applied input outside the bounds (should never happen; counted as a check).
    pub bound_violation: bool,
}

/// Runs `scenario` with `mpc` from rest at the surface. `on_sample` sees every sample and
/// may stop the run early by returning `false` (Ctrl-C); the samples so far are returned.
pub fn run<M: DiscreteModel>(
    mpc: &mut Mpc<M>,
    scenario: Scenario,
    mut on_sample: impl FnMut(&Sample) -> bool,
) -> Vec<Sample> {
    let dt = mpc.model().dt();
    let plant = scenario.plant(dt);
    let steps = (scenario.duration() / dt).round() as usize;
    let n = mpc.config().horizon;
    let (lo, hi) = mpc.bounds();
    let mut refs = vec![scenario.reference(0.0); n];
    let mut s = SimState::zeros();
    let mut out = Vec::with_capacity(steps);
    for k in 0..steps {
        let t = k as f64 * dt;
        for (j, r) in refs.iter_mut().enumerate() {
            *r = scenario.reference(t + (j + 1) as f64 * dt);
        }
        let cycle = mpc.step(&to_network(&s), &refs);
        let u = cycle.input;
        let bound_violation = (0..NU).any(|j| !(u[j] >= lo[j] - 1e-9 && u[j] <= hi[j] + 1e-9));
        let sample = Sample {
            t,
            state: s,
            reference: scenario.reference(t),
            cycle,
            prediction: mpc.prediction().to_vec(),
            bound_violation,
        };
        let go_on = on_sample(&sample);
        out.push(sample);
        s = plant.step(&s, &u);
        if !go_on {
            break;
        }
    }
    out
}

/// The numbers of a run.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Samples run.
    pub samples: usize,
    /// RMS of `z - z_ref` (m).
    pub rms_depth_m: f64,
    /// RMS of the wrapped heading error (deg).
    pub rms_heading_deg: f64,
    /// Largest overshoot past a new depth reference, in the step's direction (m).
    pub max_overshoot_depth_m: f64,
    /// Largest overshoot past a new heading reference (deg).
    pub max_overshoot_heading_deg: f64,
    /// Per depth step: time to enter and stay within 5 % of the step (s; NaN if never).
    pub settling_depth_s: Vec<f64>,
    /// Per heading step: time to enter and stay within 5 % of the step (s; NaN if never).
    pub settling_heading_s: Vec<f64>,
    /// Clarabel solve time, median (ms).
    pub solve_ms_median: f64,
    /// 99th percentile (ms).
    pub solve_ms_p99: f64,
    /// Maximum (ms).
    pub solve_ms_max: f64,
    /// Whole control cycle (rollout, linearisation, update, solve), median (ms).
    pub cycle_ms_median: f64,
    /// 99th percentile (ms).
    pub cycle_ms_p99: f64,
    /// Samples that applied the shifted previous plan.
    pub fallbacks: usize,
    /// Cycles longer than the sample period.
    pub deadline_misses: usize,
    /// Applied inputs outside the bounds.
    pub bound_violations: usize,
    /// Samples with at least one input channel at a bound.
    pub saturated_samples: usize,
}

/// Nearest-rank percentile of `v` (sorted in place).
fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let rank = ((p / 100.0) * v.len() as f64).ceil() as usize;
    v[rank.clamp(1, v.len()) - 1]
}

/// Overshoot (same units as the signal) and settling time of each reference step. Each
/// step's window ends `preview` seconds before the next step, where a controller that sees
/// the reference ahead starts moving on purpose.
fn step_response(t: &[f64], y: &[f64], steps: &[(f64, f64)], end: f64, preview: f64) -> (f64, Vec<f64>) {
    let mut overshoot: f64 = 0.0;
    let mut settling = Vec::new();
    for w in 1..steps.len() {
        let (t0, target) = steps[w];
        let (from, t1) = (steps[w - 1].1, steps.get(w + 1).map_or(end, |s| s.0 - preview));
        let size = target - from;
        let band = 0.05 * size.abs();
        let window: Vec<(f64, f64)> =
            t.iter().zip(y).filter(|(ti, _)| **ti >= t0 && **ti < t1).map(|(a, b)| (*a, *b)).collect();
        for &(_, yi) in &window {
            overshoot = overshoot.max((yi - target) * size.signum());
        }
        // The last time the error was outside the band; settled right after it.
        let last_out = window.iter().rposition(|(_, yi)| (yi - target).abs() > band);
        settling.push(match last_out {
            None => 0.0,
            Some(i) if i + 1 < window.len() => window[i + 1].0 - t0,
            Some(_) => f64::NAN,
        });
    }
    (overshoot, settling)
}

/// Summarises `samples` of `scenario` run by a controller that previews the reference
/// `preview` seconds ahead (horizon times sample period).
pub fn summarise(samples: &[Sample], scenario: Scenario, preview: f64) -> Summary {
    let t: Vec<f64> = samples.iter().map(|s| s.t).collect();
    let depth: Vec<f64> = samples.iter().map(|s| s.state[2]).collect();
    let n = samples.len().max(1) as f64;
    let rms_depth = (samples.iter().map(|s| (s.state[2] - s.reference.depth).powi(2)).sum::<f64>() / n).sqrt();
    let heading_err = |s: &Sample| wrap_angle(s.state[3] - s.reference.heading).to_degrees();
    let rms_heading = (samples.iter().map(|s| heading_err(s).powi(2)).sum::<f64>() / n).sqrt();
    // Heading unwrapped around each reference so overshoot is measured in degrees.
    let heading: Vec<f64> = samples.iter().map(|s| s.reference.heading.to_degrees() + heading_err(s)).collect();
    let end = scenario.duration();
    let (os_d, settle_d) = step_response(&t, &depth, &DEPTH_STEPS, end, preview);
    let (os_h, settle_h) = step_response(&t, &heading, &HEADING_STEPS, end, preview);
    let mut solve: Vec<f64> = samples.iter().map(|s| s.cycle.solve_us / 1e3).collect();
    let mut cycle: Vec<f64> = samples.iter().map(|s| s.cycle.cycle_us / 1e3).collect();
    Summary {
        samples: samples.len(),
        rms_depth_m: rms_depth,
        rms_heading_deg: rms_heading,
        max_overshoot_depth_m: os_d,
        max_overshoot_heading_deg: os_h,
        settling_depth_s: settle_d,
        settling_heading_s: settle_h,
        solve_ms_median: percentile(&mut solve, 50.0),
        solve_ms_p99: percentile(&mut solve, 99.0),
        solve_ms_max: solve.last().copied().unwrap_or(f64::NAN),
        cycle_ms_median: percentile(&mut cycle, 50.0),
        cycle_ms_p99: percentile(&mut cycle, 99.0),
        fallbacks: samples.iter().filter(|s| s.cycle.fallback.is_some()).count(),
        deadline_misses: samples.iter().filter(|s| s.cycle.deadline_missed).count(),
        bound_violations: samples.iter().filter(|s| s.bound_violation).count(),
        saturated_samples: samples.iter().filter(|s| s.cycle.saturated.iter().any(|&b| b)).count(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn references_follow_the_scenario_schedule() {
        let s = Scenario::Default;
        assert_eq!(s.reference(1.99).depth, 0.0);
        assert_eq!(s.reference(2.0).depth, 1.0);
        assert_eq!(s.reference(45.0).depth, 0.5);
        assert!((s.reference(10.0).heading - 45f64.to_radians()).abs() < 1e-12);
        assert!((s.reference(35.0).heading + 30f64.to_radians()).abs() < 1e-12);
        assert_eq!(s.reference(59.0).heading, 0.0);
    }

    #[test]
    fn the_current_moves_the_disturbed_plant_exactly_by_current_times_dt() {
        let (nominal, disturbed) = (Scenario::Default.plant(0.08), Scenario::Disturbed.plant(0.08));
        let s = SimState::from([0.0, 0.0, 1.0, 0.3, 0.0, 0.0, 0.0, 0.0]);
        let u = Input::zeros();
        let a = nominal.step(&s, &u);
        let b = disturbed.step(&s, &u);
        // At rest the damping does not act, so only the drift differs.
        assert!((b[0] - a[0] - 0.008).abs() < 1e-12 && (b[1] - a[1]).abs() < 1e-12);
    }

    #[test]
    fn step_metrics_of_a_known_response() {
        // First-order response to a 1 m step at t = 1 with 10 % overshoot at t = 2.
        let t: Vec<f64> = (0..100).map(|k| k as f64 * 0.1).collect();
        let y: Vec<f64> = t
            .iter()
            .map(|&t| {
                if t < 1.0 {
                    0.0
                } else if (t - 2.0).abs() < 1e-9 {
                    1.1
                } else {
                    1.0 - (-(t - 1.0) * 5.0f64).exp()
                }
            })
            .collect();
        let (os, settle) = step_response(&t, &y, &[(0.0, 0.0), (1.0, 1.0)], 10.0, 1.6);
        assert!((os - 0.1).abs() < 1e-9);
        assert!((settle[0] - 1.1).abs() < 1e-9, "{settle:?}");
        let mut v = vec![5.0, 1.0, 3.0, 2.0, 4.0];
        assert_eq!(percentile(&mut v, 50.0), 3.0);
        assert_eq!(percentile(&mut v, 99.0), 5.0);
    }
}
