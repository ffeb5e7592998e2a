//! The paper's evaluation (docs/MODEL.md section 5): one-step, 10-step rollout and physics-residual
//! MSEs, and the valid prediction time, computed with the frozen runtime.
//!
//! Definitions, for a set of trajectories with `N + 1` points each:
//! - one-step MSE: mean over every interval and all 9 components of `(x_hat_{k+1} - x_{k+1})^2`,
//!   each prediction made from the true `x_k`;
//! - `n`-step rollout MSE: rollouts of `n` steps from every point `k <= N - n`, the mean over
//!   all `n` predicted states of each rollout (the paper's `L_R` with `N_pred = n`);
//! - physics MSE: mean of `(d x_hat/dt - f(x_hat, u))^2` at `t = T` from every true `x_k`, with
//!   `d x_hat/dt` a central difference of the f64 runtime (h = 1e-5 s, truncation ~1e-10);
//! - VPT: the time of the first sample whose position error exceeds 0.05 m in a full rollout
//!   from the first point (`N T` if none does), averaged over the set.

mod recorded;
mod rollout_plot;

pub use recorded::{Evaluated, RecordedEvalError, RecordedEvaluation, Row, StartFrom, evaluate_recorded};
pub use rollout_plot::plot_rollouts;

use crate::dataset::{DatasetPreset, TrajectorySet, generate_set};
use crate::model::PincModel;
use crate::runtime::{BatchWorkspace, Predictor, RuntimeError};
use crate::traits::DiscreteModel;
use crate::types::{Input, NX, State};
use crate::vehicle::{self, VehicleParams};
use serde::Serialize;

/// Position error that ends the valid prediction time (m).
pub const VPT_THRESHOLD_M: f64 = 0.05;

/// The paper's metrics: `l1..l5` are log10 MSEs, `vpt1..vpt3` mean seconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Metrics {
    /// log10 one-step MSE on the development set.
    pub l1: f64,
    /// log10 10-step rollout MSE on the development set.
    pub l2: f64,
    /// log10 physics-residual MSE on the development set.
    pub l3: f64,
    /// log10 one-step MSE on the interpolation set (T = 0.06 s).
    pub l4: f64,
    /// log10 one-step MSE on the extrapolation set (T = 0.10 s).
    pub l5: f64,
    /// Mean VPT on the development set (s).
    pub vpt1: f64,
    /// Mean VPT on the interpolation set (s).
    pub vpt2: f64,
    /// Mean VPT on the extrapolation set (s).
    pub vpt3: f64,
}

