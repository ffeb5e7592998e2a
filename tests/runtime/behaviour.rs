//! Batch rollout against single rollouts, bad input, and the envelope flag.

use crate::common;
use pinc::runtime::{BatchWorkspace, HorizonLinearisation, Predictor, Quantity, Real, RuntimeError};
use pinc::{Input, State};

/// Random networks drift; 30 steps keep every variant finite.
const STEPS: usize = 30;

fn case(i: usize) -> (State, Vec<Input>) {
    let psi = 0.37 * i as f64;
    let x0 = State::from([0.01 * i as f64, -0.2, 0.3, psi.cos(), psi.sin(), 0.1, 0.0, 0.05, 0.02 * i as f64]);
    let inputs =
        (0..STEPS).map(|k| Input::new((0.1 * (k + i) as f64).sin(), 0.2, 3.0 + 0.01 * k as f64, 0.05)).collect();
    (x0, inputs)
}

#[test]
fn steps_match_a_plain_reference_for_every_variant() {
    // The runtime folds scalings, betas and LayerNorm affines into padded weight packs; the
    // reference computes the network as written down. f32 differs by rounding only.
    for (name, model) in common::variants() {
        for (precision, tol) in [("f64", 1e-12), ("f32", 2e-5)] {
            for portable in [false, true] {
                let mut worst = 0.0_f64;
                for i in 0..20 {
                    let (x, inputs) = case(i);
                    let (t, u) = (0.02 + 0.01 * i as f64, inputs[i % STEPS]);
                    let want = common::reference_step(&model, &x.into(), &u.into(), t);
                    let got = if precision == "f64" {
                        step_with::<f64>(&model, portable, &x, &u, t)
                    } else {
                        step_with::<f32>(&model, portable, &x, &u, t)
                    };
                    for k in 0..9 {
                        worst = worst.max((got[k] - want[k]).abs() / want[k].abs().max(1.0));
                    }
                }
                assert!(worst < tol, "{name} {precision} (portable {portable}): max relative error {worst:e}");
            }
        }
    }
}

fn step_with<T: Real>(model: &pinc::model::PincModel, portable: bool, x: &State, u: &Input, t: f64) -> State {
    let mut p = Predictor::<T>::from_model(model);
    if portable {
        p = p.with_portable_kernels();
    }
    let mut next = State::zeros();
    p.step_dt(&mut p.workspace(), x, u, t, &mut next).unwrap();
    next
}

#[test]
fn batch_rollout_equals_single_rollouts() {
    // f64: the same arithmetic up to summation order, so equal to 1e-12. f32: the batch
    // sums in another order, and 30 steps of a random network amplify rounding; the bound
    // is twice the variant's rounding scale: the largest distance of an f32 single rollout
    // (either kernel) from the f64 one over the same 70 trajectories.
    batch_equals_single::<f32>(|model| 2.0 * rounding_scale(model));
    batch_equals_single::<f64>(|_| 1e-12);
}

fn rounding_scale(model: &pinc::model::PincModel) -> f64 {
    let p64 = Predictor::reference(model);
    let (mut a, mut b) = (vec![State::zeros(); STEPS + 1], vec![State::zeros(); STEPS + 1]);
    let mut worst = 0.0_f64;
    // Both f32 kernels: they sum in different orders, and either is compared below.
    for p32 in [Predictor::new(model), Predictor::new(model).with_portable_kernels()] {
        for i in 0..70 {
            let (x0, inputs) = case(i);
            p32.rollout(&mut p32.workspace(), &x0, &inputs, &mut a).unwrap();
            p64.rollout(&mut p64.workspace(), &x0, &inputs, &mut b).unwrap();
            worst = a.iter().zip(&b).map(|(a, b)| (a - b).amax()).fold(worst, f64::max);
        }
    }
    worst
}

