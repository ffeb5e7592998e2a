//! The burn network and the frozen runtime compute the same function on the same weights.
#![cfg(feature = "train")]

use burn::prelude::*;
use pinc::model::{Activation, import_state_dict};
use pinc::runtime::Predictor;
use pinc::train::PincNet;
use pinc::{Input, State};

#[test]
fn burn_forward_matches_the_runtime_within_1e5() {
    let device = Device::flex();
    let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/random_4x32.safetensors")).unwrap();
    let model = import_state_dict(&bytes, 0.08, Activation::Softplus).unwrap();
    let net = PincNet::from_model(&model, &device);
    // burn computes the bare network: compare with the runtime without its heading rescaling.
    let p = Predictor::reference(&model).with_yaw_renormalisation(false);
    let mut ws = p.workspace();
    let n = 64;
    let mut rows = Vec::new();
    let mut us = Vec::new();
    let mut expected = Vec::new();
    for i in 0..n {
        let psi = 0.1 * i as f64;
        let x = State::from([0.01 * i as f64, -0.3, 0.5, psi.cos(), psi.sin(), 0.2, -0.05, 0.1, 0.05]);
        let u = Input::new(3.0 * (0.2 * i as f64).sin(), 0.2, 5.0, 0.1);
        let mut next = State::zeros();
        p.step(&mut ws, &x, &u, &mut next).unwrap();
        rows.extend(x.iter().map(|&v| v as f32));
        us.extend(u.iter().map(|&v| v as f32));
        expected.push(next);
    }
    let x = Tensor::<2>::from_data(TensorData::new(rows, [n, 9]), &device);
    let u = Tensor::<2>::from_data(TensorData::new(us, [n, 4]), &device);
    let t = Tensor::<2>::full([n, 1], 0.08, &device);
    let got: Vec<f32> = net.forward(x, u, t, false).state.try_into_vec_as::<f32>().unwrap();
    let mut worst = 0.0_f64;
    for i in 0..n {
        for k in 0..9 {
            worst = worst.max((f64::from(got[i * 9 + k]) - expected[i][k]).abs());
        }
    }
    assert!(worst < 1e-5, "burn vs runtime: max abs difference {worst:e}");
}
