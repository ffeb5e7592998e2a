//! The MPC in closed loop with the analytic vehicle: the true-model ("oracle") controller
//! settles a depth step, and a controller whose every solve fails keeps running on its
//! fallback plan within the bounds.
#![cfg(feature = "mpc")]

use pinc::Input;
use pinc::closed_loop::{Scenario, run, summarise};
use pinc::mpc::{Fallback, Mpc, MpcConfig};
use pinc::vehicle::Rk4Vehicle;

/// The controller envelope of the `mpc` dataset preset.
fn bounds() -> (Input, Input) {
    (Input::new(-10.0, -5.0, -5.0, -1.0), Input::new(10.0, 5.0, 20.0, 1.0))
}

fn oracle(cfg: MpcConfig) -> Mpc<Rk4Vehicle> {
    Mpc::new(Rk4Vehicle::default(), MpcConfig { bounds: Some(bounds()), ..cfg }).unwrap()
}

#[test]
fn the_oracle_loop_settles_the_first_depth_step_and_tracks_heading() {
    let mut mpc = oracle(MpcConfig::default());
    let samples = run(&mut mpc, Scenario::Default, |_| true);
    let s = summarise(&samples, Scenario::Default, 1.6);
    assert_eq!(s.samples, 750);
    assert_eq!((s.fallbacks, s.bound_violations), (0, 0), "{s:?}");
    // The 0 -> 1 m step at 2 s: within 5 cm and staying there well before the next step at 20 s.
    assert!(s.settling_depth_s.iter().chain(&s.settling_heading_s).all(|t| *t < 6.0), "{s:?}");
    let at = |t: f64| samples.iter().min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs())).unwrap();
    assert!((at(17.0).state[2] - 1.0).abs() < 0.02, "depth at 17 s: {}", at(17.0).state[2]);
    assert!((at(27.0).state[3] - 45f64.to_radians()).abs() < 1f64.to_radians(), "heading at 27 s");
    assert!(s.max_overshoot_depth_m < 0.05 && s.max_overshoot_heading_deg < 2.0, "{s:?}");
    assert!(s.solve_ms_p99 < 40.0, "{s:?}");
}

#[test]
fn failed_solves_fall_back_to_the_shifted_plan_and_the_loop_goes_on() {
    // A time limit no solve can meet: every cycle ends in Clarabel's MaxTime.
    let mut mpc = oracle(MpcConfig { solver_time_limit: 1e-12, ..MpcConfig::default() });
    let samples = run(&mut mpc, Scenario::Default, |s| s.t < 2.0);
    assert!(samples.len() > 20);
    for s in &samples {
        assert!(matches!(s.cycle.fallback, Some(Fallback::Solver(_))), "{:?}", s.cycle);
        assert!(!s.bound_violation);
    }
    let summary = summarise(&samples, Scenario::Default, 1.6);
    assert_eq!(summary.fallbacks, samples.len());
}

#[test]
fn a_controller_without_bounds_or_with_bad_weights_is_refused() {
    let e = Mpc::new(Rk4Vehicle::default(), MpcConfig::default()).err().unwrap();
    assert!(e.to_string().contains("no input bounds"), "{e}");
    let e =
        Mpc::new(Rk4Vehicle::default(), MpcConfig { bounds: Some(bounds()), depth: f64::NAN, ..MpcConfig::default() })
            .err()
            .unwrap();
    assert!(e.to_string().contains("weights"), "{e}");
}