fn batch_equals_single<T: Real>(tol: impl Fn(&pinc::model::PincModel) -> f64) {
    for (name, model) in common::variants() {
        let tol = tol(&model);
        for portable in [false, true] {
            let mut p = Predictor::<T>::from_model(&model);
            if portable {
                p = p.with_portable_kernels();
            }
            let n = 70; // more than two blocks of lanes, the last one partial
            let (x0, inputs): (Vec<State>, Vec<Vec<Input>>) = (0..n).map(case).unzip();
            let flat: Vec<Input> = inputs.concat();
            let mut out = vec![State::zeros(); n * (STEPS + 1)];
            p.rollout_batch(&mut BatchWorkspace::new(&p), &x0, &flat, &mut out)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            let mut ws = p.workspace();
            let mut single = vec![State::zeros(); STEPS + 1];
            for i in 0..n {
                p.rollout(&mut ws, &x0[i], &inputs[i], &mut single).unwrap();
                for k in 0..=STEPS {
                    let err = (out[i * (STEPS + 1) + k] - single[k]).amax();
                    assert!(err < tol, "{name} (portable {portable}) trajectory {i} step {k}: {err:e} (bound {tol:e})");
                }
            }
        }
    }
}

#[test]
fn fused_and_portable_kernels_agree() {
    let model = common::paper_4x32(3);
    let (x0, inputs) = case(5);
    let mut a = vec![State::zeros(); STEPS + 1];
    let mut b = vec![State::zeros(); STEPS + 1];
    let fused = Predictor::reference(&model);
    let portable = Predictor::reference(&model).with_portable_kernels();
    fused.rollout(&mut fused.workspace(), &x0, &inputs, &mut a).unwrap();
    portable.rollout(&mut portable.workspace(), &x0, &inputs, &mut b).unwrap();
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).amax() < 1e-12);
    }
}

#[test]
fn non_finite_arguments_are_errors_naming_the_component() {
    let p = Predictor::new(&common::paper_4x32(1));
    let mut ws = p.workspace();
    let (x0, mut inputs) = case(0);
    let mut out = State::zeros();
    let mut bad = x0;
    bad[6] = f64::NAN;
    let err = p.step(&mut ws, &bad, &inputs[0], &mut out).unwrap_err();
    assert!(matches!(err, RuntimeError::NonFiniteState { step: 0, index: 6, value } if value.is_nan()), "{err}");
    inputs[20][2] = f64::INFINITY;
    let mut traj = vec![State::zeros(); STEPS + 1];
    assert_eq!(
        p.rollout(&mut ws, &x0, &inputs, &mut traj).unwrap_err(),
        RuntimeError::NonFiniteInput { step: 20, index: 2, value: f64::INFINITY }
    );
    assert!(matches!(p.step_dt(&mut ws, &x0, &inputs[0], 0.0, &mut out), Err(RuntimeError::BadTimeStep(_))));
    assert!(matches!(
        p.rollout(&mut ws, &x0, &inputs[..3], &mut traj),
        Err(RuntimeError::LengthMismatch { expected: 4, found: 31, .. })
    ));
    let mut bws = BatchWorkspace::new(&p);
    let mut bout = vec![State::zeros(); 2 * (STEPS + 1)];
    assert!(matches!(
        p.rollout_batch(&mut bws, &[x0, x0], &[inputs.clone(), inputs.clone()].concat(), &mut bout),
        Err(RuntimeError::NonFiniteInput { step: 20, index: 2, .. })
    ));
    // No trajectories: whichever buffer is not empty is named.
    let none: [State; 0] = [];
    assert_eq!(
        p.rollout_batch(&mut bws, &none, &[], &mut bout[..3]).unwrap_err(),
        RuntimeError::LengthMismatch { what: "batch output", expected: 0, found: 3 }
    );
    assert_eq!(
        p.rollout_batch(&mut bws, &none, &inputs[..2], &mut []).unwrap_err(),
        RuntimeError::LengthMismatch { what: "batch inputs", expected: 0, found: 2 }
    );
    assert_eq!(p.rollout_batch(&mut bws, &none, &[], &mut []), Ok(()));
}

