//! The numbers of a run: tracking errors, overshoot, settling, solver timing, fallbacks and
//! bound violations.

use super::path_plan::HorizontalPlan;
use super::run::Sample;
use super::scenario::Scenario;
use crate::types::{INPUT_NAMES, NU};
use crate::vehicle::wrap_angle;
use serde::Serialize;
use std::collections::BTreeMap;

/// A held reference counts from this long after it was set (s)...
pub const HOLD_SETTLE_S: f64 = 8.0;
/// ... to this long before the next change (s), where a controller that previews the
/// reference starts moving on purpose.
pub const HOLD_LEAD_S: f64 = 2.0;

/// A station is judged from this long after control starts (s): the dive and the current's
/// first push are transients.
pub const STATION_SETTLE_S: f64 = 10.0;

/// Within this distance of the last waypoint (m) a path counts as finished.
pub const PATH_FINISHED_WITHIN_M: f64 = 0.25;

/// How well a run kept its horizontal goal.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct HorizontalFigures {
    /// `station` (distance from the point held, after [`STATION_SETTLE_S`]) or `cross-track`
    /// (distance to the nearest leg, from the first waypoint to the last's time).
    pub judged: &'static str,
    /// RMS of that distance (m).
    pub rms_m: f64,
    /// Its largest value (m).
    pub max_m: f64,
    /// Samples judged.
    pub samples: usize,
    /// A path's schedule: the time it reaches its last waypoint (s).
    pub schedule_end_s: Option<f64>,
    /// When the vehicle was first within [`PATH_FINISHED_WITHIN_M`] of the last waypoint after
    /// the schedule reached its second-to-last (s; `None`: never).
    pub finished_s: Option<f64>,
}

/// The horizontal figures of a run's samples, for a scenario with a horizontal goal. The
/// positions are taken into the plan's frame by where each sample's reference put the plan's zero:
/// the simulated plant starts there, a live vehicle wherever control started in its autopilot's
/// frame (a cycle without a horizontal reference keeps the last one's).
pub(super) fn horizontal_of(scenario: &Scenario, samples: &[Sample]) -> Option<HorizontalFigures> {
    let plan = scenario.horizontal.as_ref()?;
    let mut zero = [0.0, 0.0];
    let positions: Vec<(f64, f64, f64)> = samples
        .iter()
        .map(|s| {
            if let Some(h) = s.reference.horizontal {
                let ([n, e], _) = plan.at(s.t);
                zero = [h.north - n, h.east - e];
            }
            (s.t, s.state[0] - zero[0], s.state[1] - zero[1])
        })
        .collect();
    Some(horizontal_figures(plan, &positions))
}

/// The horizontal figures of positions `(t, north, east)` in the plan's frame.
pub fn horizontal_figures(plan: &HorizontalPlan, positions: &[(f64, f64, f64)]) -> HorizontalFigures {
    let first = plan.waypoints.first().map_or(0.0, |w| w.0);
    let window = |t: f64| {
        if plan.station { t >= STATION_SETTLE_S } else { t >= first - 1e-9 && t <= plan.end() + 1e-9 }
    };
    let d: Vec<f64> = positions.iter().filter(|p| window(p.0)).map(|p| plan.cross_track(p.1, p.2)).collect();
    let n = if d.is_empty() { f64::NAN } else { d.len() as f64 };
    let (schedule_end_s, finished_s) = if plan.station {
        (None, None)
    } else {
        let w = &plan.waypoints;
        let (last, before) = (w[w.len() - 1], w[w.len().saturating_sub(2)]);
        let done =
            positions.iter().find(|p| p.0 >= before.0 && (p.1 - last.1).hypot(p.2 - last.2) <= PATH_FINISHED_WITHIN_M);
        (Some(plan.end()), done.map(|p| p.0))
    };
    HorizontalFigures {
        judged: if plan.station { "station" } else { "cross-track" },
        rms_m: (d.iter().map(|v| v * v).sum::<f64>() / n).sqrt(),
        max_m: d.iter().copied().fold(f64::NAN, f64::max),
        samples: d.len(),
        schedule_end_s,
        finished_s,
    }
}

