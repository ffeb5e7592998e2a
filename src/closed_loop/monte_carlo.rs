//! Robustness over many perturbed runs: each run draws a plant (damping and added masses,
//! net buoyancy, a current) and sensor noise from its seed, while the controller keeps its
//! nominal model; the outcomes of many runs are summarised per controller.

use super::run::{Sample, run_on};
use super::scenario::Scenario;
use super::summary::percentile;
use crate::mpc::Mpc;
use crate::traits::DiscreteModel;
use crate::types::SimState;
use crate::vehicle::{VehicleParams, wrap_angle};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

/// Relative spread of every damping and added-mass coefficient (uniform, +-).
pub const COEFFICIENT_SPREAD: f64 = 0.2;
/// Relative spread of the net buoyancy (uniform, +-).
pub const BUOYANCY_SPREAD: f64 = 0.3;
/// Largest current (m/s), in a uniformly random horizontal direction.
pub const MAX_CURRENT: f64 = 0.2;
/// Sensor noise sigma: position (m), heading (rad), body velocities (m/s), yaw rate (rad/s).
pub const NOISE_SIGMA: [f64; 4] = [0.01, 0.5 * std::f64::consts::PI / 180.0, 0.01, std::f64::consts::PI / 180.0];
/// A run succeeds if, this long after each reference change, depth is within
/// [`DEPTH_TOLERANCE_M`] and heading within [`HEADING_TOLERANCE_DEG`] of the reference.
pub const SETTLE_S: f64 = 10.0;
/// See [`SETTLE_S`].
pub const DEPTH_TOLERANCE_M: f64 = 0.1;
/// See [`SETTLE_S`].
pub const HEADING_TOLERANCE_DEG: f64 = 5.0;

/// One perturbed plant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Draw {
    /// The seed everything below (and the run's sensor noise) comes from.
    pub seed: u64,
    /// The plant's coefficients.
    pub vehicle: VehicleParams,
    /// Water velocity `(x, y)` in the world frame (m/s).
    pub current: [f64; 2],
}

/// Draws the plant of run `seed` around `base`.
pub fn draw(base: &VehicleParams, seed: u64) -> Draw {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut v = *base;
    let mut spread = |x: &mut f64, s: f64| *x *= 1.0 + rng.random_range(-s..=s);
    for c in [
        &mut v.x_ud,
        &mut v.y_vd,
        &mut v.z_wd,
        &mut v.n_rd,
        &mut v.x_u,
        &mut v.y_v,
        &mut v.z_w,
        &mut v.n_r,
        &mut v.x_uu,
        &mut v.y_vv,
        &mut v.z_ww,
        &mut v.n_rr,
    ] {
        spread(c, COEFFICIENT_SPREAD);
    }
    // The net buoyancy through the displaced volume (mass and gravity are known).
    let mut net = base.net_buoyancy();
    spread(&mut net, BUOYANCY_SPREAD);
    v.volume = (v.m * v.g - net) / (v.rho * v.g);
    let speed = MAX_CURRENT * rng.random::<f64>();
    let (s, c) = rng.random_range(0.0..std::f64::consts::TAU).sin_cos();
    Draw { seed, vehicle: v, current: [speed * c, speed * s] }
}

/// The outcome of one run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Outcome {
    /// The run's seed.
    pub seed: u64,
    /// No fallback, no bound violation, every step reached ([`SETTLE_S`]), finite states.
    pub success: bool,
    /// Why it did not succeed (the first reason found).
    pub failure: Option<String>,
    /// RMS depth error (m); infinite when the run failed before finishing.
    pub rms_depth_m: f64,
    /// RMS horizontal error (m: from the point held, or across the track) of a scenario with
    /// a horizontal goal; `None` without one, infinite when the run failed before finishing.
    pub rms_horizontal_m: Option<f64>,
    /// RMS heading error (deg).
    pub rms_heading_deg: f64,
    /// Solve time of every cycle (ms).
    pub solve_ms: Vec<f64>,
}

