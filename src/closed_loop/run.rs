//! One closed-loop run: the controller sees the measured state each sample, the plant
//! applies its input.

use super::scenario::{Plant, Scenario};
use crate::mpc::{CycleReport, Mpc, Reference};
use crate::traits::DiscreteModel;
use crate::types::{NU, SimState, State};
use crate::vehicle::{VehicleParams, to_network};

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

/// Runs `scenario` with `mpc` from rest at the surface, the plant being `vehicle` with the
/// scenario's disturbance. `on_sample` sees every sample and may stop the run early by
/// returning `false` (Ctrl-C); the samples so far are returned.
pub fn run<M: DiscreteModel>(
    mpc: &mut Mpc<M>,
    scenario: &Scenario,
    vehicle: &VehicleParams,
    on_sample: impl FnMut(&Sample) -> bool,
) -> Vec<Sample> {
    let plant = scenario.plant(mpc.model().dt(), vehicle);
    run_on(mpc, scenario, &plant, |s| *s, on_sample)
}

/// [`run`] against any `plant`, the controller seeing `measure(true state)` (sensor noise,
/// say) while the samples record the true state.
pub fn run_on<M: DiscreteModel>(
    mpc: &mut Mpc<M>,
    scenario: &Scenario,
    plant: &Plant,
    measure: impl FnMut(&SimState) -> SimState,
    on_sample: impl FnMut(&Sample) -> bool,
) -> Vec<Sample> {
    let dt = mpc.model().dt();
    let references = |t: f64, _: &State, refs: &mut [Reference]| {
        for (j, r) in refs.iter_mut().enumerate() {
            *r = scenario.reference(t + (j + 1) as f64 * dt);
        }
        scenario.reference(t)
    };
    run_with(mpc, scenario.duration(), plant, measure, references, on_sample)
}

/// A run of `duration` s against `plant` whose references come from `references(t, measured
/// state, refs)`: it fills `refs[k]` for the predicted samples `k + 1` and returns the
/// reference at `t` (a scenario's, or a pilot's sticks turned into references).
pub fn run_with<M: DiscreteModel>(
    mpc: &mut Mpc<M>,
    duration: f64,
    plant: &Plant,
    mut measure: impl FnMut(&SimState) -> SimState,
    mut references: impl FnMut(f64, &State, &mut [Reference]) -> Reference,
    mut on_sample: impl FnMut(&Sample) -> bool,
) -> Vec<Sample> {
    let dt = mpc.model().dt();
    let steps = (duration / dt).round() as usize;
    let n = mpc.config().horizon;
    let (lo, hi) = mpc.bounds();
    let mut refs = vec![Reference::depth_heading(0.0, 0.0); n];
    let mut s = SimState::zeros();
    let mut out = Vec::with_capacity(steps);
    for k in 0..steps {
        let t = k as f64 * dt;
        let x = to_network(&measure(&s));
        let reference = references(t, &x, &mut refs);
        let cycle = mpc.step(&x, &refs);
        let u = cycle.input;
        let bound_violation = (0..NU).any(|j| !(u[j] >= lo[j] - 1e-9 && u[j] <= hi[j] + 1e-9));
        let sample = Sample { t, state: s, reference, cycle, prediction: mpc.prediction().to_vec(), bound_violation };
        let go_on = on_sample(&sample);
        out.push(sample);
        s = plant.step(&s, &u);
        if !go_on {
            break;
        }
    }
    out
}
