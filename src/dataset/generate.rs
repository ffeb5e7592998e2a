//! Seeded, bit-for-bit reproducible generation of a preset's trajectory sets.

use super::collocation::{latin_hypercube, set_rng};
use super::excitation::{apply_paper_scaling, sample_inputs};
use super::{DatasetPreset, SetSpec};
use crate::types::{Input, NS, SimState, State};
use crate::vehicle::{Rk4Vehicle, VehicleParams, to_network};
use rand::Rng;

/// One set of equally long trajectories, stored flat in trajectory-major order.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectorySet {
    /// Set name.
    pub name: String,
    /// Sample period (s).
    pub dt: f64,
    /// Number of trajectories.
    pub count: usize,
    /// Points per trajectory (intervals + 1).
    pub points: usize,
    /// Collocation times per interval (0 if none).
    pub collocation_points: usize,
    /// `count * points` network-form states.
    pub states: Vec<State>,
    /// `count * (points - 1)` held inputs.
    pub inputs: Vec<Input>,
    /// `count * (points - 1) * collocation_points` times in `[0, dt]`.
    pub collocation: Vec<f64>,
    /// Empty, or per point (indexed as `states`) the state a model's predictions start
    /// from there instead of the recorded one: what an estimator knew at that time
    /// (`pinc::estimation::window_starts`). Evaluation rolls out from it and training feeds
    /// it to the network; the targets stay `states`. Not stored with the set.
    pub starts: Vec<State>,
}

impl TrajectorySet {
    /// States and inputs of trajectory `i`.
    ///
    /// # Panics
    /// If `i >= count`.
    pub fn trajectory(&self, i: usize) -> (&[State], &[Input]) {
        let n = self.points - 1;
        (&self.states[i * self.points..(i + 1) * self.points], &self.inputs[i * n..(i + 1) * n])
    }

    /// Where a prediction from point `k` of trajectory `i` starts: [`TrajectorySet::starts`]'
    /// state there where the set has starts, else the recorded state.
    ///
    /// # Panics
    /// If `i >= count` or `k >= points`.
    pub fn start(&self, i: usize, k: usize) -> State {
        assert!(i < self.count && k < self.points, "point {k} of trajectory {i} of {}x{}", self.count, self.points);
        let at = i * self.points + k;
        if self.starts.is_empty() { self.states[at] } else { self.starts[at] }
    }
}

/// All sets of a preset, generated from one seed.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// What was generated.
    pub preset: DatasetPreset,
    /// The seed it was generated from.
    pub seed: u64,
    /// The sets, in the preset's order.
    pub sets: Vec<TrajectorySet>,
    /// For a dataset imported from recorded runs: the files and options.
    pub source: Option<super::source::ImportSource>,
}

impl Dataset {
    /// The set named `name`.
    pub fn set(&self, name: &str) -> Option<&TrajectorySet> {
        self.sets.iter().find(|s| s.name == name)
    }
}

/// Generates one set with `vehicle`; `on_trajectory` is called after each trajectory (for
/// progress).
pub fn generate_set(
    spec: &SetSpec,
    vehicle: &VehicleParams,
    seed: u64,
    mut on_trajectory: impl FnMut(),
) -> TrajectorySet {
    let mut rng = set_rng(seed, &spec.name);
    let vehicle = Rk4Vehicle { params: *vehicle, ..Rk4Vehicle::with_dt(spec.dt) };
    let n = spec.points.saturating_sub(1);
    let mut set = TrajectorySet {
        name: spec.name.clone(),
        dt: spec.dt,
        count: spec.count,
        points: spec.points,
        collocation_points: spec.collocation_points,
        states: Vec::with_capacity(spec.count * spec.points),
        inputs: Vec::with_capacity(spec.count * n),
        collocation: Vec::with_capacity(spec.count * n * spec.collocation_points),
        starts: Vec::new(),
    };
    for _ in 0..spec.count {
        let mut s0 = SimState::zeros();
        for i in 0..NS {
            let (lo, hi) = (spec.initial.lo[i], spec.initial.hi[i]);
            s0[i] = if hi > lo { rng.random_range(lo..hi) } else { lo };
        }
        let mut inputs = sample_inputs(&spec.excitation, &mut rng, n, spec.dt);
        if spec.paper_scaling {
            apply_paper_scaling(&mut inputs);
        }
        set.states.extend(vehicle.simulate(&s0, &inputs).iter().map(to_network));
        set.inputs.extend_from_slice(&inputs);
        for _ in 0..n {
            latin_hypercube(&mut rng, spec.collocation_points, spec.dt, &mut set.collocation);
        }
        on_trajectory();
    }
    set
}

/// Generates every set of `preset` from `seed`; `on_trajectory` is called after each
/// trajectory of every set.
pub fn generate(preset: &DatasetPreset, seed: u64, mut on_trajectory: impl FnMut()) -> Dataset {
    let sets = preset.sets.iter().map(|spec| generate_set(spec, &preset.vehicle, seed, &mut on_trajectory)).collect();
    Dataset { preset: preset.clone(), seed, sets, source: None }
}
