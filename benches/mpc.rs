//! `mpc_iteration_h20`: one real-time iteration of the LTV-MPC at horizon 20 (shift,
//! rollout + exact Jacobians of the shipped controller model, QP data update, one Clarabel
//! solve), from a state in the middle of a dive and turn. `mpc_iteration_h20_oracle` is the
//! same controller on the analytic model (RK4 with exact discrete Jacobians).
//!
//! Run with `cargo bench --bench mpc`; criterion reports the median.
#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{Criterion, criterion_group, criterion_main};
use pinc::model::PincModel;
use pinc::mpc::{Mpc, MpcConfig, Reference};
use pinc::runtime::Predictor;
use pinc::traits::DiscreteModel;
use pinc::vehicle::{Rk4Vehicle, to_network};
use pinc::{SimState, State};
use std::hint::black_box;

fn bench_model<M: DiscreteModel>(c: &mut Criterion, id: &str, model: M, bounds_from: &Predictor<f64>) {
    let cfg = MpcConfig { bounds: bounds_from.input_bounds(), ..MpcConfig::default() };
    let mut mpc = Mpc::new(model, cfg).unwrap();
    let x: State = to_network(&SimState::from([0.3, -0.2, 0.8, 0.4, 0.3, 0.02, 0.15, 0.1]));
    let refs = vec![Reference { depth: 1.5, heading: 0.8 }; 20];
    c.bench_function(id, |b| b.iter(|| black_box(mpc.step(black_box(&x), &refs))));
}

fn mpc_iteration(c: &mut Criterion) {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/models/mpc_pinc.pinc");
    let model = PincModel::load(path).unwrap();
    let p = Predictor::reference(&model);
    bench_model(c, "mpc_iteration_h20", Predictor::reference(&model), &p);
    bench_model(c, "mpc_iteration_h20_oracle", Rk4Vehicle::with_dt(model.dt), &p);
}

criterion_group!(benches, mpc_iteration);
criterion_main!(benches);