/// The numbers of a run.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Samples run.
    pub samples: usize,
    /// The horizontal goal's figures, for a scenario with one.
    pub horizontal: Option<HorizontalFigures>,
    /// RMS of `z - z_ref` (m).
    pub rms_depth_m: f64,
    /// RMS of the wrapped heading error (deg).
    pub rms_heading_deg: f64,
    /// Largest overshoot past a new depth reference, in the step's direction (m).
    pub max_overshoot_depth_m: f64,
    /// Largest overshoot past a new heading reference (deg).
    pub max_overshoot_heading_deg: f64,
    /// Per depth step: time to enter and stay within 5 % of the step (s; NaN if never).
    pub settling_depth_s: Vec<f64>,
    /// Per heading step: time to enter and stay within 5 % of the step (s; NaN if never).
    pub settling_heading_s: Vec<f64>,
    /// Clarabel solve time, median (ms).
    pub solve_ms_median: f64,
    /// 99th percentile (ms).
    pub solve_ms_p99: f64,
    /// Maximum (ms).
    pub solve_ms_max: f64,
    /// Whole control cycle (rollout, linearisation, update, solve), median (ms).
    pub cycle_ms_median: f64,
    /// 99th percentile (ms).
    pub cycle_ms_p99: f64,
    /// Samples that applied the shifted previous plan.
    pub fallbacks: usize,
    /// Cycles longer than the sample period.
    pub deadline_misses: usize,
    /// Applied inputs outside the bounds.
    pub bound_violations: usize,
    /// Samples with at least one input channel at a bound.
    pub saturated_samples: usize,
    /// Sum of `|u_k - u_{k-1}|` over the run, per channel `X, Y, Z, Mz` (N, N m).
    pub input_total_variation: BTreeMap<&'static str, f64>,
    /// Largest heading error while the heading reference is held (deg): from
    /// [`HOLD_SETTLE_S`] after each heading change to [`HOLD_LEAD_S`] before the next (depth
    /// may change in between). NaN if the run holds no heading that long.
    pub held_heading_error_max_deg: f64,
    /// Mean `|z - z_ref|` while the depth reference is held (m): from [`HOLD_SETTLE_S`] after
    /// each depth change to [`HOLD_LEAD_S`] before the next (heading may change in between).
    /// NaN if the run holds no depth that long.
    pub steady_depth_error_m: f64,
    /// Mean wrapped `|psi - psi_ref|` while the heading reference is held (deg), held as for
    /// `held_heading_error_max_deg`.
    pub steady_heading_error_deg: f64,
    /// Cycles whose nominal rollout left the model's training envelope.
    pub envelope_exits: usize,
    /// Cycles whose nominal rollout predicted a heading vector off unit length by more than
    /// [`crate::runtime::HEADING_TOLERANCE`] (before the runtime rescaled it).
    pub heading_off_circle: usize,
}

/// The maximal stretches `(start s, end s, value)` over which `value` stays constant; the end is
/// the time of the next change (or one sample past the last).
fn held_stretches(t: &[f64], value: &[f64]) -> Vec<(f64, f64, f64)> {
    let mut out: Vec<(f64, f64, f64)> = Vec::new();
    let step = if t.len() > 1 { t[1] - t[0] } else { 0.0 };
    for (&ti, &v) in t.iter().zip(value) {
        match out.last_mut() {
            Some(last) if last.2 == v => last.1 = ti + step,
            _ => out.push((ti, ti + step, v)),
        }
    }
    out
}

/// Whether `t` lies in the held part of one of `stretches`.
fn held_at(stretches: &[(f64, f64, f64)], t: f64) -> bool {
    stretches.iter().any(|&(a, b, _)| t >= a + HOLD_SETTLE_S - 1e-9 && t < b - HOLD_LEAD_S - 1e-9)
}

