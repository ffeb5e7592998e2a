//! One real-time iteration of the LTV-MPC (shift, rollout + exact Jacobians, QP data update
//! and condensing, one Clarabel solve), from a state in the middle of a dive and turn, for
//! three models at horizons 20 and 80, each in the default (partially condensed) formulation
//! and in the sparse one it replaced ([`MpcConfig::with_sparse_qp`]):
//! - `mpc_iteration_h20`: the shipped controller model (`models/mpc_pinc_thrust.pinc`);
//! - `mpc_iteration_h20_oracle`: the analytic vehicle (RK4, exact discrete Jacobians);
//! - `mpc_iteration_h20_paper`: the paper's network (`models/paper_pinc.pinc`);
//! - the same at `_h80`; `.../sparse` is the formulation before.
//!
//! - `estimator_update`: one sample of the state estimator beside it (`pinc::estimation`: one
//!   prediction through the model's exact Jacobians, then depth, heading and yaw rate fused),
//!   on the same models.
//!
//! Run with `cargo bench --bench mpc`; criterion reports the medians, and the end of the
//! run prints default / sparse for each pair and the estimator's cost as a fraction of the
//! MPC iteration (all measured in this one run).
#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{Criterion, criterion_group};

#[path = "common/mod.rs"]
mod common;
use common::median_ns;
use pinc::estimation::{Estimator, Measurement, NoiseSettings};
use pinc::model::PincModel;
use pinc::mpc::{Mpc, MpcConfig, Reference};
use pinc::runtime::Predictor;
use pinc::traits::DiscreteModel;
use pinc::vehicle::{Rk4Vehicle, to_network};
use pinc::{Input, SimState, State};
use std::hint::black_box;

const HORIZONS: [usize; 2] = [20, 80];
const FORMULATIONS: [&str; 2] = ["default", "sparse"];

fn bench_model<M: DiscreteModel + Clone>(c: &mut Criterion, id: &str, model: M, bounds_from: &Predictor<f64>) {
    let x: State = to_network(&SimState::from([0.3, -0.2, 0.8, 0.4, 0.3, 0.02, 0.15, 0.1]));
    for horizon in HORIZONS {
        let mut group = c.benchmark_group(id.replace("h20", &format!("h{horizon}")));
        for formulation in FORMULATIONS {
            // No time limit: a solve that stopped early would look fast.
            let cfg = MpcConfig {
                bounds: bounds_from.input_bounds(),
                horizon,
                solver_time_limit: f64::INFINITY,
                ..MpcConfig::default()
            };
            let cfg = if formulation == "sparse" { cfg.with_sparse_qp() } else { cfg };
            let mut mpc = Mpc::new(model.clone(), cfg).unwrap();
            let refs = vec![Reference { depth: 1.5, heading: 0.8 }; horizon];
            group.bench_function(formulation, |b| b.iter(|| black_box(mpc.step(black_box(&x), &refs))));
        }
        group.finish();
    }
}

fn load(name: &str) -> PincModel {
    PincModel::load(format!("{}/models/{name}", env!("CARGO_MANIFEST_DIR"))).unwrap()
}

fn mpc_iteration(c: &mut Criterion) {
    let shipped = load("mpc_pinc_thrust.pinc");
    let p = Predictor::reference(&shipped);
    bench_model(c, "mpc_iteration_h20", Predictor::reference(&shipped), &p);
    bench_model(c, "mpc_iteration_h20_oracle", Rk4Vehicle::with_dt(shipped.dt), &p);
    let paper = load("paper_pinc.pinc");
    let pp = Predictor::reference(&paper);
    bench_model(c, "mpc_iteration_h20_paper", Predictor::reference(&paper), &pp);
}

