//! A batch of trajectories as tensors, and the five losses of docs/MODEL.md section 4.

use super::config::{LossKind, TrainConfig};
use super::net::PincNet;
use super::physics::rhs;
use crate::dataset::TrajectorySet;
use crate::types::{NU, NX};
use crate::vehicle::VehicleParams;
use burn::prelude::*;
use rand::Rng;
use rand_distr::{Distribution, Normal};

/// Rollout windows: start states and, per step, the held inputs and the true next states.
pub struct RolloutBatch {
    /// `[W, 9]` true start states.
    pub start: Tensor<2>,
    /// Per step `j`: `[W, 4]` inputs.
    pub inputs: Vec<Tensor<2>>,
    /// Per step `j`: `[W, 9]` true states after `j + 1` steps.
    pub targets: Vec<Tensor<2>>,
}

/// The tensors of one batch of trajectories.
pub struct Batch {
    /// `[M, 9]` states `x_k` of every interval (with input noise, if configured).
    pub x: Tensor<2>,
    /// `[M, 4]` held inputs `u_k`.
    pub u: Tensor<2>,
    /// `[M, 9]` true next states `x_{k+1}`.
    pub next: Tensor<2>,
    /// `[M, 9]` true states without noise (the initial-condition target).
    pub x_clean: Tensor<2>,
    /// `[M, 1]` the sample period.
    pub t_end: Tensor<2>,
    /// `[M, 1]` zeros.
    pub t_zero: Tensor<2>,
    /// Collocation rows: `[M P, 9]` states, `[M P, 4]` inputs, `[M P, 1]` times.
    pub colloc: (Tensor<2>, Tensor<2>, Tensor<2>),
    /// Rollout windows, when a rollout loss is active.
    pub rollout: Option<RolloutBatch>,
}

fn tensor(data: Vec<f32>, cols: usize, device: &Device) -> Tensor<2> {
    let rows = data.len() / cols;
    Tensor::from_data(TensorData::new(data, [rows, cols]), device)
}

impl Batch {
    /// Builds the batch of trajectories `traj` of `set`.
    pub fn new(set: &TrajectorySet, traj: &[usize], cfg: &TrainConfig, rng: &mut impl Rng, device: &Device) -> Self {
        let noise = Normal::new(0.0, cfg.input_noise.max(0.0)).expect("finite noise level");
        let mut jitter = |v: f64| -> f32 { (if cfg.input_noise > 0.0 { v + noise.sample(rng) } else { v }) as f32 };
        let intervals = set.points - 1;
        let p = set.collocation_points.max(1);
        let (mut x, mut u, mut next, mut clean) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut cx, mut cu, mut ct) = (Vec::new(), Vec::new(), Vec::new());
        for &i in traj {
            let (xs, us) = set.trajectory(i);
            for k in 0..intervals {
                // The network's input: the estimator's state where the set has one (what a
                // controller gives it), else the recorded one; the target is always recorded.
                let start = set.start(i, k);
                let xk: Vec<f32> = start.iter().map(|&v| jitter(v)).collect();
                let uk: Vec<f32> = us[k].iter().map(|&v| jitter(v)).collect();
                for c in 0..p {
                    cx.extend_from_slice(&xk);
                    cu.extend_from_slice(&uk);
                    let t = if set.collocation_points == 0 {
                        set.dt
                    } else {
                        set.collocation[(i * intervals + k) * set.collocation_points + c]
                    };
                    ct.push(t as f32);
                }
                x.extend(xk);
                u.extend(uk);
                next.extend(xs[k + 1].iter().map(|&v| v as f32));
                clean.extend(start.iter().map(|&v| v as f32));
            }
        }
        let m = traj.len() * intervals;
        let rollout = (cfg.uses(LossKind::Rollout) || cfg.uses(LossKind::PhysicsRollout))
            .then(|| rollout_windows(set, traj, cfg.rollout_steps.min(intervals), cfg.rollout_stride, rng, device));
        Self {
            x: tensor(x, NX, device),
            u: tensor(u, NU, device),
            next: tensor(next, NX, device),
            x_clean: tensor(clean, NX, device),
            t_end: Tensor::full([m, 1], set.dt as f32, device),
            t_zero: Tensor::zeros([m, 1], device),
            colloc: (tensor(cx, NX, device), tensor(cu, NU, device), tensor(ct, 1, device)),
            rollout,
        }
    }
}

/// Windows of `steps` from every `stride`-th point (random offset below `stride`), as the
/// paper's `L_R` starts from every point that leaves room for the whole rollout.
fn rollout_windows(
    set: &TrajectorySet,
    traj: &[usize],
    steps: usize,
    stride: usize,
    rng: &mut impl Rng,
    device: &Device,
) -> RolloutBatch {
    let intervals = set.points - 1;
    let offset = rng.random_range(0..stride.min(intervals + 1 - steps));
    let starts: Vec<usize> = (offset..=intervals - steps).step_by(stride).collect();
    let mut start = Vec::new();
    let mut inputs = vec![Vec::new(); steps];
    let mut targets = vec![Vec::new(); steps];
    for &i in traj {
        let (xs, us) = set.trajectory(i);
        for &k in &starts {
            start.extend(set.start(i, k).iter().map(|&v| v as f32));
            for j in 0..steps {
                inputs[j].extend(us[k + j].iter().map(|&v| v as f32));
                targets[j].extend(xs[k + j + 1].iter().map(|&v| v as f32));
            }
        }
    }
    RolloutBatch {
        start: tensor(start, NX, device),
        inputs: inputs.into_iter().map(|d| tensor(d, NU, device)).collect(),
        targets: targets.into_iter().map(|d| tensor(d, NX, device)).collect(),
    }
}

