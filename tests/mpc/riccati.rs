//! The Riccati interior-point solver against Clarabel in closed loop: on every cycle of the
//! scenarios and of perturbed (Monte-Carlo) plants, fed the same measured state, the two give
//! the same inputs where both converge; and the real-time settings track as Clarabel's do.
#![cfg(feature = "mpc")]

use crate::common;
use pinc::closed_loop::campaign::{Campaign, Settings};
use pinc::closed_loop::{Scenario, run, summarise};
use pinc::model::PincModel;
use pinc::mpc::{Mpc, MpcConfig, QpSolver, Reference};
use pinc::runtime::Predictor;
use pinc::traits::DiscreteModel;
use pinc::vehicle::{Rk4Vehicle, VehicleParams, to_network};
use pinc::{Input, SimState};

/// Both solvers to 1e-10: Clarabel in the sparse form (every state a variable) drives the
/// plant; on every cycle the Riccati controller gets the same measured state and references.
pub(crate) fn tight(bounds: (Input, Input)) -> (MpcConfig, MpcConfig) {
    let base =
        MpcConfig { bounds: Some(bounds), solver_tolerance: 1e-10, riccati_tolerance: 1e-10, ..common::untimed() };
    (MpcConfig { condensing_block: 1, ..base.clone() }, MpcConfig { qp: QpSolver::Riccati, ..base })
}

/// What one comparison saw: the worst absolute input difference per channel, the cycles
/// compared, and the cycles where either solver did not converge (left out).
#[derive(Debug)]
pub(crate) struct Agreement {
    pub(crate) worst: [f64; 4],
    pub(crate) cycles: usize,
    pub(crate) unconverged: usize,
}

pub(crate) fn compare<M: DiscreteModel + Clone>(
    model: M,
    cfgs: (MpcConfig, MpcConfig),
    scenario: &Scenario,
    plant: &VehicleParams,
    seconds: f64,
) -> Agreement {
    let mut clarabel = Mpc::new(model.clone(), cfgs.0).unwrap();
    let mut riccati = Mpc::new(model, cfgs.1).unwrap();
    let (dt, n) = (clarabel.model().dt(), clarabel.config().horizon);
    let mut seen = Agreement { worst: [0.0; 4], cycles: 0, unconverged: 0 };
    run(&mut clarabel, scenario, plant, |s| {
        let refs: Vec<Reference> = (0..n).map(|j| scenario.reference(s.t + (j + 1) as f64 * dt)).collect();
        let r = riccati.step(&to_network(&s.state), &refs);
        if r.fallback.is_some() || s.cycle.fallback.is_some() {
            eprintln!("t {:.2} s: riccati {:?}, clarabel {:?}", s.t, riccati.riccati_info(), s.cycle.status);
            seen.unconverged += 1;
        } else {
            for j in 0..4 {
                seen.worst[j] = seen.worst[j].max((r.input[j] - s.cycle.input[j]).abs());
            }
            seen.cycles += 1;
        }
        s.t < seconds
    });
    seen
}

pub(crate) fn shipped() -> Predictor<f64> {
    Predictor::reference(
        &PincModel::load(format!("{}/models/mpc_pinc_thrust.pinc", env!("CARGO_MANIFEST_DIR"))).unwrap(),
    )
}

#[test]
fn riccati_gives_clarabels_inputs_on_every_cycle_of_the_scenarios() {
    let pinc = shipped();
    let bounds = pinc.input_bounds().unwrap();
    for scenario in [Scenario::default(), Scenario::disturbed()] {
        let plant = VehicleParams::default();
        let oracle = compare(Rk4Vehicle::default(), tight(bounds), &scenario, &plant, 60.0);
        eprintln!("oracle, {}: {oracle:?}", scenario.name());
        assert!(oracle.cycles >= 700 && oracle.unconverged == 0, "{oracle:?}");
        assert!(oracle.worst.iter().all(|w| *w < 1e-6), "oracle, {}: {oracle:?}", scenario.name());
        let network = compare(pinc.clone(), tight(bounds), &scenario, &plant, 60.0);
        eprintln!("shipped model, {}: {network:?}", scenario.name());
        assert!(network.cycles >= 700 && network.unconverged == 0, "{network:?}");
        assert!(network.worst.iter().all(|w| *w < 1e-6), "shipped model, {}: {network:?}", scenario.name());
    }
}

