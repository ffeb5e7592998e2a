//! The hybrid model: the vehicle's RK4 step plus the network's correction, through the same
//! calls as a PINC.

use crate::common;
use pinc::model::PincModel;
use pinc::runtime::{HorizonLinearisation, Predictor};
use pinc::vehicle::{Rk4Vehicle, to_network};
use pinc::{Input, SimState, State};

/// A hybrid whose network outputs zero everywhere (the trainer's starting point).
fn silent_hybrid(substeps: u32) -> PincModel {
    let mut m = common::hybrid(common::paper_4x32(21), substeps);
    m.weights.output.weight.iter_mut().for_each(|w| *w = 0.0);
    m.weights.output.bias.iter_mut().for_each(|b| *b = 0.0);
    m
}

fn inputs(n: usize) -> Vec<Input> {
    (0..n).map(|k| Input::new(8.0 * (0.2 * k as f64).sin(), -3.0, 6.0, 1.5 * (0.1 * k as f64).cos())).collect()
}

#[test]
fn a_silent_hybrid_is_its_vehicle_as_pinc_simulate_integrates_it() {
    let model = silent_hybrid(16);
    let vehicle = Rk4Vehicle { params: model.vehicle, dt: model.dt, substeps: 16 };
    let s0 = SimState::from([1.0, -2.0, 3.0, 2.9, 0.3, -0.1, 0.05, 0.2]);
    let u = inputs(100);
    let truth = vehicle.simulate(&s0, &u);
    let (p32, p64) = (Predictor::new(&model), Predictor::reference(&model));
    assert!(p32.is_hybrid() && p64.is_hybrid());
    for precision in ["f32", "f64"] {
        let mut traj = vec![State::zeros(); u.len() + 1];
        match precision {
            "f32" => p32.rollout(&mut p32.workspace(), &to_network(&s0), &u, &mut traj).unwrap(),
            _ => p64.rollout(&mut p64.workspace(), &to_network(&s0), &u, &mut traj).unwrap(),
        }
        let worst = traj.iter().zip(&truth).map(|(x, s)| (x - to_network(s)).amax()).fold(0.0, f64::max);
        // Only the heading vector's renormalisation separates them (RK4 keeps it on the circle
        // to about 1e-12 per step).
        assert!(worst < 1e-9, "{precision}: 8 s of a silent hybrid differ from the vehicle by {worst:e}");
    }
    // Its linearisation is the vehicle's (RK4 sensitivities), up to the renormalisation.
    let p = Predictor::reference(&model).with_yaw_renormalisation(false);
    let mut lin = HorizonLinearisation::new(10);
    let x0 = to_network(&s0);
    p.linearise_horizon(&mut p.workspace(), &x0, &u[..10], &mut lin).unwrap();
    for k in 0..10 {
        let (next, a, b) = vehicle.step_with_jacobians(&lin.trajectory()[k], &u[k]);
        assert!((next - lin.trajectory()[k + 1]).amax() < 1e-12);
        assert!((a - lin.a()[k]).amax() < 1e-12 && (b - lin.b()[k]).amax() < 1e-12, "step {k}");
    }
}

#[test]
fn the_correction_is_added_to_the_physics_step() {
    // Against the plain reference (network written out, physics by `rk4`) at times other
    // than the model's period: the physics is integrated over the asked time.
    for (name, model) in common::variants().into_iter().filter(|(_, m)| m.hybrid.is_some()) {
        let p = Predictor::reference(&model);
        let x = State::from([0.5, 0.1, 2.0, 0.6_f64.cos(), 0.6_f64.sin(), 0.4, -0.2, 0.1, 0.3]);
        let u = Input::new(10.0, -4.0, 8.0, 1.0);
        for t in [0.04, 0.08, 0.1] {
            let mut got = State::zeros();
            p.step_dt(&mut p.workspace(), &x, &u, t, &mut got).unwrap();
            let want = common::reference_step(&model, &x.into(), &u.into(), t);
            let err = (got - State::from(want)).amax();
            assert!(err < 1e-12, "{name} at t = {t}: {err:e}");
            // And the correction is not nothing: the physics alone is elsewhere.
            let physics =
                Rk4Vehicle { params: model.vehicle, dt: t, substeps: model.hybrid.unwrap().substeps as usize }
                    .step_network(&x, &u);
            assert!((got - physics).amax() > 1e-4, "{name}: the network adds nothing");
        }
    }
}

/// Anchored at rest, a hybrid at rest (any position and heading, no velocity, the heave force
/// that holds its physics still) steps exactly as its physics over any period, through the
/// single, f32 and batch calls.
#[test]
fn an_anchored_hybrid_at_rest_steps_as_its_physics() {
    let mut model = PincModel::load(concat!(env!("CARGO_MANIFEST_DIR"), "/models/hybrid_plant_a.pinc")).unwrap();
    model.hybrid = Some(pinc::model::HybridPhysics { rest_anchored: true, ..model.hybrid.unwrap() });
    let (p32, p64) = (Predictor::new(&model), Predictor::reference(&model));
    let rests: Vec<SimState> = (0..5)
        .map(|i| SimState::from([i as f64, -2.0 * i as f64, 0.5 + i as f64, 0.7 * i as f64 - 1.3, 0.0, 0.0, 0.0, 0.0]))
        .collect();
    for dt in [model.dt, 0.05] {
        let physics = model.hybrid_vehicle().unwrap().over(dt);
        let hold = model.rest_input();
        let zero = [hold];
        for s in &rests {
            let want = physics.step_network(&to_network(s), &hold);
            let mut traj = [State::zeros(); 2];
            p64.rollout_dt(&mut p64.workspace(), &to_network(s), &zero, dt, &mut traj).unwrap();
            assert!((traj[1] - want).amax() < 1e-12, "f64, dt {dt}: {}", (traj[1] - want).amax());
            p32.rollout_dt(&mut p32.workspace(), &to_network(s), &zero, dt, &mut traj).unwrap();
            // f32: the output at rest is computed once, by the portable kernel; the call's own
            // kernel may round the same sum differently.
            assert!((traj[1] - want).amax() < 1e-6, "f32, dt {dt}: {}", (traj[1] - want).amax());
        }
        let x0: Vec<State> = rests.iter().map(to_network).collect();
        let mut out = vec![State::zeros(); 2 * x0.len()];
        let mut ws = pinc::runtime::BatchWorkspace::new(&p32);
        p32.rollout_batch_dt(&mut ws, &x0, &vec![hold; x0.len()], dt, &mut out).unwrap();
        for (i, s) in rests.iter().enumerate() {
            let want = physics.step_network(&to_network(s), &hold);
            assert!((out[2 * i + 1] - want).amax() < 1e-6, "batch, dt {dt}");
        }
    }
    // Unanchored, the same weights move the vehicle at rest (what the anchoring removes).
    let plain = PincModel::load(concat!(env!("CARGO_MANIFEST_DIR"), "/models/hybrid_plant_a.pinc")).unwrap();
    let p = Predictor::reference(&plain);
    let mut next = State::zeros();
    let hold = plain.rest_input();
    p.step(&mut p.workspace(), &to_network(&rests[0]), &hold, &mut next).unwrap();
    let physics = plain.hybrid_vehicle().unwrap().step_network(&to_network(&rests[0]), &hold);
    assert!((next - physics).amax() > 1e-5, "{}", (next - physics).amax());
}