/// Runs `scenario` on the plant of `d` (the draw's current replaces the scenario's; its
/// damping scale still applies) with sensor noise from the draw's seed; `mpc` keeps its own
/// model. A panic inside the run is caught and reported as the failure, never propagated.
pub fn run_perturbed<M: DiscreteModel>(mpc: &mut Mpc<M>, scenario: &Scenario, d: &Draw) -> Outcome {
    let failed = |why: String| Outcome {
        seed: d.seed,
        success: false,
        failure: Some(why),
        rms_depth_m: f64::INFINITY,
        rms_horizontal_m: scenario.horizontal.as_ref().map(|_| f64::INFINITY),
        rms_heading_deg: f64::INFINITY,
        solve_ms: Vec::new(),
    };
    let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let mut plant = scenario.plant(mpc.model().dt(), &d.vehicle);
        plant.current = d.current;
        // The noise stream is the draw's, after the plant's numbers (a different stream id).
        let mut rng = ChaCha8Rng::seed_from_u64(d.seed);
        rng.set_stream(1);
        let sigma = NOISE_SIGMA.map(|s| Normal::new(0.0, s).expect("positive sigma"));
        let measure = |s: &SimState| {
            let mut m = *s;
            let noise = |i: usize, rng: &mut ChaCha8Rng| sigma[[0, 0, 0, 1, 2, 2, 2, 3][i]].sample(rng);
            for i in 0..8 {
                m[i] += noise(i, &mut rng);
            }
            m
        };
        // A run whose state stops being finite ends there (and fails).
        run_on(mpc, scenario, &plant, measure, |s| s.state.iter().all(|v| v.is_finite()))
    }));
    match run {
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            failed(format!("panicked: {what}"))
        }
        Ok(samples) => judge(d.seed, &samples, scenario),
    }
}

/// The outcome of a finished run's samples.
fn judge(seed: u64, samples: &[Sample], scenario: &Scenario) -> Outcome {
    let n = samples.len().max(1) as f64;
    let heading_err = |s: &Sample| wrap_angle(s.state[3] - s.reference.heading).to_degrees();
    let rms_depth = (samples.iter().map(|s| (s.state[2] - s.reference.depth).powi(2)).sum::<f64>() / n).sqrt();
    let rms_heading = (samples.iter().map(|s| heading_err(s).powi(2)).sum::<f64>() / n).sqrt();
    let mut failure = None;
    if let Some(s) = samples.iter().find(|s| s.state.iter().any(|v| !v.is_finite())) {
        failure = Some(format!("non-finite state at {:.2} s", s.t));
    } else if let Some(s) = samples.iter().find(|s| s.cycle.fallback.is_some()) {
        failure = Some(format!("fallback at {:.2} s: {:?}", s.t, s.cycle.fallback));
    } else if let Some(s) = samples.iter().find(|s| s.bound_violation) {
        failure = Some(format!("input outside the bounds at {:.2} s", s.t));
    } else {
        // SETTLE_S after each change of a reference (while the run lasts), compare.
        for k in 1..samples.len() {
            let (prev, now) = (&samples[k - 1].reference, &samples[k].reference);
            if now.depth == prev.depth && now.heading == prev.heading {
                continue;
            }
            let t_check = samples[k].t + SETTLE_S;
            let Some(at) = samples[k..].iter().find(|s| s.t >= t_check - 1e-9) else { continue };
            if now.depth != prev.depth && (at.state[2] - at.reference.depth).abs() > DEPTH_TOLERANCE_M {
                failure =
                    Some(format!("depth {:.3} m at {:.1} s, reference {:.3} m", at.state[2], at.t, at.reference.depth));
                break;
            }
            if now.heading != prev.heading && heading_err(at).abs() > HEADING_TOLERANCE_DEG {
                failure = Some(format!("heading off by {:.2} deg at {:.1} s", heading_err(at), at.t));
                break;
            }
        }
    }
    Outcome {
        seed,
        success: failure.is_none(),
        failure,
        rms_depth_m: rms_depth,
        rms_horizontal_m: super::summary::horizontal_of(scenario, samples).map(|h| h.rms_m),
        rms_heading_deg: rms_heading,
        solve_ms: samples.iter().map(|s| s.cycle.solve_us / 1e3).collect(),
    }
}