#[test]
fn riccati_gives_clarabels_inputs_on_perturbed_plants_with_rate_limits() {
    let campaign = Campaign::new(&Settings {
        model: format!("{}/models/mpc_pinc_thrust.pinc", env!("CARGO_MANIFEST_DIR")).into(),
        ..Settings::default()
    })
    .unwrap();
    let pinc = Predictor::reference(&campaign.model);
    let scenario = Scenario::default();
    for seed in 0..4 {
        let plant = campaign.draw(seed).vehicle;
        let (a, b) = tight(campaign.bounds);
        // Every other plant with rate limits, so their rows bind too.
        let rate_limit = (seed % 2 == 1).then_some([5.0, 5.0, 3.0, 0.5]);
        let cfgs = (MpcConfig { rate_limit, ..a }, MpcConfig { rate_limit, ..b });
        let seen = compare(pinc.clone(), cfgs, &scenario, &plant, 30.0);
        eprintln!("plant {seed} (rate limit {rate_limit:?}): {seen:?}");
        assert!(seen.cycles >= 350 && seen.unconverged == 0, "plant {seed}: {seen:?}");
        assert!(seen.worst.iter().all(|w| *w < 1e-6), "plant {seed}: {seen:?}");
    }
}

/// The real-time settings (the Riccati solver's default tolerance, Clarabel's default
/// formulation) track alike: the same summary figures within 1 %, no fallback.
#[test]
fn the_real_time_riccati_controller_tracks_as_clarabels() {
    let pinc = shipped();
    let bounds = pinc.input_bounds().unwrap();
    let scenario = Scenario::default();
    let fly = |qp: QpSolver| {
        let cfg = MpcConfig { bounds: Some(bounds), qp, ..common::untimed() };
        let mut mpc = Mpc::new(pinc.clone(), cfg).unwrap();
        summarise(&run(&mut mpc, &scenario, &VehicleParams::default(), |_| true), &scenario, 1.6)
    };
    let (c, r) = (fly(QpSolver::Clarabel), fly(QpSolver::Riccati));
    eprintln!("clarabel {c:?}\nriccati {r:?}");
    assert_eq!((r.fallbacks, r.bound_violations, r.envelope_exits), (0, 0, 0), "{r:?}");
    assert!((r.rms_depth_m - c.rms_depth_m).abs() <= 0.01 * c.rms_depth_m, "{r:?}\n{c:?}");
    assert!((r.rms_heading_deg - c.rms_heading_deg).abs() <= 0.01 * c.rms_heading_deg, "{r:?}\n{c:?}");
}

/// A cycle that runs out of iterations ends in a typed status (`MaxIterations`) and applies
/// the shifted plan, never a NaN input.
#[test]
fn a_riccati_cycle_out_of_iterations_falls_back_without_a_nan() {
    let mut cfg = tight((Input::new(-10.0, -5.0, -5.0, -1.0), Input::new(10.0, 5.0, 20.0, 1.0))).1;
    cfg.solver_max_iter = 3;
    let mut mpc = Mpc::new(Rk4Vehicle::default(), cfg).unwrap();
    let x = to_network(&SimState::from([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]));
    let report = mpc.step(&x, &[Reference::depth_heading(3.0, 1.0); 20]);
    assert_eq!(report.fallback, Some(pinc::mpc::Fallback::Solver(clarabel::solver::SolverStatus::MaxIterations)));
    assert!(report.input.iter().all(|v| v.is_finite()));
}

/// The Riccati solver is the campaigns' (so `mpc_track`'s, the live session's and Python's)
/// default; `sparse_qp`, a formulation of Clarabel's QP, takes Clarabel unless told otherwise
/// and refuses the Riccati solver by name.
#[test]
fn campaigns_default_to_riccati_and_the_sparse_qp_to_clarabel() {
    let model = format!("{}/models/mpc_pinc_thrust.pinc", env!("CARGO_MANIFEST_DIR"));
    let campaign = |s: Settings| Campaign::new(&Settings { model: model.clone().into(), ..s });
    assert_eq!(campaign(Settings::default()).unwrap().config.qp, QpSolver::Riccati);
    let sparse = campaign(Settings { sparse_qp: true, ..Settings::default() }).unwrap();
    assert_eq!((sparse.config.qp, sparse.config.condensing_block), (QpSolver::Clarabel, 1));
    let Err(e) = campaign(Settings { sparse_qp: true, qp: Some(QpSolver::Riccati), ..Settings::default() }) else {
        panic!("the Riccati solver has no sparse formulation")
    };
    assert!(e.to_string().contains("sparse_qp is a formulation of Clarabel's QP; the riccati solver"), "{e}");
}
