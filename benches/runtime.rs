//! Latency of the models a controller steps: the analytic vehicle (`rk4_step`, one 0.08 s
//! sample period at the default sub-steps).
//!
//! Run with `cargo bench --bench runtime`; criterion reports the median of each ID.

#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{Criterion, criterion_group, criterion_main};
use pinc::vehicle::{Rk4Vehicle, to_network};
use pinc::{Input, SimState};
use std::hint::black_box;

fn rk4_step(c: &mut Criterion) {
    let vehicle = Rk4Vehicle::default();
    let s = SimState::from([0.1, -0.2, 0.5, 0.3, 0.2, 0.01, 0.05, 0.1]);
    let u = Input::new(4.0, 0.3, 8.0, 0.4);
    c.bench_function("rk4_step", |b| b.iter(|| vehicle.step_sim(black_box(&s), black_box(&u))));
    let x = to_network(&s);
    c.bench_function("rk4_step_jacobians", |b| b.iter(|| vehicle.step_with_jacobians(black_box(&x), black_box(&u))));
}

criterion_group!(benches, rk4_step);
criterion_main!(benches);