/// Nearest-rank percentile of `v` (sorted in place).
pub(super) fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let rank = ((p / 100.0) * v.len() as f64).ceil() as usize;
    v[rank.clamp(1, v.len()) - 1]
}

/// Overshoot (same units as the signal) and settling time of each reference step. Each
/// step's window ends `preview` seconds before the next step, where a controller that sees
/// the reference ahead starts moving on purpose.
fn step_response(t: &[f64], y: &[f64], steps: &[(f64, f64)], end: f64, preview: f64) -> (f64, Vec<f64>) {
    let mut overshoot: f64 = 0.0;
    let mut settling = Vec::new();
    for w in 1..steps.len() {
        let (t0, target) = steps[w];
        let (from, t1) = (steps[w - 1].1, steps.get(w + 1).map_or(end, |s| s.0 - preview));
        let size = target - from;
        let band = 0.05 * size.abs();
        let window: Vec<(f64, f64)> =
            t.iter().zip(y).filter(|(ti, _)| **ti >= t0 && **ti < t1).map(|(a, b)| (*a, *b)).collect();
        for &(_, yi) in &window {
            overshoot = overshoot.max((yi - target) * size.signum());
        }
        // The last time the error was outside the band; settled right after it.
        let last_out = window.iter().rposition(|(_, yi)| (yi - target).abs() > band);
        settling.push(match last_out {
            None => 0.0,
            Some(i) if i + 1 < window.len() => window[i + 1].0 - t0,
            Some(_) => f64::NAN,
        });
    }
    (overshoot, settling)
}

