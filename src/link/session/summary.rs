//! The end of a session: the stop (neutral, the disarm it owes, why), what the log must still
//! say (out-of-order messages, positions left out, thrust not delivered, the model's misfits),
//! and the summary's live figures.

use super::flight::Flight;
use super::truth::{errors_against_truth, percentiles_ms, position_at, rms, truth_at};
use super::{AnyEstimator, AutopilotHold, LiveRun, NavigationTrack, SessionOptions};
use crate::closed_loop::Level;
use crate::estimation::Health;
use crate::link::drive::Drive;
use crate::link::safety::Trigger;
use crate::traits::DiscreteModel;
use crate::types::NU;
use serde_json::{Value, json};

/// Stops the drive (neutral; a disarm if it armed), writes what the log must still say and
/// gathers the figures.
pub(super) fn end<M: DiscreteModel>(
    mut f: Flight,
    mut drive: Drive,
    outcome: Result<(), Trigger>,
    estimator: &AnyEstimator<M>,
    o: &SessionOptions,
) -> LiveRun {
    let stopped = match outcome {
        Ok(()) if f.handed_back => drive.hand_back(),
        Ok(()) => drive.finish(),
        Err(trigger) => drive.abort(trigger),
    };
    f.notes.extend(drive.take_notes());
    f.write_notes();
    let on_clock = |at: f64| f.t0.map_or(0.0, |s| (at - s).max(0.0));
    let reason = stopped.trigger.as_ref().map(|t| {
        format!(
            "{t}; neutral command sent{}{}",
            stopped.neutral_t.map_or(" (failed)".to_string(), |n| format!(" at {:.3} s", on_clock(n))),
            if stopped.disarm_sent { ", disarm sent" } else { "" }
        )
    });
    if let Some(r) = &reason {
        f.log_line(stopped.t, Level::Error, r);
        eprintln!("{r}");
    }
    if drive.out_of_order() > 0 {
        let line = format!("{} messages arrived out of order and were dropped", drive.out_of_order());
        f.log_line(stopped.t, Level::Warning, &line);
    }
    if f.dead_reckoned > 0 {
        let line = format!(
            "{} position and velocity measurements were left out while the autopilot did not measure its position",
            f.dead_reckoned
        );
        f.log_line(stopped.t, Level::Warning, &line);
    }
    let ratios = delivered_ratios(&mut f, stopped.t);
    // What the innovations said of the model, in words an owner acts on.
    let health: Health = each!(estimator, tr => *tr.ekf().health());
    let misfits = if o.estimator.no_estimator { Vec::new() } else { health.misfits() };
    for line in &misfits {
        eprintln!("{line}");
        f.log_line(stopped.t, Level::Warning, line);
    }
    let mut live = figures(&mut f, estimator, o, &health, &drive);
    let extra = json!({
        "delivered_to_commanded": ratios,
        "model_misfits": misfits,
        "disarm_sent": stopped.disarm_sent,
        "stop_trigger": stopped.trigger.as_ref().map(|t| t.key()),
        "stop_autopilot_s": stopped.trigger.as_ref().map(|_| stopped.t),
        "neutral_autopilot_s": stopped.neutral_t,
        // A flight longer than this: its figures are those of its last part (the log has all).
        "history": {"kept_s": f.history_s, "cycles_forgotten": f.forgotten_cycles,
                    "deadline_misses_forgotten": f.forgotten_deadline_misses},
    });
    if let (Value::Object(live), Value::Object(extra)) = (&mut live, extra) {
        live.extend(extra);
    }
    let navigation = navigation_track(&f);
    LiveRun {
        samples: std::mem::take(&mut f.samples),
        log_error: f.log_error,
        stopped: reason,
        live: Some(live),
        navigation,
    }
}