fn mse(a: Tensor<2>, b: Tensor<2>) -> Tensor<1> {
    (a - b).powi_scalar(2).mean()
}

/// The physics residual's MSE at `(x, u, t)`: `d x_hat/dt - f(x_hat, u)`.
fn residual(net: &PincNet, params: &VehicleParams, x: Tensor<2>, u: Tensor<2>, t: Tensor<2>) -> Tensor<1> {
    let pred = net.forward(x, u.clone(), t, true);
    let rate = pred.rate.expect("tangent requested");
    mse(rate, rhs(params, pred.state, u))
}

/// Rollout loss and / or physics-rollout loss from one shared rollout.
fn rollout_losses(
    net: &PincNet,
    params: &VehicleParams,
    r: &RolloutBatch,
    t_end: f32,
    want_data: bool,
    want_physics: bool,
) -> (Option<Tensor<1>>, Option<Tensor<1>>) {
    let device = r.start.device();
    let mut x = r.start.clone();
    let (mut data, mut phys): (Option<Tensor<1>>, Option<Tensor<1>>) = (None, None);
    let add = |acc: &mut Option<Tensor<1>>, v: Tensor<1>| *acc = Some(acc.take().map_or(v.clone(), |a| a + v));
    for (j, (u, target)) in r.inputs.iter().zip(&r.targets).enumerate() {
        let [w, _] = x.dims();
        let t = Tensor::full([w, 1], t_end, &device);
        // From the second step on, the state is the previous prediction.
        let pred = net.forward_from(x, u.clone(), t, want_physics, j > 0);
        if let Some(rate) = pred.rate {
            add(&mut phys, mse(rate, rhs(params, pred.state.clone(), u.clone())));
        }
        if want_data {
            add(&mut data, mse(pred.state.clone(), target.clone()));
        }
        x = pred.state;
    }
    let n = r.inputs.len() as f64;
    (data.map(|d| d / n), phys.map(|p| p / n))
}

/// One loss on `batch` (a fresh forward pass, so each loss owns its graph).
pub fn loss(kind: LossKind, net: &PincNet, params: &VehicleParams, batch: &Batch) -> Tensor<1> {
    match kind {
        LossKind::Data => {
            mse(net.forward(batch.x.clone(), batch.u.clone(), batch.t_end.clone(), false).state, batch.next.clone())
        }
        LossKind::InitialCondition => {
            mse(net.forward(batch.x.clone(), batch.u.clone(), batch.t_zero.clone(), false).state, batch.x_clean.clone())
        }
        LossKind::Physics => {
            let (x, u, t) = batch.colloc.clone();
            residual(net, params, x, u, t)
        }
        LossKind::Rollout | LossKind::PhysicsRollout => {
            let r = batch.rollout.as_ref().expect("rollout windows built for a rollout loss");
            let t_end = batch.t_end.clone().narrow(0, 0, 1).into_scalar::<f32>();
            let want_data = kind == LossKind::Rollout;
            let (d, p) = rollout_losses(net, params, r, t_end, want_data, !want_data);
            if want_data { d } else { p }.expect("rollout has at least one step")
        }
    }
}

/// The active losses in one graph, weighted by `weights` (parallel to `cfg.losses`; a zero
/// weight leaves that loss out, uncomputed). The rollout is shared between the two rollout
/// losses. Returns `(weighted total, per-loss values)`, `None` for the losses left out.
///
/// # Panics
/// If `weights` is not parallel to `cfg.losses` or every weight is zero.
pub fn joint_losses(
    cfg: &TrainConfig,
    net: &PincNet,
    params: &VehicleParams,
    batch: &Batch,
    weights: &[f64],
) -> (Tensor<1>, Vec<Option<Tensor<1>>>) {
    assert_eq!(weights.len(), cfg.losses.len(), "one weight per active loss");
    let mut values: Vec<Option<Tensor<1>>> = vec![None; cfg.losses.len()];
    let pos = |k: LossKind| cfg.losses.iter().position(|&l| l == k).filter(|&i| weights[i] != 0.0);
    let (pr, pp) = (pos(LossKind::Rollout), pos(LossKind::PhysicsRollout));
    if let (Some(r), true) = (&batch.rollout, pr.is_some() || pp.is_some()) {
        let t_end = batch.t_end.clone().narrow(0, 0, 1).into_scalar::<f32>();
        let (d, p) = rollout_losses(net, params, r, t_end, pr.is_some(), pp.is_some());
        if let Some(i) = pr {
            values[i] = d;
        }
        if let Some(i) = pp {
            values[i] = p;
        }
    }
    for (i, &k) in cfg.losses.iter().enumerate() {
        if values[i].is_none() && weights[i] != 0.0 {
            values[i] = Some(loss(k, net, params, batch));
        }
    }
    let total = values
        .iter()
        .zip(weights)
        .filter_map(|(v, &w)| v.as_ref().map(|v| v.clone() * w))
        .reduce(|a, b| a + b)
        .expect("at least one weighted loss");
    (total, values)
}