/// One estimator sample: the model step with its Jacobians and three scalar updates.
fn bench_estimator<M: DiscreteModel>(c: &mut Criterion, id: &str, model: M) {
    let mut tracker = Estimator::new(model, NoiseSettings::default());
    let x0 = SimState::from([0.3, -0.2, 0.8, 0.4, 0.3, 0.02, 0.15, 0.1]);
    let u = Input::new(10.0, 0.0, 20.0, 1.0);
    let mut t = 0.0;
    let feed = |tracker: &mut Estimator<M>, t: f64| {
        tracker.measure(Measurement::Depth { t, z: x0[2] });
        tracker.measure(Measurement::Heading { t, psi: x0[3] });
        tracker.measure(Measurement::YawRate { t, r: x0[7] });
    };
    feed(&mut tracker, t);
    tracker.advance(t).unwrap().expect("the filter starts");
    tracker.commanded(u);
    c.bench_function(id, |b| {
        b.iter(|| {
            t += 0.08;
            feed(&mut tracker, t);
            black_box(tracker.advance(black_box(t)).unwrap())
        })
    });
}

fn estimator_update(c: &mut Criterion) {
    let shipped = load("mpc_pinc_thrust.pinc");
    bench_estimator(c, "estimator_update", Predictor::reference(&shipped));
    bench_estimator(c, "estimator_update_oracle", Rk4Vehicle::with_dt(shipped.dt));
    bench_estimator(c, "estimator_update_paper", Predictor::reference(&load("paper_pinc.pinc")));
}

criterion_group!(benches, mpc_iteration, estimator_update);

/// Clarabel's own timers for one solve of the default formulation (after 50 cycles from the
/// bench's state), where the time of a cycle goes.
fn print_solver_timers<M: DiscreteModel>(id: &str, model: M, bounds_from: &Predictor<f64>, horizon: usize) {
    let cfg = MpcConfig {
        bounds: bounds_from.input_bounds(),
        horizon,
        solver_time_limit: f64::INFINITY,
        ..MpcConfig::default()
    };
    let mut mpc = Mpc::new(model, cfg).unwrap();
    let x: State = to_network(&SimState::from([0.3, -0.2, 0.8, 0.4, 0.3, 0.02, 0.15, 0.1]));
    let refs = vec![Reference { depth: 1.5, heading: 0.8 }; horizon];
    let report = (0..50).map(|_| mpc.step(&x, &refs)).last().unwrap();
    println!(
        "\n{id}: cycle {:.1} us (rollout + Jacobians {:.1}, condensing + update {:.1}, solve {:.1}), {} iterations; Clarabel's timers:",
        report.cycle_us, report.linearise_us, report.update_us, report.solve_us, report.iterations
    );
    if let Some(t) = &mpc.solver().timers {
        t.print();
    }
}

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    let shipped = load("mpc_pinc_thrust.pinc");
    let paper = load("paper_pinc.pinc");
    let (ps, pp) = (Predictor::reference(&shipped), Predictor::reference(&paper));
    for horizon in HORIZONS {
        print_solver_timers(&format!("mpc_iteration_h{horizon}"), ps.clone(), &ps, horizon);
        print_solver_timers(&format!("mpc_iteration_h{horizon}_oracle"), Rk4Vehicle::with_dt(shipped.dt), &ps, horizon);
        print_solver_timers(&format!("mpc_iteration_h{horizon}_paper"), pp.clone(), &pp, horizon);
    }
    println!("\ncycle time, partially condensed / sparse (medians of this run):");
    for model in ["", "_oracle", "_paper"] {
        for horizon in HORIZONS {
            let id = format!("mpc_iteration_h{horizon}{model}");
            match (median_ns(&format!("{id}/default")), median_ns(&format!("{id}/sparse"))) {
                (Some(new), Some(old)) => {
                    println!("{id:28} {:8.1} us / {:8.1} us = {:.2}", new / 1e3, old / 1e3, new / old)
                }
                _ => println!("{id:28} (not measured in this run)"),
            }
        }
    }
    println!("\nestimator sample / MPC iteration at N = 20 (medians of this run):");
    for model in ["", "_oracle", "_paper"] {
        let (e, m) = (format!("estimator_update{model}"), format!("mpc_iteration_h20{model}/default"));
        match (median_ns(&e), median_ns(&m)) {
            (Some(e_ns), Some(m_ns)) => {
                println!("{e:28} {:8.1} us / {:8.1} us = {:.3}", e_ns / 1e3, m_ns / 1e3, e_ns / m_ns)
            }
            _ => println!("{e:28} (not measured in this run)"),
        }
    }
}