/// What the thrusters delivered of what was asked (from SERVO_OUTPUT_RAW): a wrong pilot gain
/// or thruster table shows here as a ratio away from 1, and is said.
fn delivered_ratios(f: &mut Flight, t_end: f64) -> serde_json::Map<String, Value> {
    let mut ratios = serde_json::Map::new();
    for (j, name) in crate::types::INPUT_NAMES.iter().enumerate().take(NU) {
        let (num, den, count) = f.delivered[j];
        let ratio = (count >= 20 && den > 0.0).then(|| num / den);
        if let Some(r) = ratio
            && (r - 1.0).abs() > 0.25
        {
            let line = format!(
                "the thrusters delivered {r:.2} of the commanded {name} over {count} samples (SERVO_OUTPUT_RAW \
                 through the vehicle file): check the pilot gain ({}) against the autopilot's and the vehicle \
                 file's thrusters",
                f.js_gain
            );
            eprintln!("{line}");
            f.log_line(t_end, Level::Warning, &line);
        }
        ratios.insert(name.to_string(), json!(ratio));
    }
    ratios
}

/// pinc's own navigation: what it navigated on, its dead reckoning, and (with the simulator's
/// truth) its horizontal position's error beside the autopilot's, each measured from where it
/// put the vehicle when control started.
fn navigation_figures<M: DiscreteModel>(f: &Flight, estimator: &AnyEstimator<M>, drive: &Drive) -> Value {
    let reader = drive.assembler().reader();
    let late_fixes = each!(estimator, tr => tr.late_fixes());
    let bound = each!(estimator, tr => tr.dead_reckoning_bound());
    // Also after the first 20 s: the estimate's own settling left out.
    let settled_from = f.t0.unwrap_or(0.0) + 20.0;
    let error = |track: Vec<Displaced>| -> Option<Value> {
        let miss = |d: &Displaced| (d.own.0 - d.truth.0).hypot(d.own.1 - d.truth.1);
        let errors: Vec<f64> = track.iter().map(miss).collect();
        let settled: Vec<f64> = track.iter().filter(|d| d.t >= settled_from).map(miss).collect();
        let max = errors.iter().copied().fold(0.0, f64::max);
        (!errors.is_empty()).then(|| {
            json!({"rms_m": rms(&errors), "max_m": max, "samples": errors.len(),
                   "rms_after_20_s_m": (!settled.is_empty()).then(|| rms(&settled))})
        })
    };
    let (pinc, autopilot) = (error(pinc_track(f)), error(autopilot_track(f)));
    let changes: Vec<Value> =
        f.navigation_changes.iter().map(|(t, mode, std)| json!({"t": t, "mode": mode, "added_std_m": std})).collect();
    let (estimate, counts) = each!(estimator, tr => (tr.ekf().estimate(), tr.counts()));
    let ((offset, offset_std), (yaw, yaw_std), (scale, scale_std)) =
        (estimate.fix_offset, estimate.dvl_yaw, estimate.dvl_scale);
    json!({
        "fix_frame": {
            "offset_m": offset,
            "offset_std_m": offset_std,
            "known": each!(estimator, tr => tr.ekf().fix_offset_known()),
            "outliers_left_out": counts.fixes_rejected,
            "frame_moves": counts.fix_frame_moves,
            "anchor_e7": reader.anchor(),
            "origin_changes": reader.origin_changes(),
        },
        "dvl_mounting": {
            "yaw_deg": yaw.to_degrees(),
            "yaw_std_deg": yaw_std.to_degrees(),
            "scale_error": scale,
            "scale_error_std": scale_std,
        },
        "dvl_seen": f.own_velocity_at.is_some(),
        "dvl_fused": f.dvl_fused,
        "dvl_left_out_beside_the_autopilots_position": f.dvl_left_out,
        "autopilot_offset_m": f.autopilot_offset,
        "fixes": f.fixes.count(),
        "fixes_before_the_origin": reader.fixes_before_origin(),
        "fix_latency_s": reader.fix_latency(),
        "fix_std_stated_m": f.fix_std_stated,
        "fix_noise_measured_m": f.fixes.noise(),
        "dvl_noise_measured_m_s": f.dvl_velocities.noise(),
        "autopilot_left_out_beside_own_fixes": f.autopilot_left_out,
        "late_fixes": late_fixes,
        "dead_reckoning_bound_m": bound,
        "dead_reckoning_max_m": f.dead_reckoning_max,
        "changes": changes,
        "position_error_against_truth": {"pinc": pinc, "autopilot": autopilot},
    })
}

