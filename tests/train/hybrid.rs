//! A hybrid in the trainer: it starts as its physics, and the gradient of a rollout flows
//! through the physics' step (checked against finite differences of the frozen runtime).
#![cfg(feature = "train")]

use crate::common;
use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use pinc::runtime::Predictor;
use pinc::train::PincNet;
use pinc::vehicle::Rk4Vehicle;
use pinc::{Input, State};

const STEPS: usize = 4;

fn start() -> (State, Vec<Input>) {
    let x = State::from([0.2, -0.1, 1.5, 0.4_f64.cos(), 0.4_f64.sin(), 0.3, -0.1, 0.05, 0.2]);
    let u = (0..STEPS).map(|k| Input::new(6.0 - k as f64, 2.0, -4.0, 0.8)).collect();
    (x, u)
}

fn tensor(rows: &[f64], cols: usize, device: &Device) -> Tensor<2> {
    let data: Vec<f32> = rows.iter().map(|&v| v as f32).collect();
    Tensor::from_data(TensorData::new(data, [rows.len() / cols, cols]), device)
}

/// The rollout's last state in burn, as the rollout losses compute it.
fn burn_rollout(net: &PincNet, x0: &State, u: &[Input], device: &Device) -> Tensor<2> {
    let mut x = tensor(x0.as_slice(), 9, device);
    for (j, uj) in u.iter().enumerate() {
        let t = Tensor::full([1, 1], 0.08, device);
        x = net.forward_from(x, tensor(uj.as_slice(), 4, device), t, false, j > 0).state;
    }
    x
}

/// Weights of the scalar whose gradient is checked: `sum_c w_c x_N[c]`.
const W: [f64; 9] = [1.0, -0.5, 2.0, 0.3, 0.7, 3.0, -2.0, 1.5, 4.0];

#[test]
fn a_fresh_hybrid_network_is_its_physics() {
    let device = Device::flex();
    let model = common::hybrid(common::paper_4x32(5), 16);
    let net = PincNet::init(&model.architecture, 3, &device)
        .into_hybrid(pinc::train::Hybrid { vehicle: model.vehicle, physics: model.hybrid.unwrap() });
    let (x0, u) = start();
    let got: Vec<f32> = burn_rollout(&net, &x0, &u, &device).try_into_vec_as::<f32>().unwrap();
    let vehicle = Rk4Vehicle { params: model.vehicle, dt: 0.08, substeps: 16 };
    let want = u.iter().fold(x0, |x, u| vehicle.step_network(&x, u));
    for c in 0..9 {
        // f32 states between the steps.
        assert!((f64::from(got[c]) - want[c]).abs() < 1e-5, "component {c}: {} vs {}", got[c], want[c]);
    }
}

/// Every parameter's gradient, flattened in visiting order (the output bias last).
struct Grads<'a>(&'a burn::tensor::Gradients, Vec<f32>);

impl ModuleVisitor for Grads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let n: usize = param.dims().iter().product();
        match param.grad(self.0) {
            Some(g) => self.1.extend(g.try_into_vec_as::<f32>().unwrap()),
            None => self.1.extend(std::iter::repeat_n(0.0, n)),
        }
    }
}

#[test]
fn the_rollout_gradient_flows_through_the_physics() {
    let device = Device::flex().autodiff();
    let model = common::hybrid(common::paper_4x32(5), 16);
    let net = PincNet::from_model(&model, &device);
    let (x0, u) = start();
    let last = burn_rollout(&net, &x0, &u, &device);
    let scalar = (last * tensor(&W, 9, &device)).sum();
    let grads = scalar.backward();
    let mut v = Grads(&grads, Vec::new());
    net.visit(&mut v);
    let got = &v.1[v.1.len() - 9..];
    // d scalar / d (output bias) by central differences of the f64 runtime.
    let objective = |m: &pinc::model::PincModel| {
        let p = Predictor::reference(m).with_yaw_renormalisation(false);
        let mut traj = vec![State::zeros(); STEPS + 1];
        p.rollout(&mut p.workspace(), &x0, &u, &mut traj).unwrap();
        traj[STEPS].iter().zip(W).map(|(x, w)| x * w).sum::<f64>()
    };
    let mut worst = 0.0_f64;
    for c in 0..9 {
        let (mut plus, mut minus) = (model.clone(), model.clone());
        plus.weights.output.bias[c] += 1e-2;
        minus.weights.output.bias[c] -= 1e-2;
        let h = f64::from(plus.weights.output.bias[c]) - f64::from(minus.weights.output.bias[c]);
        let fd = (objective(&plus) - objective(&minus)) / h;
        let err = (f64::from(got[c]) - fd).abs() / fd.abs().max(1.0);
        worst = worst.max(err);
        assert!(err < 1e-2, "bias {c}: burn {} vs finite differences {fd}", got[c]);
    }
    println!("worst relative gradient error: {worst:e}");
}
