//! Latency of the models a controller steps, on the 4 x 32 network of
//! `tests/fixtures/random_4x32.safetensors` (the paper's architecture, PyTorch layout):
//!
//! - `step`: one prediction; `rollout_65`: 65 autoregressive steps (one paper trajectory);
//!   `step_shipped`: one prediction of the shipped controller model (`models/mpc_pinc_thrust.pinc`)
//!   at the state and input `python/examples/overhead.py` times Python's `step_into` at;
//! - `linearise_h20`: a 20-step horizon with every exact A_k, B_k;
//! - `batch_rollout_1000x65`: 1000 trajectories of 65 steps, one thread;
//! - unsuffixed IDs use the default `f32` predictor with the AVX2 + FMA kernels (where the
//!   CPU has them); `*_f64` the `f64` reference predictor; `*_portable` the portable kernels
//!   (no FMA, baseline x86-64 SIMD) in `f32`;
//! - `burn_step`: the same weights through the burn training network (flex device, batch 1,
//!   no tangent), so the runtime's advantage over the framework is measured in one run;
//!   `burn_step_ndarray` on burn's ndarray device;
//! - `rk4_step`: one 0.08 s sample period of the analytic vehicle (16 RK4 sub-steps), and
//!   `rk4_linearise`: the same with the exact Jacobians of the discrete map; `rk4_step_network`
//!   the step in the network's state form (what a hybrid model integrates);
//! - `hybrid_step`, `hybrid_linearise_h20`: the same network as the correction of a hybrid
//!   model on the BlueROV2 (16 sub-steps); at the end, the ratio of `hybrid_step` to
//!   `rk4_step_network` plus `step`, measured in this run.
//!
//! Run with `cargo bench --features tools --bench runtime`; criterion reports the median of each ID.
#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{Criterion, criterion_group};

#[path = "common/mod.rs"]
mod common;
use pinc::model::{Activation, PincModel, import_state_dict};
use pinc::runtime::{BatchWorkspace, HorizonLinearisation, Predictor, Real};
use pinc::vehicle::{Rk4Vehicle, to_network};
use pinc::{Input, SimState, State};
use std::hint::black_box;

fn predictor<T: Real>() -> Predictor<T> {
    let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/random_4x32.safetensors")).unwrap();
    Predictor::from_model(&import_state_dict(&bytes, 0.08, Activation::Softplus).unwrap())
}

fn x0() -> State {
    to_network(&SimState::from([0.1, -0.2, 0.5, 0.3, 0.2, 0.01, 0.05, 0.1]))
}

fn inputs(n: usize) -> Vec<Input> {
    (0..n).map(|k| Input::new(2.0 * (0.1 * k as f64).sin(), 0.1, 5.0, 0.05 * (0.2 * k as f64).cos())).collect()
}

fn network(c: &mut Criterion) {
    bench_predictor(c, "", predictor::<f32>());
    bench_predictor(c, "_f64", predictor::<f64>());
    bench_predictor(c, "_portable", predictor::<f32>().with_portable_kernels());
    // The shipped controller model at `python/examples/overhead.py`'s state and input: the
    // Rust call that Python's `step_into` is measured against.
    let model = PincModel::load(concat!(env!("CARGO_MANIFEST_DIR"), "/models/mpc_pinc_thrust.pinc")).unwrap();
    let p = Predictor::new(&model);
    let mut ws = p.workspace();
    let x = State::from([0.0, 0.0, 1.0, 1.0, 0.0, 0.2, 0.0, 0.05, 0.0]);
    let u = Input::new(2.0, 0.1, 5.0, 0.05);
    let mut out = State::zeros();
    c.bench_function("step_shipped", |b| b.iter(|| p.step(&mut ws, black_box(&x), black_box(&u), &mut out).unwrap()));
}

fn bench_predictor<T: Real>(c: &mut Criterion, suffix: &str, p: Predictor<T>) {
    {
        let mut ws = p.workspace();
        let (x, u) = (x0(), inputs(65));
        let mut out = State::zeros();
        c.bench_function(&format!("step{suffix}"), |b| {
            b.iter(|| p.step(&mut ws, black_box(&x), black_box(&u[0]), &mut out).unwrap())
        });
        let mut traj = vec![State::zeros(); 66];
        c.bench_function(&format!("rollout_65{suffix}"), |b| {
            b.iter(|| p.rollout(&mut ws, black_box(&x), black_box(&u), &mut traj).unwrap())
        });
        let mut lin = HorizonLinearisation::new(20);
        c.bench_function(&format!("linearise_h20{suffix}"), |b| {
            b.iter(|| p.linearise_horizon(&mut ws, black_box(&x), black_box(&u[..20]), &mut lin).unwrap())
        });
        let mut bws = BatchWorkspace::new(&p);
        let x0s: Vec<State> = (0..1000)
            .map(|i| {
                let mut x = x0();
                x[2] += 0.001 * i as f64;
                x
            })
            .collect();
        let batch_inputs: Vec<Input> = (0..1000).flat_map(|_| inputs(65)).collect();
        let mut batch_out = vec![State::zeros(); 1000 * 66];
        let mut group = c.benchmark_group("batch");
        group.sample_size(20);
        group.bench_function(format!("batch_rollout_1000x65{suffix}"), |b| {
            b.iter(|| p.rollout_batch(&mut bws, black_box(&x0s), black_box(&batch_inputs), &mut batch_out).unwrap())
        });
        group.finish();
    }
}