/// Median, 95th percentile and maximum.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spread {
    /// Median.
    pub median: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
    /// Maximum.
    pub max: f64,
}

impl Spread {
    /// Of `v` (sorted in place); NaN for an empty `v`.
    pub fn of(v: &mut [f64]) -> Self {
        Self { median: percentile(v, 50.0), p95: percentile(v, 95.0), max: percentile(v, 100.0) }
    }
}

/// One controller's figures over many runs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Robustness {
    /// Runs.
    pub runs: usize,
    /// Fraction of runs that succeeded.
    pub success_rate: f64,
    /// RMS depth error over runs (m).
    pub rms_depth_m: Spread,
    /// RMS heading error over runs (deg).
    pub rms_heading_deg: Spread,
    /// RMS horizontal error over runs (m), for a scenario with a horizontal goal.
    pub rms_horizontal_m: Option<Spread>,
    /// 99th percentile of every cycle's solve time over all runs (ms).
    pub solve_ms_p99: f64,
    /// The runs that failed: seed and reason.
    pub failures: Vec<(u64, String)>,
}

/// Summarises `outcomes`.
pub fn robustness(outcomes: &[Outcome]) -> Robustness {
    let ok = outcomes.iter().filter(|o| o.success).count();
    let mut depth: Vec<f64> = outcomes.iter().map(|o| o.rms_depth_m).collect();
    let mut heading: Vec<f64> = outcomes.iter().map(|o| o.rms_heading_deg).collect();
    let mut solve: Vec<f64> = outcomes.iter().flat_map(|o| o.solve_ms.iter().copied()).collect();
    Robustness {
        runs: outcomes.len(),
        success_rate: ok as f64 / outcomes.len().max(1) as f64,
        rms_depth_m: Spread::of(&mut depth),
        rms_heading_deg: Spread::of(&mut heading),
        rms_horizontal_m: {
            let mut h: Vec<f64> = outcomes.iter().filter_map(|o| o.rms_horizontal_m).collect();
            (!h.is_empty()).then(|| Spread::of(&mut h))
        },
        solve_ms_p99: percentile(&mut solve, 99.0),
        failures: outcomes.iter().filter_map(|o| o.failure.clone().map(|f| (o.seed, f))).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_stay_within_their_spreads_and_repeat_from_the_seed() {
        let base = VehicleParams::default();
        for seed in 0..200 {
            let d = draw(&base, seed);
            assert_eq!(d, draw(&base, seed));
            for (key, v) in d.vehicle.named() {
                let b = base.named().into_iter().find(|(k, _)| *k == key).unwrap().1;
                match key {
                    "m" | "g" | "rho" | "izz" => assert_eq!(v, b),
                    "volume" => {}
                    _ => assert!((v / b - 1.0).abs() <= COEFFICIENT_SPREAD + 1e-12, "{key}: {v} vs {b}"),
                }
            }
            assert!((d.vehicle.net_buoyancy() / base.net_buoyancy() - 1.0).abs() <= BUOYANCY_SPREAD + 1e-9);
            assert!(d.current[0].hypot(d.current[1]) <= MAX_CURRENT);
            d.vehicle.validate().unwrap();
        }
    }

    #[test]
    fn spreads_are_nearest_rank() {
        let mut v: Vec<f64> = (1..=100).map(f64::from).collect();
        let s = Spread::of(&mut v);
        assert_eq!((s.median, s.p95, s.max), (50.0, 95.0, 100.0));
    }
}