/// A horizontal position at one time (autopilot time, s) against the truth: its displacement
/// from its own first sample, the truth's from where the vehicle truly was when control
/// started (north, east, m).
pub(super) struct Displaced {
    pub(super) t: f64,
    pub(super) own: (f64, f64),
    pub(super) truth: (f64, f64),
}

/// Positions `(t, north, east)` against the simulator's truth; empty without it.
fn against_truth(f: &Flight, from: impl Iterator<Item = (f64, f64, f64)>) -> Vec<Displaced> {
    let Some(t0) = f.t0.and_then(|start| position_at(&f.truth_positions, start)) else { return Vec::new() };
    let mut origin = None;
    from.filter_map(|(t, n, e)| {
        let truth = position_at(&f.truth_positions, t)?.north_east_from(&t0);
        let (n0, e0) = *origin.get_or_insert((n, e));
        Some(Displaced { t, own: (n - n0, e - e0), truth })
    })
    .collect()
}

/// pinc's estimate from the start on, against the truth.
pub(super) fn pinc_track(f: &Flight) -> Vec<Displaced> {
    let start = f.t0.unwrap_or(0.0);
    against_truth(f, f.estimates.iter().filter(|e| e.t >= start).map(|e| (e.t, e.sim[0], e.sim[1])))
}

/// The autopilot's position (while it measured one), against the truth.
pub(super) fn autopilot_track(f: &Flight) -> Vec<Displaced> {
    let start = f.t0.unwrap_or(0.0);
    against_truth(f, f.raw_positions.iter().map(|&(t, n, e)| (t + start, n, e)))
}

/// The navigation against the truth for its plot; `None` without the truth.
fn navigation_track(f: &Flight) -> Option<NavigationTrack> {
    let start = f.t0?;
    let (pinc, autopilot) = (pinc_track(f), autopilot_track(f));
    if pinc.is_empty() {
        return None;
    }
    let on_clock = |d: &Displaced| d.t - start;
    let distance = |track: &[Displaced], of: fn(&Displaced) -> (f64, f64)| -> Vec<(f64, f64)> {
        track.iter().map(|d| (on_clock(d), of(d).0.hypot(of(d).1))).collect()
    };
    let error = |track: &[Displaced]| -> Vec<(f64, f64)> {
        track.iter().map(|d| (on_clock(d), (d.own.0 - d.truth.0).hypot(d.own.1 - d.truth.1))).collect()
    };
    Some(NavigationTrack {
        truth: distance(&pinc, |d| d.truth),
        pinc: distance(&pinc, |d| d.own),
        autopilot: distance(&autopilot, |d| d.own),
        pinc_error: error(&pinc),
        autopilot_error: error(&autopilot),
        changes: f.navigation_changes.iter().map(|&(t, mode, _)| (t, mode)).collect(),
    })
}

