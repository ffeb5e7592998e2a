//! Exact Jacobians of the runtime against central finite differences in f64.

use crate::common;
use pinc::runtime::{HorizonLinearisation, Predictor};
use pinc::{Input, InputMatrix, State, StateMatrix};

fn x0() -> State {
    let psi: f64 = 0.7;
    State::from([0.3, -0.2, 0.5, psi.cos(), psi.sin(), 0.2, -0.05, 0.1, 0.15])
}

fn inputs(n: usize) -> Vec<Input> {
    (0..n)
        .map(|k| Input::new(2.0 * (0.3 * k as f64).sin(), 0.5, 4.0 + 0.2 * k as f64, 0.1 * (0.2 * k as f64).cos()))
        .collect()
}

fn step(p: &Predictor<f64>, x: &State, u: &Input) -> State {
    let mut ws = p.workspace();
    let mut out = State::zeros();
    p.step(&mut ws, x, u, &mut out).unwrap();
    out
}

/// Central differences of one step; returns (A, B).
fn finite_differences(p: &Predictor<f64>, x: &State, u: &Input) -> (StateMatrix, InputMatrix) {
    let h = 1e-6;
    let mut a = StateMatrix::zeros();
    let mut b = InputMatrix::zeros();
    for j in 0..9 {
        let mut e = State::zeros();
        e[j] = h;
        a.set_column(j, &((step(p, &(x + e), u) - step(p, &(x - e), u)) / (2.0 * h)));
    }
    for j in 0..4 {
        let mut e = Input::zeros();
        e[j] = h;
        b.set_column(j, &((step(p, x, &(u + e)) - step(p, x, &(u - e))) / (2.0 * h)));
    }
    (a, b)
}

#[test]
fn horizon_jacobians_match_central_differences_for_every_variant() {
    let mut worst_all = 0.0_f64;
    for (name, model) in common::variants() {
        for (renorm, portable) in [(false, false), (true, false), (false, true)] {
            let mut p = Predictor::reference(&model).with_yaw_renormalisation(renorm);
            if portable {
                p = p.with_portable_kernels();
            }
            let n = 20;
            let u = inputs(n);
            let mut ws = p.workspace();
            let mut lin = HorizonLinearisation::new(n);
            p.linearise_horizon(&mut ws, &x0(), &u, &mut lin).unwrap_or_else(|e| panic!("{name}: {e}"));
            let (traj, a, b) = (lin.trajectory(), lin.a(), lin.b());
            // The nominal trajectory is the rollout.
            let mut roll = vec![State::zeros(); n + 1];
            p.rollout(&mut ws, &x0(), &u, &mut roll).unwrap();
            for (t, r) in traj.iter().zip(&roll) {
                assert!((t - r).amax() < 1e-14, "{name}: nominal trajectory differs from the rollout");
            }
            for k in 0..n {
                let (fa, fb) = finite_differences(&p, &traj[k], &u[k]);
                let scale = fa.amax().max(fb.amax()).max(1.0);
                let err = (a[k] - fa).amax().max((b[k] - fb).amax()) / scale;
                worst_all = worst_all.max(err);
                assert!(err < 1e-7, "{name} (renorm {renorm}, portable {portable}) step {k}: Jacobian error {err:e}");
            }
        }
    }
    println!("worst relative Jacobian error vs central differences: {worst_all:e}");
}

#[test]
fn single_linearise_agrees_with_horizon_and_step() {
    let model = common::paper_4x32(11);
    let p = Predictor::reference(&model);
    let mut ws = p.workspace();
    let (x, u) = (x0(), inputs(1)[0]);
    let (mut next, mut a, mut b) = (State::zeros(), StateMatrix::zeros(), InputMatrix::zeros());
    p.linearise(&mut ws, &x, &u, &mut next, &mut a, &mut b).unwrap();
    assert_eq!(next, step(&p, &x, &u));
    let (fa, fb) = finite_differences(&p, &x, &u);
    assert!((a - fa).amax() < 1e-7 && (b - fb).amax() < 1e-7);
}

#[test]
fn position_free_network_has_identity_position_columns() {
    let (_, model) = common::variants().into_iter().find(|(n, _)| *n == "position-free 2x24").unwrap();
    let p = Predictor::reference(&model);
    let mut ws = p.workspace();
    let (x, u) = (x0(), inputs(1)[0]);
    let (mut next, mut a, mut b) = (State::zeros(), StateMatrix::zeros(), InputMatrix::zeros());
    p.linearise(&mut ws, &x, &u, &mut next, &mut a, &mut b).unwrap();
    // Position does not enter the network: translating x, y, z translates the prediction.
    for j in 0..3 {
        for i in 0..9 {
            assert_eq!(a[(i, j)], if i == j { 1.0 } else { 0.0 });
        }
    }
    let shift = State::from([5.0, -3.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    assert!((step(&p, &(x + shift), &u) - next - shift).amax() < 1e-12);
}

#[test]
fn f32_jacobians_agree_with_the_f64_reference() {
    for (name, model) in common::variants() {
        let p64 = Predictor::reference(&model);
        let p32 = Predictor::new(&model);
        let n = 20;
        let u = inputs(n);
        let (mut l64, mut l32) = (HorizonLinearisation::new(n), HorizonLinearisation::new(n));
        p64.linearise_horizon(&mut p64.workspace(), &x0(), &u, &mut l64).unwrap();
        p32.linearise_horizon(&mut p32.workspace(), &x0(), &u, &mut l32).unwrap();
        let (t64, a64, b64) = (l64.trajectory(), l64.a(), l64.b());
        let (t32, a32, b32) = (l32.trajectory(), l32.a(), l32.b());
        for k in 0..n {
            let scale = a64[k].amax().max(b64[k].amax()).max(1.0);
            let err = (a32[k] - a64[k]).amax().max((b32[k] - b64[k]).amax()) / scale;
            assert!(err < 1e-4, "{name} step {k}: f32 Jacobian differs by {err:e}");
            assert!((t32[k + 1] - t64[k + 1]).amax() < 1e-4, "{name} step {k}: trajectories diverge");
        }
    }
}
