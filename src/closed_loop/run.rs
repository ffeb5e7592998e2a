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
    mut measure: impl FnMut(&SimState) -> SimState,
    mut on_sample: impl FnMut(&Sample) -> bool,
) -> Vec<Sample> {
    let dt = mpc.model().dt();
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
        let cycle = mpc.step(&to_network(&measure(&s)), &refs);
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
