//! One real-time iteration of the LTV-MPC (shift, rollout + exact Jacobians, QP data update,
//! one QP solve), from a state in the middle of a dive and turn, for three models at horizons
//! 20, 40 and 80, with Clarabel on the default (partially condensed) formulation, on the
//! sparse one it replaced ([`MpcConfig::with_sparse_qp`]), and with the Riccati
//! interior-point solver ([`QpSolver::Riccati`]):
//! - `mpc_iteration_h20`: the shipped controller model (`models/mpc_pinc_thrust.pinc`);
//! - `mpc_iteration_h20_oracle`: the analytic vehicle (RK4, exact discrete Jacobians);
//! - `mpc_iteration_h20_paper`: the paper's network (`models/paper_pinc.pinc`);
//! - the same at `_h40`, `_h80`; `.../sparse` is Clarabel's formulation before, `.../riccati`
//!   the Riccati solver;
//! - `riccati_scaling/N`: the oracle's cycle on the Riccati solver at N = 20, 40, 80, 160 (the
//!   end of the run prints each cycle's time per interior-point iteration, linear in N).
//! - `four_axis_h20[_oracle]/riccati_9`: the cycle on four axes (9 kept states, a horizontal
//!   goal) beside `riccati_7`, the same controller on depth and heading.
//!
//! - `estimator_update`: one sample of the state estimator beside it (`pinc::estimation`: one
//!   prediction through the model's exact Jacobians, then depth, heading and yaw rate fused),
//!   on the same models.
//!
//! Run with `cargo bench --bench mpc`; criterion reports the medians, and the end of the
//! run prints default / sparse and riccati / default for each model and horizon and the
//! estimator's cost as a fraction of the MPC iteration (all measured in this one run).
#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{Criterion, criterion_group};

#[path = "common/mod.rs"]
mod common;
use common::median_ns;
use pinc::estimation::{Estimator, Measurement, NoiseSettings};
use pinc::model::PincModel;
use pinc::mpc::{Mpc, MpcConfig, QpSolver, Reference};
use pinc::runtime::Predictor;
use pinc::traits::DiscreteModel;
use pinc::vehicle::{Rk4Vehicle, to_network};
use pinc::{Input, SimState, State};
use std::hint::black_box;

const HORIZONS: [usize; 3] = [20, 40, 80];
const FORMULATIONS: [&str; 3] = ["default", "sparse", "riccati"];
const SCALING: [usize; 4] = [20, 40, 80, 160];

/// The bench's controller settings: `formulation` at `horizon`, no time limit (a solve that
/// stopped early would look fast).
fn config(formulation: &str, horizon: usize, bounds_from: &Predictor<f64>) -> MpcConfig {
    let cfg = MpcConfig {
        bounds: bounds_from.input_bounds(),
        horizon,
        solver_time_limit: f64::INFINITY,
        ..MpcConfig::default()
    };
    match formulation {
        "sparse" => cfg.with_sparse_qp(),
        "riccati" => MpcConfig { qp: QpSolver::Riccati, ..cfg },
        _ => cfg,
    }
}

fn bench_state() -> State {
    to_network(&SimState::from([0.3, -0.2, 0.8, 0.4, 0.3, 0.02, 0.15, 0.1]))
}