#[test]
fn a_state_beyond_the_network_precision_is_an_error_not_a_finite_guess() {
    // 1e39 is finite in f64 but infinite in the f32 network; the NaNs it makes inside (inf -
    // inf) must reach the output as an error, in the single and in the batch path. (Before,
    // the softplus's max(y, 0) turned them into 0 and the step returned a finite state.)
    let p = Predictor::new(&common::paper_4x32(4));
    let (mut x, inputs) = case(1);
    x[2] = 1e39;
    let err = p.step(&mut p.workspace(), &x, &inputs[0], &mut State::zeros()).unwrap_err();
    assert_eq!(err, RuntimeError::NonFiniteOutput { step: 0 });
    let mut out = vec![State::zeros(); 2];
    let err = p.rollout_batch(&mut BatchWorkspace::new(&p), &[x], &inputs[..1], &mut out).unwrap_err();
    assert_eq!(err, RuntimeError::BatchDiverged { count: 1, trajectory: 0, step: 0 }, "batch");
}

#[test]
fn a_diverging_trajectory_does_not_cost_the_rest_of_the_batch() {
    // Trajectory 1 of 3 diverges at its first step; 0 and 2 must come out as they do in a
    // batch without it (lanes are computed independently, so bit for bit), and 1 keeps its
    // initial state with NaN after it.
    let p = Predictor::new(&common::paper_4x32(4));
    let (a, ua) = case(1);
    let (c, uc) = case(2);
    let mut bad = a;
    bad[2] = 1e39;
    let mut bws = BatchWorkspace::new(&p);
    let mut out = vec![State::zeros(); 3 * (STEPS + 1)];
    let err = p.rollout_batch(&mut bws, &[a, bad, c], &[ua.clone(), ua.clone(), uc.clone()].concat(), &mut out);
    assert_eq!(err, Err(RuntimeError::BatchDiverged { count: 1, trajectory: 1, step: 0 }));
    let mut clean = vec![State::zeros(); 2 * (STEPS + 1)];
    p.rollout_batch(&mut bws, &[a, c], &[ua, uc].concat(), &mut clean).unwrap();
    let n = STEPS + 1;
    assert_eq!(out[..n], clean[..n]);
    assert_eq!(out[2 * n..], clean[n..]);
    assert_eq!(out[n], bad);
    assert!(out[n + 1..2 * n].iter().all(|s| s.iter().all(|v| v.is_nan())));
}

#[test]
fn leaving_the_training_envelope_is_flagged_not_refused() {
    let model = common::with_extras(common::paper_4x32(2));
    let p = Predictor::new(&model);
    let mut ws = p.workspace();
    let (x0, mut inputs) = case(0);
    let mut traj = vec![State::zeros(); STEPS + 1];
    p.rollout(&mut ws, &x0, &inputs[..10], &mut traj[..11]).unwrap();
    assert!(ws.envelope_status().inside(), "{:?}", ws.envelope_status());
    inputs[4][3] = 1.5; // Mz above the 1 N m seen in training
    inputs[7][0] = -11.0;
    p.rollout(&mut ws, &x0, &inputs[..10], &mut traj[..11]).unwrap();
    let status = ws.envelope_status();
    assert_eq!(status.exits, 2);
    let first = status.first.unwrap();
    assert_eq!((first.step, first.quantity, first.value, first.max), (4, Quantity::Input(3), 1.5, 1.0));
    // The status is per call: a clean call clears it.
    inputs[4][3] = 0.0;
    inputs[7][0] = 0.0;
    p.rollout(&mut ws, &x0, &inputs[..10], &mut traj[..11]).unwrap();
    assert!(ws.envelope_status().inside());
}

#[test]
fn envelope_covers_only_what_the_network_sees() {
    let (_, model) = common::variants().into_iter().find(|(n, _)| *n == "position-free 2x24").unwrap();
    let p = Predictor::new(&model);
    let mut ws = p.workspace();
    let (mut x0, inputs) = case(0);
    x0[0] = 50.0; // far outside the position range, but position is not a network input
    let mut out = State::zeros();
    p.step(&mut ws, &x0, &inputs[0], &mut out).unwrap();
    assert!(ws.envelope_status().inside());
    x0[5] = 3.0; // surge speed is seen
    p.step(&mut ws, &x0, &inputs[0], &mut out).unwrap();
    assert_eq!(ws.envelope_status().first.unwrap().quantity, Quantity::State(5));
}

