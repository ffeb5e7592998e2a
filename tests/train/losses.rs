//! Each training loss against an independent computation with the frozen f64 runtime
//! (forward passes, rollouts, and time derivatives by central differences).
#![cfg(feature = "train")]

use crate::common;
use burn::prelude::*;
use pinc::dataset::{DatasetPreset, TrajectorySet, generate_set};
use pinc::runtime::Predictor;
use pinc::train::{Batch, LossKind, PincNet, TrainConfig, loss};
use pinc::vehicle;
use pinc::{Input, State};
use rand::SeedableRng;

const STEPS: usize = 5;

fn small_set() -> TrajectorySet {
    let mut spec = DatasetPreset::paper().set("train").unwrap().clone();
    spec.count = 3;
    generate_set(&spec, &Default::default(), 11, || {})
}

fn value(t: Tensor<1>) -> f64 {
    f64::from(t.into_scalar::<f32>())
}

/// `d x_hat / dt` at `dt` by central differences of the f64 runtime, and `x_hat(dt)`.
fn rate(p: &Predictor<f64>, x: &State, u: &Input, dt: f64) -> (State, State) {
    let mut ws = p.workspace();
    let h = 1e-6;
    let (mut a, mut b, mut at) = (State::zeros(), State::zeros(), State::zeros());
    p.step_dt(&mut ws, x, u, dt + h, &mut a).unwrap();
    p.step_dt(&mut ws, x, u, dt - h, &mut b).unwrap();
    p.step_dt(&mut ws, x, u, dt, &mut at).unwrap();
    (at, (a - b) / (2.0 * h))
}

fn assert_rel(got: f64, want: f64, what: &str) {
    let rel = (got - want).abs() / want.abs();
    assert!(rel < 2e-3, "{what}: burn {got:e} vs runtime {want:e} (relative {rel:e})");
}

#[test]
fn every_loss_matches_the_runtime() {
    losses_match_the_runtime(common::paper_4x32(21));
}

#[test]
fn every_loss_of_a_hybrid_matches_the_runtime() {
    // The physics (another vehicle than the data's) enters every loss, its time derivative
    // included: the runtime's is by central differences of the RK4 step in its length.
    losses_match_the_runtime(common::hybrid(common::paper_4x32(21), 16));
}

fn losses_match_the_runtime(model: pinc::model::PincModel) {
    let device = Device::flex();
    let set = small_set();
    let net = PincNet::from_model(&model, &device);
    // burn computes the bare network: compare with the runtime without its heading rescaling.
    let p = Predictor::reference(&model).with_yaw_renormalisation(false);
    let params = model.vehicle;
    let mut cfg = TrainConfig::paper();
    cfg.rollout_steps = STEPS;
    cfg.rollout_stride = 1;
    let traj = [0, 1, 2];
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let batch = Batch::new(&set, &traj, &cfg, &mut rng, &device);

    let mut ws = p.workspace();
    let (mut data, mut phys, mut roll, mut phys_roll) = (0.0, 0.0, 0.0, 0.0);
    let (mut n, mut windows) = (0usize, 0usize);
    for &i in &traj {
        let (xs, us) = set.trajectory(i);
        for k in 0..us.len() {
            let mut next = State::zeros();
            p.step(&mut ws, &xs[k], &us[k], &mut next).unwrap();
            data += (next - xs[k + 1]).norm_squared();
            let (at, r) = rate(&p, &xs[k], &us[k], set.dt);
            phys += (r - vehicle::rhs(&params, &at, &us[k])).norm_squared();
            n += 1;
        }
        for k in 0..=us.len() - STEPS {
            let mut x = xs[k];
            for j in 0..STEPS {
                let (at, r) = rate(&p, &x, &us[k + j], set.dt);
                phys_roll += (r - vehicle::rhs(&params, &at, &us[k + j])).norm_squared();
                roll += (at - xs[k + j + 1]).norm_squared();
                x = at;
            }
            windows += 1;
        }
    }
    let per = |sum: f64, count: usize| sum / (count * 9) as f64;
    assert_rel(value(loss(LossKind::Data, &net, &params, &batch)), per(data, n), "data loss");
    assert_rel(value(loss(LossKind::Physics, &net, &params, &batch)), per(phys, n), "physics loss");
    assert_rel(value(loss(LossKind::Rollout, &net, &params, &batch)), per(roll, windows * STEPS), "rollout loss");
    assert_rel(
        value(loss(LossKind::PhysicsRollout, &net, &params, &batch)),
        per(phys_roll, windows * STEPS),
        "physics-rollout loss",
    );
    // The initial-condition loss is the residual network's output at t = 0, which the runtime
    // cannot evaluate (it refuses dt = 0); with zero output weights it must vanish exactly.
    let mut zero = model.clone();
    zero.weights.output.weight.fill(0.0);
    zero.weights.output.bias.fill(0.0);
    let ic = value(loss(LossKind::InitialCondition, &PincNet::from_model(&zero, &device), &params, &batch));
    // A hybrid's physics over t = 0 is the state itself (RK4 steps of length zero).
    assert_eq!(ic, 0.0);
    assert!(value(loss(LossKind::InitialCondition, &net, &params, &batch)) > 0.0);
}
