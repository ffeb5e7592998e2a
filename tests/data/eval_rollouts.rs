//! The evaluator's rollouts when a prediction stops being finite: the trajectory keeps every
//! finite prediction and reads as infinite from the first non-finite one; the others are
//! unaffected.
#![cfg(feature = "tools")]

use crate::common;
use pinc::dataset::TrajectorySet;
use pinc::eval::full_rollouts;
use pinc::model::Architecture;
use pinc::runtime::{Predictor, RuntimeError};
use pinc::{Input, State};

#[test]
fn a_diverging_trajectory_is_infinite_from_its_first_non_finite_prediction() {
    // One softplus unit in its linear range carries z (+ 30) to the output, with gain 1e10:
    // from z = 0, z grows tenfold-billionfold per step until it overflows f64 (~step 31).
    // From z = -1e6 the unit is off (softplus underflows to 0) and z stays put.
    let mut arch = Architecture::paper(1, 8);
    arch.layer_norm = vec![false];
    let z_col = arch.state_inputs.iter().position(|&i| i == 2).unwrap();
    let mut model = common::random_model(arch, 11);
    let (hidden, output) = (&mut model.weights.hidden[0], &mut model.weights.output);
    hidden.beta = 1.0;
    hidden.linear.weight.fill(0.0);
    hidden.linear.bias.fill(0.0);
    hidden.linear.weight[z_col] = 1.0;
    hidden.linear.bias[0] = 30.0;
    output.weight.fill(0.0);
    output.bias.fill(0.0);
    output.weight[2 * output.cols] = 1e10;
    let points = 50;
    let x0 = |z: f64| State::from([0.0, 0.0, z, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let inputs = vec![Input::zeros(); points - 1];
    let set = TrajectorySet {
        name: "diverging".into(),
        dt: 0.08,
        count: 2,
        points,
        collocation_points: 0,
        states: [x0(0.0), x0(-1e6)].iter().flat_map(|&x| vec![x; points]).collect(),
        inputs: [inputs.clone(), inputs.clone()].concat(),
        collocation: Vec::new(),
        starts: Vec::new(),
    };
    let p = Predictor::reference(&model);
    let mut ws = p.workspace();
    let mut single = vec![State::zeros(); points];
    // Where the single rollout stops: step k fails, so predictions 1..=k are finite.
    let err = p.rollout(&mut ws, &x0(0.0), &inputs, &mut single).unwrap_err();
    let RuntimeError::NonFiniteOutput { step } = err else { panic!("{err}") };
    assert!(step > 1 && step + 1 < points, "diverges inside the horizon, at step {step}");

    let out = full_rollouts(&p, &set).unwrap();
    let (diverged, kept) = out.split_at(points);
    assert_eq!(&diverged[..=step], &single[..=step], "every finite prediction is kept");
    assert!(diverged[step + 1..].iter().all(|s| s.iter().all(|&v| v == f64::INFINITY)), "infinite after step {step}");

    p.rollout(&mut ws, &x0(-1e6), &inputs, &mut single).unwrap();
    assert_eq!(kept, &single[..], "the finite trajectory is its single rollout");
}

#[test]
fn a_non_finite_sample_in_a_set_is_an_error_at_that_sample() {
    // The physics residual steps the network from every true state; a NaN there is the
    // set's fault and is named at its sample (before, it was reported as state[0] = NaN at
    // step 0 whatever it was).
    let model = common::random_model(Architecture::paper(1, 8), 3);
    let points = 6;
    let mut set = TrajectorySet {
        name: "bad".into(),
        dt: 0.08,
        count: 2,
        points,
        collocation_points: 0,
        states: vec![State::from([0.0, 0.0, 0.5, 1.0, 0.0, 0.1, 0.0, 0.0, 0.0]); 2 * points],
        inputs: vec![Input::new(1.0, 0.0, 2.0, 0.0); 2 * (points - 1)],
        collocation: Vec::new(),
        starts: Vec::new(),
    };
    let p = Predictor::reference(&model);
    let params = pinc::vehicle::VehicleParams::default();
    assert!(pinc::eval::physics_mse(&p, &params, &set).unwrap().is_finite());
    set.states[points + 3][7] = f64::NAN;
    let err = pinc::eval::physics_mse(&p, &params, &set).unwrap_err();
    assert!(matches!(err, RuntimeError::NonFiniteState { step: 3, index: 7, value } if value.is_nan()), "{err}");
    set.states[points + 3][7] = 0.0;
    set.inputs[points - 1 + 2][1] = f64::INFINITY;
    let err = pinc::eval::physics_mse(&p, &params, &set).unwrap_err();
    assert_eq!(err, RuntimeError::NonFiniteInput { step: 2, index: 1, value: f64::INFINITY });
}