/// Summarises `samples` of `scenario` run by a controller that previews the reference
/// `preview` seconds ahead (horizon times sample period).
pub fn summarise(samples: &[Sample], scenario: &Scenario, preview: f64) -> Summary {
    let t: Vec<f64> = samples.iter().map(|s| s.t).collect();
    let depth: Vec<f64> = samples.iter().map(|s| s.state[2]).collect();
    // No sample, no figure: NaN (null in JSON), never a number such as -0.0.
    let n = if samples.is_empty() { f64::NAN } else { samples.len() as f64 };
    let rms_depth = (samples.iter().map(|s| (s.state[2] - s.reference.depth).powi(2)).sum::<f64>() / n).sqrt();
    let heading_err = |s: &Sample| wrap_angle(s.state[3] - s.reference.heading).to_degrees();
    let rms_heading = (samples.iter().map(|s| heading_err(s).powi(2)).sum::<f64>() / n).sqrt();
    // Heading unwrapped around each reference so overshoot is measured in degrees.
    let heading: Vec<f64> = samples.iter().map(|s| s.reference.heading.to_degrees() + heading_err(s)).collect();
    let end = scenario.duration();
    let depth_ref: Vec<f64> = samples.iter().map(|s| s.reference.depth).collect();
    let heading_ref: Vec<f64> = samples.iter().map(|s| s.reference.heading.to_degrees()).collect();
    let (depth_held, heading_held) = (held_stretches(&t, &depth_ref), held_stretches(&t, &heading_ref));
    // Steps for overshoot and settling: the references' constant stretches of 1 s or more
    // (a ramp is a sequence of short stretches and gives none).
    let steps = |h: &[(f64, f64, f64)]| -> Vec<(f64, f64)> {
        h.iter().filter(|s| s.1 - s.0 >= 1.0).map(|s| (s.0, s.2)).collect()
    };
    let (os_d, settle_d) = step_response(&t, &depth, &steps(&depth_held), end, preview);
    let (os_h, settle_h) = step_response(&t, &heading, &steps(&heading_held), end, preview);
    let held_heading: Vec<f64> =
        samples.iter().filter(|s| held_at(&heading_held, s.t)).map(|s| heading_err(s).abs()).collect();
    let mut held_depth =
        samples.iter().filter(|s| held_at(&depth_held, s.t)).map(|s| (s.state[2] - s.reference.depth).abs());
    let mean = |v: &mut dyn Iterator<Item = f64>| {
        let (sum, n) = v.fold((0.0, 0usize), |(a, n), x| (a + x, n + 1));
        if n == 0 { f64::NAN } else { sum / n as f64 }
    };
    let mut variation = [0.0; NU];
    for w in samples.windows(2) {
        for j in 0..NU {
            variation[j] += (w[1].cycle.input[j] - w[0].cycle.input[j]).abs();
        }
    }
    let mut solve: Vec<f64> = samples.iter().map(|s| s.cycle.solve_us / 1e3).collect();
    let mut cycle: Vec<f64> = samples.iter().map(|s| s.cycle.cycle_us / 1e3).collect();
    Summary {
        samples: samples.len(),
        horizontal: horizontal_of(scenario, samples),
        rms_depth_m: rms_depth,
        rms_heading_deg: rms_heading,
        max_overshoot_depth_m: os_d,
        max_overshoot_heading_deg: os_h,
        settling_depth_s: settle_d,
        settling_heading_s: settle_h,
        solve_ms_median: percentile(&mut solve, 50.0),
        solve_ms_p99: percentile(&mut solve, 99.0),
        solve_ms_max: solve.last().copied().unwrap_or(f64::NAN),
        cycle_ms_median: percentile(&mut cycle, 50.0),
        cycle_ms_p99: percentile(&mut cycle, 99.0),
        fallbacks: samples.iter().filter(|s| s.cycle.fallback.is_some()).count(),
        deadline_misses: samples.iter().filter(|s| s.cycle.deadline_missed).count(),
        bound_violations: samples.iter().filter(|s| s.bound_violation).count(),
        saturated_samples: samples.iter().filter(|s| s.cycle.saturated.iter().any(|&b| b)).count(),
        input_total_variation: INPUT_NAMES.into_iter().zip(variation).collect(),
        held_heading_error_max_deg: held_heading.iter().copied().fold(f64::NAN, f64::max),
        steady_depth_error_m: mean(&mut held_depth),
        steady_heading_error_deg: mean(&mut held_heading.iter().copied()),
        envelope_exits: samples.iter().filter(|s| !s.cycle.envelope.inside()).count(),
        heading_off_circle: samples.iter().filter(|s| !s.cycle.envelope.heading_on_circle()).count(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_metrics_of_a_known_response() {
        // First-order response to a 1 m step at t = 1 with 10 % overshoot at t = 2.
        let t: Vec<f64> = (0..100).map(|k| k as f64 * 0.1).collect();
        let y: Vec<f64> = t
            .iter()
            .map(|&t| {
                if t < 1.0 {
                    0.0
                } else if (t - 2.0).abs() < 1e-9 {
                    1.1
                } else {
                    1.0 - (-(t - 1.0) * 5.0f64).exp()
                }
            })
            .collect();
        let (os, settle) = step_response(&t, &y, &[(0.0, 0.0), (1.0, 1.0)], 10.0, 1.6);
        assert!((os - 0.1).abs() < 1e-9);
        assert!((settle[0] - 1.1).abs() < 1e-9, "{settle:?}");
        let mut v = vec![5.0, 1.0, 3.0, 2.0, 4.0];
        assert_eq!(percentile(&mut v, 50.0), 3.0);
        assert_eq!(percentile(&mut v, 99.0), 5.0);
    }

    #[test]
    fn held_windows_start_8_s_after_a_change_and_end_2_s_before_the_next() {
        let t: Vec<f64> = (0..300).map(|k| k as f64 * 0.1).collect();
        let v: Vec<f64> = t.iter().map(|&t| if t < 10.0 { 0.0 } else { 1.0 }).collect();
        let h = held_stretches(&t, &v);
        assert_eq!(h.len(), 2);
        assert!((h[0].1 - 10.0).abs() < 1e-9 && (h[1].1 - 30.0).abs() < 1e-9, "{h:?}");
        // The first stretch is 10 s long: held from 8 s to 8 s, i.e. never.
        let held = |t| held_at(&h, t);
        assert!(!held(7.9) && !held(8.0) && !held(8.05));
        assert!(held(18.0) && held(27.9) && !held(28.0) && !held(9.0));
    }
}