/// The live figures: latencies, the estimate's and the tracking's errors against the
/// simulator's truth (where it was streamed), the estimator's counts and health.
fn figures<M: DiscreteModel>(
    f: &mut Flight,
    estimator: &AnyEstimator<M>,
    o: &SessionOptions,
    health: &Health,
    drive: &Drive,
) -> Value {
    let counts = each!(estimator, tr => (tr.counts(), tr.late(), tr.restarts()));
    let errors = errors_against_truth(&f.estimates, &f.truths);
    let names = ["u", "v", "w", "r", "z"];
    let estimate_rms: serde_json::Map<String, Value> =
        names.iter().zip(&errors).map(|(n, e)| (n.to_string(), json!(rms(e)))).collect();
    // The tracking against the truth: depth, the truth's heading (true north) and the raw
    // depth sensor beside the estimate.
    let (mut depth_err, mut heading_err, mut raw_depth_err) = (Vec::new(), Vec::new(), Vec::new());
    if let Some(start) = f.t0 {
        for s in &f.samples {
            if let Some(tr) = truth_at(&f.truths, s.t + start) {
                depth_err.push(tr.z - s.reference.depth);
                heading_err.push(crate::vehicle::wrap_angle(tr.psi - s.reference.heading).to_degrees());
            }
        }
    }
    // The horizontal goal against the truth: its positions from where it truly was when control
    // started, moved to where the plan's zero lies from there (a plan from the start: nothing).
    let horizontal = match (&f.plan, f.t0) {
        (Some(plan), Some(start)) => position_at(&f.truth_positions, start).map(|t0| {
            let offset = f.plan_offset();
            let shift = (f.hold_xy().0 - offset[0], f.hold_xy().1 - offset[1]);
            let positions: Vec<(f64, f64, f64)> = f
                .samples
                .iter()
                .filter_map(|s| position_at(&f.truth_positions, s.t + start).map(|p| (s.t, p.north_east_from(&t0))))
                .map(|(t, (n, e))| (t, n + shift.0, e + shift.1))
                .collect();
            crate::closed_loop::horizontal_figures(plan, &positions)
        }),
        _ => None,
    };
    // The same against the autopilot's own position, which both controllers steer by: what the
    // controller does with the position it is given, the position source's own error left out.
    let against_source = f.plan.as_ref().map(|plan| {
        let offset = f.plan_offset();
        let positions: Vec<(f64, f64, f64)> =
            f.raw_positions.iter().map(|&(t, n, e)| (t, n - offset[0], e - offset[1])).collect();
        crate::closed_loop::horizontal_figures(plan, &positions)
    });
    let navigation = navigation_figures(f, estimator, drive);
    for &(t, z) in &f.raw_depths {
        if let Some(tr) = truth_at(&f.truths, t) {
            raw_depth_err.push(z - tr.z);
        }
    }
    let sensors: serde_json::Map<String, Value> = crate::estimation::Sensor::ALL
        .iter()
        .map(|s| {
            let h = health.sensor(*s);
            (
                s.name().to_string(),
                json!({"count": h.count, "rejected": h.rejected, "nis_slow_max": h.nis_slow_max, "nis_slow": h.nis_slow}),
            )
        })
        .collect();
    json!({
        "flown_by": f.hold.map_or("pinc", AutopilotHold::name),
        "hold_mode_entered_s": f.mode_entered,
        "estimator": if o.estimator.no_estimator { Value::Null } else { json!(o.estimator.estimator_model) },
        "control_started_after_arming_s": f.control_after,
        "state_age_ms": percentiles_ms(&mut f.ages),
        "latency_ms": percentiles_ms(&mut f.latencies),
        "estimate_rms_error": estimate_rms,
        "truth_samples": errors[0].len(),
        "truth_rms": {"depth_m": rms(&depth_err), "heading_deg": rms(&heading_err), "samples": depth_err.len()},
        "truth_horizontal": horizontal,
        "horizontal_against_position_source": against_source,
        "horizontal_goal_changes": f.goal_changes,
        "navigation": navigation,
        "raw_depth_rms_error": rms(&raw_depth_err),
        "js_gain": f.js_gain,
        "heading_reference": f.heading_reference.map(|h| h.key()),
        "heading_reference_text": f.heading_reference.map(|h| h.describe()),
        "autopilot_not_ready": f.not_ready_said,
        "dead_reckoned_left_out": f.dead_reckoned,
        "vertical_velocity": {"taken": f.vertical_velocities,
            "left_out_ekf_not_ready": drive.assembler().reader().vertical_velocity_left_out()},
        "estimator_health": sensors,
        "process_noise_scale": each!(estimator, tr => tr.ekf().process_scale()),
        "fused": counts.0.fused, "rejected": counts.0.rejected, "reacquired": counts.0.reacquired, "late": counts.1, "restarts": counts.2,
    })
}