#[test]
fn batch_envelope_flags_match_the_single_rollouts() {
    // The batch checks the envelope lane-wise and looks at single lanes only where something
    // left it; what it records must be what 40 single rollouts record (two blocks of lanes):
    // every exit counted (the random network also drifts out), the first in the batch's order
    // (block, then step, then trajectory).
    let p = Predictor::new(&common::with_extras(common::paper_4x32(2)));
    let n = 40;
    let mut x0 = Vec::new();
    let mut inputs = Vec::new();
    for i in 0..n {
        let (mut x, mut u) = case(i % 7);
        match i {
            3 => u[9][3] = 1.5,                     // Mz above its training range at step 9
            17 => u[4][0] = -11.0,                  // X below it at step 4
            21 => (u[4][1], u[12][2]) = (9.0, 9.0), // two steps of one trajectory
            33 => x[5] = 3.0,                       // a seen state at step 0, second block
            _ => {}
        }
        x0.push(x);
        inputs.extend(u);
    }
    let (mut exits, mut first) = (0, None);
    let mut ws = p.workspace();
    let mut traj = vec![State::zeros(); STEPS + 1];
    for (i, x) in x0.iter().enumerate() {
        p.rollout(&mut ws, x, &inputs[i * STEPS..(i + 1) * STEPS], &mut traj).unwrap();
        let status = ws.envelope_status();
        exits += status.exits;
        if let Some(exit) = status.first {
            let key = (i / 32, exit.step, i);
            if first.is_none_or(|(k, _)| key < k) {
                first = Some((key, exit));
            }
        }
    }
    assert!(exits > 5, "the planted exits and those of the drifting random network: {exits}");
    let mut bws = BatchWorkspace::new(&p);
    let mut out = vec![State::zeros(); n * (STEPS + 1)];
    p.rollout_batch(&mut bws, &x0, &inputs, &mut out).unwrap();
    let status = bws.envelope_status();
    assert_eq!(status.exits, exits);
    let (_, want) = first.unwrap();
    assert_eq!(status.first, Some(want));
    assert_eq!((want.step, want.quantity), (4, Quantity::Input(0)));
}

#[test]
fn a_workspace_or_output_made_for_another_predictor_or_horizon_is_an_error_not_a_panic() {
    let small = Predictor::new(&common::random_model(pinc::model::Architecture::paper(2, 8), 1));
    let large = Predictor::new(&common::paper_4x32(2));
    let (x0, inputs) = case(0);
    let mut traj = vec![State::zeros(); 11];
    let mut next = State::zeros();
    let mismatch = RuntimeError::WorkspaceMismatch { what: "workspace" };
    // Buffers sized for 2 x 8 are too small for 4 x 32, and the reverse has other strides.
    for (p, other) in [(&large, &small), (&small, &large)] {
        let mut ws = other.workspace();
        assert_eq!(p.rollout(&mut ws, &x0, &inputs[..10], &mut traj), Err(mismatch));
        assert_eq!(p.step(&mut ws, &x0, &inputs[0], &mut next), Err(mismatch));
        let mut lin = HorizonLinearisation::new(10);
        assert_eq!(p.linearise_horizon(&mut ws, &x0, &inputs[..10], &mut lin), Err(mismatch));
        let mut bws = BatchWorkspace::new(other);
        let mut out = vec![State::zeros(); 11];
        assert_eq!(
            p.rollout_batch(&mut bws, &[x0], &inputs[..10], &mut out),
            Err(RuntimeError::WorkspaceMismatch { what: "batch workspace" })
        );
    }
    // The right workspace, a linearisation output for another horizon.
    let mut ws = large.workspace();
    let mut lin = HorizonLinearisation::new(20);
    assert_eq!(
        large.linearise_horizon(&mut ws, &x0, &inputs[..10], &mut lin),
        Err(RuntimeError::HorizonMismatch { expected: 20, found: 10 })
    );
    assert_eq!(lin, HorizonLinearisation::new(20), "nothing written on a refused call");
    large.linearise_horizon(&mut ws, &x0, &inputs[..20], &mut lin).unwrap();
    assert_eq!(lin.trajectory()[0], x0);
}