#[cfg(feature = "train")]
fn burn_step(c: &mut Criterion) {
    use burn::prelude::*;
    let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/random_4x32.safetensors")).unwrap();
    let model = import_state_dict(&bytes, 0.08, Activation::Softplus).unwrap();
    let (x, u) = (x0(), inputs(1)[0]);
    #[allow(deprecated)] // burn marks ndarray deprecated in favour of flex; the design asks for it.
    let devices = [("burn_step", Device::flex()), ("burn_step_ndarray", Device::ndarray())];
    for (id, device) in devices {
        let net = pinc::train::PincNet::from_model(&model, &device);
        let row = |v: Vec<f32>, n: usize| Tensor::<2>::from_data(TensorData::new(v, [1, n]), &device);
        let xs: Vec<f32> = x.iter().map(|&v| v as f32).collect();
        let us: Vec<f32> = u.iter().map(|&v| v as f32).collect();
        c.bench_function(id, |b| {
            b.iter(|| {
                let p = net.forward(row(xs.clone(), 9), row(us.clone(), 4), row(vec![0.08], 1), false);
                black_box(p.state.try_into_vec_as::<f32>().unwrap())
            })
        });
    }
}

#[cfg(not(feature = "train"))]
fn burn_step(_: &mut Criterion) {}

fn rk4_step(c: &mut Criterion) {
    let vehicle = Rk4Vehicle::default();
    let s = SimState::from([0.1, -0.2, 0.5, 0.3, 0.2, 0.01, 0.05, 0.1]);
    let u = Input::new(4.0, 0.3, 8.0, 0.4);
    c.bench_function("rk4_step", |b| b.iter(|| vehicle.step_sim(black_box(&s), black_box(&u))));
    let x = to_network(&s);
    c.bench_function("rk4_linearise", |b| b.iter(|| vehicle.step_with_jacobians(black_box(&x), black_box(&u))));
    c.bench_function("rk4_step_network", |b| b.iter(|| vehicle.step_network(black_box(&x), black_box(&u))));
}

fn hybrid(c: &mut Criterion) {
    let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/random_4x32.safetensors")).unwrap();
    let mut model = import_state_dict(&bytes, 0.08, Activation::Softplus).unwrap();
    model.hybrid = Some(pinc::model::HybridPhysics { substeps: 16, rest_anchored: false });
    let p = Predictor::new(&model);
    let mut ws = p.workspace();
    let (x, u) = (x0(), inputs(20));
    let mut out = State::zeros();
    c.bench_function("hybrid_step", |b| b.iter(|| p.step(&mut ws, black_box(&x), black_box(&u[0]), &mut out).unwrap()));
    let mut lin = HorizonLinearisation::new(20);
    c.bench_function("hybrid_linearise_h20", |b| {
        b.iter(|| p.linearise_horizon(&mut ws, black_box(&x), black_box(&u), &mut lin).unwrap())
    });
}

criterion_group!(benches, network, burn_step, rk4_step, hybrid);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    let m = common::median_ns;
    println!("\nhybrid / (its physics + its network), medians of this run:");
    for (hybrid, parts) in
        [("hybrid_step", ["rk4_step_network", "step"]), ("hybrid_linearise_h20", ["rk4_linearise", "linearise_h20"])]
    {
        match (m(hybrid), m(parts[0]), m(parts[1])) {
            (Some(h), Some(a), Some(b)) => {
                // The linearisation's physics part runs 20 times per horizon.
                let physics = if hybrid == "hybrid_step" { a } else { 20.0 * a };
                println!(
                    "{hybrid:22} {:8.2} us / ({:.2} + {:.2}) us = {:.2}",
                    h / 1e3,
                    physics / 1e3,
                    b / 1e3,
                    h / (physics + b)
                )
            }
            _ => println!("{hybrid:22} (not measured in this run)"),
        }
    }
}
