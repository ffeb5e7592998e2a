//! Import + runtime against outputs PyTorch computed for the same random weights
//! (tests/fixtures, made outside this project: float32 on CPU, layout of the paper's code).
#![cfg(feature = "tools")]

use pinc::model::{Activation, import_state_dict};
use pinc::runtime::{Predictor, Real};
use pinc::{Input, State};
use serde_json::Value;

struct Fixture {
    model: pinc::model::PincModel,
    expected: Value,
}

fn fixture(name: &str) -> Fixture {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/");
    let weights = std::fs::read(format!("{dir}{name}.safetensors")).unwrap();
    let expected: Value =
        serde_json::from_str(&std::fs::read_to_string(format!("{dir}{name}_expected.json")).unwrap()).unwrap();
    Fixture { model: import_state_dict(&weights, 0.08, Activation::Softplus).unwrap(), expected }
}

fn vec_of(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

fn check_fixture(name: &str, layers: usize, width: usize) {
    check_fixture_in::<f32>(name, layers, width);
    check_fixture_in::<f64>(name, layers, width);
}

fn check_fixture_in<T: Real>(name: &str, layers: usize, width: usize) {
    let precision = std::any::type_name::<T>();
    let f = fixture(name);
    let arch = &f.model.architecture;
    assert_eq!((arch.hidden_layers, arch.width), (layers, width));
    assert_eq!(
        arch.layer_norm,
        (0..layers).map(|l| l % 2 == 0).collect::<Vec<_>>(),
        "LayerNorm after hidden layers 1, 3, .."
    );
    for portable in [false, true] {
        // PyTorch's network leaves (cos psi, sin psi) as predicted.
        let mut p = Predictor::<T>::from_model(&f.model).with_yaw_renormalisation(false);
        if portable {
            p = p.with_portable_kernels();
        }
        let mut ws = p.workspace();
        // Single steps: 8 rows of [state(9), input(4), dt].
        let ss = &f.expected["single_step"];
        let mut worst_step = 0.0_f64;
        for (inp, out) in ss["inputs"].as_array().unwrap().iter().zip(ss["outputs"].as_array().unwrap()) {
            let v = vec_of(inp);
            let x = State::from_column_slice(&v[..9]);
            let u = Input::from_column_slice(&v[9..13]);
            let mut next = State::zeros();
            p.step_dt(&mut ws, &x, &u, v[13], &mut next).unwrap();
            for (a, b) in next.iter().zip(vec_of(out)) {
                worst_step = worst_step.max((a - b).abs());
            }
        }
        assert!(
            worst_step < 1e-5,
            "{name} {precision}: single-step max abs error {worst_step:e} (portable {portable})"
        );
        // 65-step rollout.
        let r = &f.expected["rollout"];
        let x0 = State::from_column_slice(&vec_of(&r["x0"]));
        let dt = r["dt"].as_f64().unwrap();
        let inputs: Vec<Input> =
            r["inputs"].as_array().unwrap().iter().map(|u| Input::from_column_slice(&vec_of(u))).collect();
        let mut traj = vec![State::zeros(); inputs.len() + 1];
        p.rollout_dt(&mut ws, &x0, &inputs, dt, &mut traj).unwrap();
        let mut worst_roll = 0.0_f64;
        for (got, want) in traj.iter().zip(r["states"].as_array().unwrap()) {
            for (a, b) in got.iter().zip(vec_of(want)) {
                worst_roll = worst_roll.max((a - b).abs() / b.abs().max(1.0));
            }
        }
        assert!(
            worst_roll < 1e-4,
            "{name} {precision}: rollout max relative error {worst_roll:e} (portable {portable})"
        );
        println!(
            "{name} {precision} portable={portable}: single step {worst_step:.2e} abs, rollout {worst_roll:.2e} rel"
        );
    }
}

#[test]
fn random_4x32_matches_pytorch() {
    check_fixture("random_4x32", 4, 32);
}

#[test]
fn random_3x16_matches_pytorch() {
    check_fixture("random_3x16", 3, 16);
}