/// The full-thrust controller model under a hard turn while surging and diving: its raw
/// `(cos psi, sin psi)` drifts off the unit circle along the horizon.
fn turning_horizon() -> (pinc::model::PincModel, State, Vec<Input>) {
    let model = pinc::model::PincModel::load(concat!(env!("CARGO_MANIFEST_DIR"), "/models/mpc_pinc_thrust.pinc"))
        .expect("shipped model");
    let x0 = State::from([0.0, 0.0, 1.0, 1.0, 0.0, 0.3, 0.0, 0.1, 0.5]);
    let inputs = (0..40).map(|k| Input::new(60.0, 0.0, 30.0, if k < 20 { 20.0 } else { -20.0 })).collect();
    (model, x0, inputs)
}

#[test]
fn heading_vectors_stay_on_the_unit_circle_and_drift_is_its_own_warning() {
    let (model, x0, inputs) = turning_horizon();
    let n = inputs.len();
    let mut raw = vec![State::zeros(); n + 1];
    let bare = Predictor::new(&model).with_yaw_renormalisation(false);
    let mut ws = bare.workspace();
    bare.rollout(&mut ws, &x0, &inputs, &mut raw).unwrap();
    // Without rescaling each stored state is the raw prediction: count its drift by hand.
    let by_hand = raw[1..].iter().filter(|x| (x[3].hypot(x[4]) - 1.0).abs() > pinc::runtime::HEADING_TOLERANCE).count();
    assert!(by_hand > 0, "the case must drift for the test to mean anything");
    let status = ws.envelope_status();
    assert_eq!(status.heading_off_circle, by_hand);
    let worst = status.heading_worst.unwrap();
    let v = raw[worst.step + 1];
    assert!((worst.deviation - (v[3].hypot(v[4]) - 1.0)).abs() < 1e-15, "{worst:?}");

    // Rescaled (the default): every state on the circle; the raw drift is still reported.
    let p = Predictor::new(&model);
    let mut ws = p.workspace();
    let mut out = vec![State::zeros(); n + 1];
    p.rollout(&mut ws, &x0, &inputs, &mut out).unwrap();
    for (k, x) in out.iter().enumerate() {
        assert!((x[3].hypot(x[4]) - 1.0).abs() < 1e-12, "step {k}: |(cos, sin)| = {}", x[3].hypot(x[4]));
    }
    let status = ws.envelope_status();
    assert!(!status.heading_on_circle() && status.heading_off_circle <= n);
    // Heading is not an envelope quantity: no exit names cos psi or sin psi.
    assert!(status.worst_exits().iter().all(|e| !matches!(e.quantity, Quantity::State(3 | 4))));

    // The batch counts the same predictions.
    let mut batch_out = vec![State::zeros(); 2 * (n + 1)];
    let mut bws = BatchWorkspace::new(&p);
    let both: Vec<Input> = inputs.iter().chain(&inputs).copied().collect();
    p.rollout_batch(&mut bws, &[x0, x0], &both, &mut batch_out).unwrap();
    assert_eq!(bws.envelope_status().heading_off_circle, 2 * status.heading_off_circle);

    // A caller's state off the circle is not an envelope exit either.
    let mut off = x0;
    off[3] = 1.05;
    p.step(&mut ws, &off, &inputs[0], &mut out[0]).unwrap();
    assert!(ws.envelope_status().worst_exits().iter().all(|e| !matches!(e.quantity, Quantity::State(3 | 4))));
}