impl Metrics {
    /// `(name, value)` pairs, in table order.
    pub fn entries(&self) -> [(&'static str, f64); 8] {
        [
            ("l1", self.l1),
            ("l2", self.l2),
            ("l3", self.l3),
            ("l4", self.l4),
            ("l5", self.l5),
            ("vpt1", self.vpt1),
            ("vpt2", self.vpt2),
            ("vpt3", self.vpt3),
        ]
    }
}

/// The three evaluation sets of a preset, freshly generated.
pub struct EvalSets {
    /// Development set (`dev_eval`, T = 0.08 s).
    pub dev: TrajectorySet,
    /// Interpolation set (T = 0.06 s).
    pub interp: TrajectorySet,
    /// Extrapolation set (T = 0.10 s).
    pub extrap: TrajectorySet,
}

impl EvalSets {
    /// Generates `dev_eval`, `interp` and `extrap` of `preset` from `seed`, with `count`
    /// trajectories each (`None`: the preset's count).
    ///
    /// # Panics
    /// If the preset lacks one of the three sets (both built-in presets have them).
    pub fn generate(preset: &DatasetPreset, seed: u64, count: Option<usize>, mut progress: impl FnMut()) -> Self {
        let mut make = |name: &str| {
            let mut spec = preset.set(name).unwrap_or_else(|| panic!("preset has no {name} set")).clone();
            if let Some(c) = count {
                spec.count = c;
            }
            generate_set(&spec, &preset.vehicle, seed, &mut progress)
        };
        Self { dev: make("dev_eval"), interp: make("interp"), extrap: make("extrap") }
    }
}

/// All eight metrics of `model` on `sets`.
///
/// # Errors
/// A non-finite state or input in a set (a prediction that diverges is not an error: it
/// counts as an infinite error).
pub fn evaluate(model: &PincModel, sets: &EvalSets) -> Result<Metrics, RuntimeError> {
    let p = Predictor::<f32>::new(model);
    let p64 = Predictor::reference(model);
    // The physics residual against the vehicle the model was trained for.
    let params = model.vehicle;
    Ok(Metrics {
        l1: one_step_mse(&p, &sets.dev)?.log10(),
        l2: rollout_mse(&p, &sets.dev, 10)?.log10(),
        l3: physics_mse(&p64, &params, &sets.dev)?.log10(),
        l4: one_step_mse(&p, &sets.interp)?.log10(),
        l5: one_step_mse(&p, &sets.extrap)?.log10(),
        vpt1: mean(&vpt(&p, &sets.dev)?),
        vpt2: mean(&vpt(&p, &sets.interp)?),
        vpt3: mean(&vpt(&p, &sets.extrap)?),
    })
}

pub(crate) fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Rolls out every `(x0, inputs)` pair for `steps` steps at `set.dt`; a trajectory whose
/// prediction stops being finite is filled with infinities from that step on.
fn rollouts<T: crate::runtime::Real>(
    p: &Predictor<T>,
    dt: f64,
    x0: &[State],
    inputs: &[Input],
    steps: usize,
) -> Result<Vec<State>, RuntimeError> {
    let mut out = vec![State::zeros(); x0.len() * (steps + 1)];
    let mut ws = BatchWorkspace::new(p);
    match p.rollout_batch_dt(&mut ws, x0, inputs, dt, &mut out) {
        Ok(()) => Ok(out),
        Err(RuntimeError::BatchDiverged { .. }) => {
            // The diverged trajectories hold NaN from their first non-finite prediction on.
            out.iter_mut().filter(|s| s.iter().any(|v| !v.is_finite())).for_each(|s| s.fill(f64::INFINITY));
            Ok(out)
        }
        Err(e) => Err(e),
    }
}

fn squared_error(a: &State, b: &State) -> f64 {
    let e = (a - b).norm_squared();
    if e.is_nan() { f64::INFINITY } else { e }
}

/// One-step MSE over every interval of `set`.
///
/// # Errors
/// A non-finite state or input in the set.
pub fn one_step_mse<T: crate::runtime::Real>(p: &Predictor<T>, set: &TrajectorySet) -> Result<f64, RuntimeError> {
    rollout_mse(p, set, 1)
}

/// `steps`-step rollout MSE from every point that leaves room for `steps` more (each started
/// at [`TrajectorySet::start`], scored against the recorded states).
///
/// # Errors
/// A non-finite state or input in the set.
pub fn rollout_mse<T: crate::runtime::Real>(
    p: &Predictor<T>,
    set: &TrajectorySet,
    steps: usize,
) -> Result<f64, RuntimeError> {
    Ok(mean(&rollout_mse_per_trajectory(p, set, steps)?))
}

/// [`rollout_mse`] of each trajectory of `set` (every trajectory has as many starting points,
/// so their mean is the set's).
///
/// # Errors
/// A non-finite state or input in the set.
pub fn rollout_mse_per_trajectory<T: crate::runtime::Real>(
    p: &Predictor<T>,
    set: &TrajectorySet,
    steps: usize,
) -> Result<Vec<f64>, RuntimeError> {
    rollout_mse_by(|x0, inputs, n| rollouts(p, set.dt, x0, inputs, n), set, steps)
}

/// Per-trajectory rollout MSE with the rollouts made by `roll(x0, inputs, steps)`.
fn rollout_mse_by(
    roll: impl Fn(&[State], &[Input], usize) -> Result<Vec<State>, RuntimeError>,
    set: &TrajectorySet,
    steps: usize,
) -> Result<Vec<f64>, RuntimeError> {
    let intervals = set.points - 1;
    let starts = intervals + 1 - steps.min(intervals);
    let mut x0 = Vec::with_capacity(set.count * starts);
    let mut inputs = Vec::with_capacity(set.count * starts * steps);
    for i in 0..set.count {
        let (_, us) = set.trajectory(i);
        for k in 0..starts {
            x0.push(set.start(i, k));
            inputs.extend_from_slice(&us[k..k + steps]);
        }
    }
    let out = roll(&x0, &inputs, steps)?;
    let per = (0..set.count)
        .map(|i| {
            let (xs, _) = set.trajectory(i);
            let mut sum = 0.0;
            for k in 0..starts {
                let pred = &out[(i * starts + k) * (steps + 1)..(i * starts + k + 1) * (steps + 1)];
                for j in 1..=steps {
                    sum += squared_error(&pred[j], &xs[k + j]);
                }
            }
            sum / (starts * steps * NX) as f64
        })
        .collect();
    Ok(per)
}

/// Rolls out a [`DiscreteModel`] from every `x0` under its `steps` inputs, at the model's own
/// period; a trajectory whose prediction stops being finite is filled with infinities from
/// that step on (as the network's rollouts).
fn discrete_rollouts<M: DiscreteModel>(
    m: &M,
    x0: &[State],
    inputs: &[Input],
    steps: usize,
) -> Result<Vec<State>, RuntimeError> {
    let mut ws = m.workspace();
    let mut out = vec![State::zeros(); x0.len() * (steps + 1)];
    for (i, x) in x0.iter().enumerate() {
        let traj = &mut out[i * (steps + 1)..(i + 1) * (steps + 1)];
        crate::runtime::check_state(0, x)?;
        traj[0] = *x;
        for k in 0..steps {
            let u = &inputs[i * steps + k];
            crate::runtime::check_input(k, u)?;
            let mut next = State::zeros();
            match m.step(&mut ws, &traj[k], u, &mut next) {
                Ok(()) => traj[k + 1] = next,
                Err(RuntimeError::NonFiniteOutput { .. } | RuntimeError::NonFiniteState { .. }) => {
                    traj[k + 1..].iter_mut().for_each(|s| s.fill(f64::INFINITY));
                    break;
                }
                Err(e) => return Err(e),
            }
        }
    }
    Ok(out)
}

/// [`SetMetrics`] of any [`DiscreteModel`] (the analytic vehicle, identified physics) on
/// `set`, by the same definitions as [`evaluate_set`]; the model steps at its own period,
/// which must be the set's. The physics residual is NaN (not applicable: it measures a
/// network's time derivative against the vehicle).
///
/// # Errors
/// A non-finite state or input in the set; [`RuntimeError::BadTimeStep`] when the model's
/// period is not the set's.
pub fn evaluate_set_discrete<M: DiscreteModel>(m: &M, set: &TrajectorySet) -> Result<SetMetrics, RuntimeError> {
    if (m.dt() - set.dt).abs() > 1e-12 * set.dt.max(1.0) {
        return Err(RuntimeError::BadTimeStep(m.dt()));
    }
    let roll = |x0: &[State], inputs: &[Input], n: usize| discrete_rollouts(m, x0, inputs, n);
    let x0: Vec<State> = (0..set.count).map(|i| set.start(i, 0)).collect();
    let mut v = vpt_of_rollouts(&roll(&x0, &set.inputs, set.points - 1)?, set);
    v.sort_by(f64::total_cmp);
    Ok(SetMetrics {
        one_step_mse: mean(&rollout_mse_by(roll, set, 1)?),
        rollout10_mse: mean(&rollout_mse_by(roll, set, 10.min(set.points - 1))?),
        physics_mse: f64::NAN,
        vpt_s: mean(&v),
        vpt_median_s: v.get(v.len() / 2).copied().unwrap_or(0.0),
        windows: set.count,
    })
}

/// Physics-residual MSE at `t = T` from every true state of `set`.
///
/// # Errors
/// A non-finite state or input in the set.
pub fn physics_mse(p: &Predictor<f64>, params: &VehicleParams, set: &TrajectorySet) -> Result<f64, RuntimeError> {
    const H: f64 = 1e-5;
    let mut ws = p.workspace();
    let (mut at, mut plus, mut minus) = (State::zeros(), State::zeros(), State::zeros());
    let mut sum = 0.0;
    let mut n = 0usize;
    for i in 0..set.count {
        let (xs, us) = set.trajectory(i);
        for (k, (x, u)) in xs.iter().zip(us).enumerate() {
            // A prediction that is not finite counts as an infinite error, as in the rollout
            // losses; a non-finite state or input of the set is an error at its sample.
            let finite = |r: Result<(), RuntimeError>| match r {
                Ok(()) => Ok(true),
                Err(RuntimeError::NonFiniteOutput { .. }) => Ok(false),
                Err(RuntimeError::NonFiniteState { index, value, .. }) => {
                    Err(RuntimeError::NonFiniteState { step: k, index, value })
                }
                Err(RuntimeError::NonFiniteInput { index, value, .. }) => {
                    Err(RuntimeError::NonFiniteInput { step: k, index, value })
                }
                Err(e) => Err(e),
            };
            let ok = finite(p.step_dt(&mut ws, x, u, set.dt, &mut at))?
                && finite(p.step_dt(&mut ws, x, u, set.dt + H, &mut plus))?
                && finite(p.step_dt(&mut ws, x, u, set.dt - H, &mut minus))?;
            sum += if ok {
                squared_error(&((plus - minus) / (2.0 * H)), &vehicle::rhs(params, &at, u))
            } else {
                f64::INFINITY
            };
            n += 1;
        }
    }
    Ok(sum / (n * NX).max(1) as f64)
}

/// Position error of a predicted trajectory against the truth at every sample (m).
pub fn position_errors(pred: &[State], truth: &[State]) -> Vec<f64> {
    pred.iter()
        .zip(truth)
        .map(|(a, b)| {
            let e = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            if e.is_nan() { f64::INFINITY } else { e }
        })
        .collect()
}

/// Valid prediction time of one rollout: the time of the first sample whose position error
/// exceeds [`VPT_THRESHOLD_M`], or the whole length if none does.
pub fn valid_prediction_time(errors: &[f64], dt: f64) -> f64 {
    let k = errors.iter().position(|&e| e > VPT_THRESHOLD_M).unwrap_or(errors.len().saturating_sub(1));
    k as f64 * dt
}

/// Full rollouts of every trajectory of `set` from its first point ([`TrajectorySet::start`]).
///
/// # Errors
/// A non-finite state or input in the set.
pub fn full_rollouts<T: crate::runtime::Real>(
    p: &Predictor<T>,
    set: &TrajectorySet,
) -> Result<Vec<State>, RuntimeError> {
    let x0: Vec<State> = (0..set.count).map(|i| set.start(i, 0)).collect();
    rollouts(p, set.dt, &x0, &set.inputs, set.points - 1)
}

/// VPT of every trajectory of `set` (s).
///
/// # Errors
/// A non-finite state or input in the set.
pub fn vpt<T: crate::runtime::Real>(p: &Predictor<T>, set: &TrajectorySet) -> Result<Vec<f64>, RuntimeError> {
    Ok(vpt_of_rollouts(&full_rollouts(p, set)?, set))
}

/// VPT of every trajectory of `set` (s) from its [`full_rollouts`].
pub fn vpt_of_rollouts(out: &[State], set: &TrajectorySet) -> Vec<f64> {
    (0..set.count)
        .map(|i| {
            let pred = &out[i * set.points..(i + 1) * set.points];
            valid_prediction_time(&position_errors(pred, set.trajectory(i).0), set.dt)
        })
        .collect()
}

/// The metrics of one set of recorded windows (an imported dataset's test split).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SetMetrics {
    /// One-step MSE.
    pub one_step_mse: f64,
    /// 10-step rollout MSE (shorter when the windows are).
    pub rollout10_mse: f64,
    /// Physics-residual MSE at `t = T` against the given vehicle (NaN, JSON null, for a
    /// model that is not a network).
    pub physics_mse: f64,
    /// Mean VPT (s); a window's VPT is at most its length.
    pub vpt_s: f64,
    /// Median VPT (s).
    pub vpt_median_s: f64,
    /// Windows evaluated.
    pub windows: usize,
}

/// [`SetMetrics`] of `model` on `set`, the physics residual against `vehicle`.
///
/// # Errors
/// A non-finite state or input in the set.
pub fn evaluate_set(
    model: &PincModel,
    set: &TrajectorySet,
    vehicle: &VehicleParams,
) -> Result<SetMetrics, RuntimeError> {
    let p = Predictor::<f32>::new(model);
    let mut v = vpt(&p, set)?;
    v.sort_by(f64::total_cmp);
    Ok(SetMetrics {
        one_step_mse: one_step_mse(&p, set)?,
        rollout10_mse: rollout_mse(&p, set, 10.min(set.points - 1))?,
        physics_mse: physics_mse(&Predictor::reference(model), vehicle, set)?,
        vpt_s: mean(&v),
        vpt_median_s: v.get(v.len() / 2).copied().unwrap_or(0.0),
        windows: set.count,
    })
}