fn bench_model<M: DiscreteModel + Clone>(c: &mut Criterion, id: &str, model: M, bounds_from: &Predictor<f64>) {
    let x = bench_state();
    for horizon in HORIZONS {
        let mut group = c.benchmark_group(id.replace("h20", &format!("h{horizon}")));
        for formulation in FORMULATIONS {
            let mut mpc = Mpc::new(model.clone(), config(formulation, horizon, bounds_from)).unwrap();
            let refs = vec![Reference::depth_heading(1.5, 0.8); horizon];
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

/// The Riccati cycle on four axes (9 kept states, a horizontal goal with its velocity) beside
/// the same controller on depth and heading (7 kept states), on the shipped model and the
/// analytic vehicle at N 20.
fn four_axis(c: &mut Criterion) {
    let shipped = load("mpc_pinc_thrust.pinc");
    let p = Predictor::reference(&shipped);
    let x = bench_state();
    let goal = pinc::mpc::Horizontal { north: 0.5, east: -0.3, velocity: [0.2, 0.1] };
    let four = vec![Reference { horizontal: Some(goal), ..Reference::depth_heading(1.5, 0.8) }; 20];
    let two = vec![Reference::depth_heading(1.5, 0.8); 20];
    for (id, oracle) in [("four_axis_h20", false), ("four_axis_h20_oracle", true)] {
        let mut group = c.benchmark_group(id);
        for (name, cfg, refs) in [
            ("riccati_7", config("riccati", 20, &p), &two),
            ("riccati_9", config("riccati", 20, &p).four_axis(), &four),
        ] {
            if oracle {
                let mut mpc = Mpc::new(Rk4Vehicle::with_dt(shipped.dt), cfg).unwrap();
                group.bench_function(name, |b| b.iter(|| black_box(mpc.step(black_box(&x), refs))));
            } else {
                let mut mpc = Mpc::new(p.clone(), cfg).unwrap();
                group.bench_function(name, |b| b.iter(|| black_box(mpc.step(black_box(&x), refs))));
            }
        }
        group.finish();
    }
}

/// The Riccati solver's cycle on the analytic vehicle as the horizon doubles.
fn riccati_scaling(c: &mut Criterion) {
    let shipped = load("mpc_pinc_thrust.pinc");
    let p = Predictor::reference(&shipped);
    let x = bench_state();
    let mut group = c.benchmark_group("riccati_scaling");
    for horizon in SCALING {
        let mut mpc = Mpc::new(Rk4Vehicle::with_dt(shipped.dt), config("riccati", horizon, &p)).unwrap();
        let refs = vec![Reference::depth_heading(1.5, 0.8); horizon];
        group.bench_function(horizon.to_string(), |b| b.iter(|| black_box(mpc.step(black_box(&x), &refs))));
    }
    group.finish();
}

/// The Riccati solver's time per interior-point iteration (its solve time over its
/// iterations, median of 200 cycles from the bench's state) at each horizon of
/// [`SCALING`], and where a cycle's time goes.
fn print_riccati_iterations() {
    let shipped = load("mpc_pinc_thrust.pinc");
    let p = Predictor::reference(&shipped);
    println!(
        "
Riccati solver on the oracle: time per interior-point iteration (median of 200 cycles)"
    );
    for horizon in SCALING {
        let mut mpc = Mpc::new(Rk4Vehicle::with_dt(shipped.dt), config("riccati", horizon, &p)).unwrap();
        let refs = vec![Reference::depth_heading(1.5, 0.8); horizon];
        let mut per: Vec<(f64, f64, f64, u32)> = (0..200)
            .map(|_| mpc.step(&bench_state(), &refs))
            .map(|r| (r.solve_us / r.iterations.max(1) as f64, r.linearise_us, r.solve_us, r.iterations))
            .collect();
        per.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (it_us, lin_us, solve_us, iterations) = per[per.len() / 2];
        println!(
            "N = {horizon:3}: {it_us:7.1} us per iteration ({:.3} us per stage), {iterations} iterations, solve {solve_us:.1} us, rollout + Jacobians {lin_us:.1} us",
            it_us / horizon as f64
        );
    }
}

/// One estimator sample: the model step with its Jacobians and three scalar updates; with
/// `navigation`, pinc's own navigation beside them: a DVL's body velocity every sample and a
/// USBL's fix, half a second late, every third (4 Hz), fused at the time it was measured.
fn bench_estimator<M: DiscreteModel>(c: &mut Criterion, id: &str, model: M, navigation: bool) {
    let mut tracker = Estimator::new(model, NoiseSettings::default());
    let x0 = SimState::from([0.3, -0.2, 0.8, 0.4, 0.3, 0.02, 0.15, 0.1]);
    let u = Input::new(10.0, 0.0, 20.0, 1.0);
    let mut t = 0.0;
    let mut k = 0u64;
    let mut feed = |tracker: &mut Estimator<M>, t: f64| {
        tracker.measure(Measurement::Depth { t, z: x0[2] });
        tracker.measure(Measurement::Heading { t, psi: x0[3] });
        tracker.measure(Measurement::YawRate { t, r: x0[7] });
        if navigation {
            tracker.measure(Measurement::VelocityBody { t, u: x0[4], v: x0[5], w: x0[6] });
            if k.is_multiple_of(3) && t >= 0.5 {
                tracker.measure(Measurement::Fix { t: t - 0.5, x: x0[0], y: x0[1], std: 0.25 });
            }
        }
        k += 1;
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
    bench_estimator(c, "estimator_update", Predictor::reference(&shipped), false);
    bench_estimator(c, "estimator_update_oracle", Rk4Vehicle::with_dt(shipped.dt), false);
    bench_estimator(c, "estimator_update_paper", Predictor::reference(&load("paper_pinc.pinc")), false);
    bench_estimator(c, "estimator_navigation", Predictor::reference(&shipped), true);
    bench_estimator(c, "estimator_navigation_oracle", Rk4Vehicle::with_dt(shipped.dt), true);
}

criterion_group!(benches, mpc_iteration, riccati_scaling, four_axis, estimator_update);

/// Clarabel's own timers for one solve of the default formulation (after 50 cycles from the
/// bench's state), where the time of a cycle goes.
fn print_solver_timers<M: DiscreteModel>(id: &str, model: M, bounds_from: &Predictor<f64>, horizon: usize) {
    let mut mpc = Mpc::new(model, config("default", horizon, bounds_from)).unwrap();
    let x = bench_state();
    let refs = vec![Reference::depth_heading(1.5, 0.8); horizon];
    let report = (0..50).map(|_| mpc.step(&x, &refs)).last().unwrap();
    println!(
        "\n{id}: cycle {:.1} us (rollout + Jacobians {:.1}, condensing + update {:.1}, solve {:.1}), {} iterations; Clarabel's timers:",
        report.cycle_us, report.linearise_us, report.update_us, report.solve_us, report.iterations
    );
    if let Some(t) = mpc.solver().and_then(|s| s.timers.as_ref()) {
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
    print_riccati_iterations();
    for (new, old, what) in [
        ("default", "sparse", "Clarabel, partially condensed / sparse"),
        ("riccati", "default", "Riccati / Clarabel partially condensed"),
    ] {
        println!("\ncycle time, {what} (medians of this run):");
        for model in ["", "_oracle", "_paper"] {
            for horizon in HORIZONS {
                let id = format!("mpc_iteration_h{horizon}{model}");
                match (median_ns(&format!("{id}/{new}")), median_ns(&format!("{id}/{old}"))) {
                    (Some(new), Some(old)) => {
                        println!("{id:28} {:8.1} us / {:8.1} us = {:.2}", new / 1e3, old / 1e3, new / old)
                    }
                    _ => println!("{id:28} (not measured in this run)"),
                }
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
    // The live cycle on four axes: the MPC iteration and one estimator sample, with pinc's own
    // navigation (a DVL and late fixes) against the estimator on depth, heading and yaw rate.
    println!("\nfour-axis cycle (MPC N = 20 + estimator sample), navigation / without (medians of this run):");
    for model in ["", "_oracle"] {
        let ids = [
            format!("four_axis_h20{model}/riccati_9"),
            format!("estimator_navigation{model}"),
            format!("estimator_update{model}"),
        ];
        match (median_ns(&ids[0]), median_ns(&ids[1]), median_ns(&ids[2])) {
            (Some(m), Some(n), Some(e)) => println!(
                "{:28} ({:.1} + {:.1}) us / ({:.1} + {:.1}) us = {:.3}",
                ids[0],
                m / 1e3,
                n / 1e3,
                m / 1e3,
                e / 1e3,
                (m + n) / (m + e)
            ),
            _ => println!("{:28} (not measured in this run)", ids[0]),
        }
    }
}
