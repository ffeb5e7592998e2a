//! The forward-mode tangent `d x_hat / d t` of the burn network against central finite
//! differences, in f64 (this binary configures the flex device to f64 before any tensor
//! exists, so it runs alone).
#![cfg(feature = "train")]

mod common;
use burn::prelude::*;
use burn::tensor::FloatDType;
use pinc::model::{Activation, Architecture};
use pinc::train::PincNet;

fn column(v: &[f64], n: usize, device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(v.to_vec(), [v.len() / n, n]), device)
}

fn values(t: Tensor<2>) -> Vec<f64> {
    t.try_into_vec_as::<f64>().unwrap()
}

#[test]
fn tangent_matches_central_differences_for_every_variant() {
    let mut device = Device::flex();
    device.configure(FloatDType::F64).expect("configure f64 before any tensor");
    let mut rng = common::Rng(5);
    let n = 16;
    let xs: Vec<f64> = (0..n * 9).map(|_| rng.sym()).collect();
    let us: Vec<f64> = (0..n * 4).map(|_| 3.0 * rng.sym()).collect();
    let ts: Vec<f64> = (0..n).map(|i| 0.01 + 0.09 * i as f64 / n as f64).collect();
    let mut tanh = Architecture::paper(3, 16);
    tanh.activation = Activation::Tanh;
    let mut no_pos = Architecture::paper(2, 24);
    no_pos.state_inputs = vec![3, 4, 5, 6, 7, 8];
    let mut plain = Architecture::paper(3, 20);
    plain.residual = false;
    plain.rotate_xy = false;
    plain.layer_norm = vec![false; 3];
    for (name, arch) in
        [("paper 4x32", Architecture::paper(4, 32)), ("tanh", tanh), ("position-free", no_pos), ("plain", plain)]
    {
        let net = PincNet::init(&arch, 3, &device);
        let eval = |t: &[f64], tangent: bool| {
            net.forward(column(&xs, 9, &device), column(&us, 4, &device), column(t, 1, &device), tangent)
        };
        let p = eval(&ts, true);
        let rate = values(p.rate.expect("tangent requested"));
        let h = 1e-5;
        let plus: Vec<f64> = ts.iter().map(|t| t + h).collect();
        let minus: Vec<f64> = ts.iter().map(|t| t - h).collect();
        let (a, b) = (values(eval(&plus, false).state), values(eval(&minus, false).state));
        let mut worst = 0.0_f64;
        for i in 0..rate.len() {
            let fd = (a[i] - b[i]) / (2.0 * h);
            worst = worst.max((fd - rate[i]).abs() / fd.abs().max(1.0));
        }
        assert!(worst < 1e-7, "{name}: tangent vs central differences {worst:e}");
        // The state without the tangent is the same computation.
        assert_eq!(values(eval(&ts, false).state), values(p.state));
    }
}
