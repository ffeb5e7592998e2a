//! The live session: references flown on a vehicle over MAVLink, by pinc's MPC or by the
//! autopilot's own depth and heading hold, with one home for everything around the loop:
//! connect, check the autopilot's configuration, arm (each refusal printed), wait until the
//! autopilot's own estimate is usable, estimate the state, command, every safety stop, the
//! MCAP log (the same schema for both controllers, so one summary, plot and table compare
//! them) and the summary's live figures. `mpc_track --connect` runs it.

use super::autopilot_estimate::HeadingReference;
use super::cli::{DriveArgs, EstimatorArgs, LinkOptions, non_negative, open};
use super::command::CommandWay;
use super::drive::{Drive, Note};
use super::link::{Received, SubMode};
use super::safety::Trigger;
use crate::closed_loop::{Level, LogError, McapLog, Sample, Scenario};
use crate::estimation::mavlink::Observation;
use crate::estimation::{Estimate, Estimator, Health, Measurement};
use crate::mpc::{CycleReport, Mpc};
use crate::runtime::EnvelopeStatus;
use crate::traits::DiscreteModel;
use crate::types::{Input, NU, SimState};
use crate::vehicle::{Rk4Vehicle, Thrusters, VehicleParams, to_network};
use mavlink::dialects::ardupilotmega::{
    AttitudeTargetTypemask, MavFrame, MavMessage, PositionTargetTypemask, SET_ATTITUDE_TARGET_DATA,
    SET_POSITION_TARGET_GLOBAL_INT_DATA, SET_POSITION_TARGET_LOCAL_NED_DATA, SIM_STATE_DATA,
};
use serde_json::{Value, json};
use std::cell::RefCell;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// `SERVO_OUTPUT_RAW`, whose outputs are the input the estimator is driven by.
const SERVO_OUTPUT_RAW_ID: u32 = 36;
/// `SIM_STATE`: the simulator's truth.
const SIM_STATE_ID: u32 = 108;
/// How long to wait for a first `EKF_STATUS_REPORT` before going on without the autopilot's
/// word on its own estimate (older firmware may not send it).
const EKF_STATUS_WAIT: Duration = Duration::from_secs(5);

/// The autopilot's own controllers that fly the same references.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AutopilotHold {
    /// ALT_HOLD: depth by `SET_POSITION_TARGET_GLOBAL_INT` (z only), heading by
    /// `SET_ATTITUDE_TARGET` (attitude only).
    AltHold,
    /// GUIDED: position, velocity and heading by `SET_POSITION_TARGET_LOCAL_NED` (needs a
    /// position source).
    Guided,
}

impl AutopilotHold {
    /// `althold` or `guided`.
    pub fn name(self) -> &'static str {
        match self {
            AutopilotHold::AltHold => "althold",
            AutopilotHold::Guided => "guided",
        }
    }

    fn mode(self) -> SubMode {
        match self {
            AutopilotHold::AltHold => SubMode::AltHold,
            AutopilotHold::Guided => SubMode::Guided,
        }
    }
}

/// Who flies the references.
pub enum Flyer<M: DiscreteModel> {
    /// pinc's MPC on its model.
    Mpc(Box<Mpc<M>>),
    /// The autopilot's own controller; `model` is the estimator's (the estimate is logged as
    /// in an MPC run, for the same figures).
    Autopilot {
        /// Which controller.
        hold: AutopilotHold,
        /// The model the state estimate runs on.
        model: M,
    },
}

impl<M: DiscreteModel> Flyer<M> {
    fn model(&self) -> &M {
        match self {
            Flyer::Mpc(m) => m.model(),
            Flyer::Autopilot { model, .. } => model,
        }
    }
}

/// What a session needs besides the flyer: the address, the vehicle file and the options.
pub struct SessionOptions<'a> {
    /// The MAVLink address.
    pub connect: &'a str,
    /// The vehicle file (its `[[thruster]]` tables turn the wrench into commands).
    pub vehicle: Option<&'a Path>,
    /// What a model fitted by `pinc fit` carries of its vehicle: its thrusters where no
    /// vehicle file is given, its sensor model where no noise flag is, its report's warnings.
    pub fitted: Option<&'a crate::model::FittedVehicle>,
    /// The link.
    pub link: &'a LinkOptions,
    /// Commands and safety limits.
    pub drive: &'a DriveArgs,
    /// The state estimator.
    pub estimator: &'a EstimatorArgs,
}

/// A session's outcome.
pub struct LiveRun {
    /// One per control cycle.
    pub samples: Vec<Sample>,
    /// The first log write error, if any (the session went on).
    pub log_error: Option<LogError>,
    /// Why it stopped early (with the neutral command and disarm it sent); `None`: it ran to
    /// the scenario's end.
    pub stopped: Option<String>,
    /// The live figures: latencies, the estimator's counts and health, the heading reference,
    /// the errors against a simulator's truth.
    pub live: Option<Value>,
}

/// The simulator's truth at an autopilot time: depth, heading, body velocities, yaw rate.
#[derive(Debug, Clone, Copy)]
struct Truth {
    t: f64,
    z: f64,
    psi: f64,
    uvw: [f64; 3],
    r: f64,
}

fn truth_of(t: f64, s: &SIM_STATE_DATA) -> Truth {
    // NED velocity into the body frame by the whole attitude (Z-Y-X Euler angles).
    let (roll, pitch, yaw) = (f64::from(s.roll), f64::from(s.pitch), f64::from(s.yaw));
    let r = nalgebra::Rotation3::from_euler_angles(roll, pitch, yaw);
    let body = r.inverse() * nalgebra::Vector3::new(f64::from(s.vn), f64::from(s.ve), f64::from(s.vd));
    Truth { t, z: -f64::from(s.alt), psi: yaw, uvw: [body.x, body.y, body.z], r: f64::from(s.zgyro) }
}

/// The truth at `t`, interpolated between two truths at most 0.2 s apart (`SIM_STATE` has no
/// stamp of its own: its arrival's autopilot time is used).
fn truth_at(truths: &[Truth], t: f64) -> Option<Truth> {
    let k = truths.partition_point(|tr| tr.t <= t);
    if k == 0 || k == truths.len() {
        return None;
    }
    let (a, b) = (&truths[k - 1], &truths[k]);
    if b.t - a.t > 0.2 || b.t <= a.t {
        return None;
    }
    let f = (t - a.t) / (b.t - a.t);
    let lerp = |x: f64, y: f64| x + f * (y - x);
    Some(Truth {
        t,
        z: lerp(a.z, b.z),
        psi: a.psi + f * crate::vehicle::wrap_angle(b.psi - a.psi),
        uvw: std::array::from_fn(|i| lerp(a.uvw[i], b.uvw[i])),
        r: lerp(a.r, b.r),
    })
}

/// The estimate's errors `u v w r z` against the truth at each estimate's time. Heading is left
/// out: ATTITUDE's is magnetic where the autopilot knows no declination, the truth's true.
fn errors_against_truth(estimates: &[Estimate], truths: &[Truth]) -> [Vec<f64>; 5] {
    let mut errors: [Vec<f64>; 5] = Default::default();
    for e in estimates {
        let Some(tr) = truth_at(truths, e.t) else { continue };
        let truth = [tr.uvw[0], tr.uvw[1], tr.uvw[2], tr.r, tr.z];
        for (i, idx) in [4, 5, 6, 7, 2].into_iter().enumerate() {
            errors[i].push(e.sim[idx] - truth[i]);
        }
    }
    errors
}

fn rms(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt())
}

fn percentiles_ms(v: &mut [f64]) -> Value {
    if v.is_empty() {
        return json!({"median": null, "p99": null, "max": null});
    }
    v.sort_by(f64::total_cmp);
    let at = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1] * 1e3;
    json!({"median": at(0.5), "p99": at(0.99), "max": v[v.len() - 1] * 1e3})
}

/// The process model of the estimator.
enum EstimatorModel<M> {
    Controller(M),
    Vehicle(Rk4Vehicle),
}

/// Either model behind one estimator type.
enum AnyEstimator<M: DiscreteModel> {
    Controller(Estimator<M>),
    Vehicle(Estimator<Rk4Vehicle>),
}

macro_rules! each {
    ($t:expr, $x:ident => $body:expr) => {
        match $t {
            AnyEstimator::Controller($x) => $body,
            AnyEstimator::Vehicle($x) => $body,
        }
    };
}

/// The autopilot's targets for one cycle: depth and heading at `reference`, the start's
/// horizontal position held (GUIDED), the depth's rate from the next reference.
fn send_targets(
    drive: &Drive,
    hold: AutopilotHold,
    time_boot_ms: u32,
    reference: (f64, f64),
    depth_rate: f64,
    hold_xy: (f64, f64),
) -> Result<(), Trigger> {
    let (system, component) = {
        let a = drive.autopilot();
        (a.system_id, a.component_id)
    };
    let (depth, heading) = reference;
    let link = drive.link();
    let sent = match hold {
        AutopilotHold::AltHold => {
            // ArduSub 4.x in ALT_HOLD: z only (type_mask 3579), `alt` metres up from the origin.
            let depth_target = MavMessage::SET_POSITION_TARGET_GLOBAL_INT(SET_POSITION_TARGET_GLOBAL_INT_DATA {
                time_boot_ms,
                target_system: system,
                target_component: component,
                coordinate_frame: MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT,
                type_mask: PositionTargetTypemask::from_bits_truncate(3579),
                lat_int: 0,
                lon_int: 0,
                alt: -depth as f32,
                vx: 0.0,
                vy: 0.0,
                vz: 0.0,
                afx: 0.0,
                afy: 0.0,
                afz: 0.0,
                yaw: 0.0,
                yaw_rate: 0.0,
            });
            // Attitude only, the throttle ignored (type_mask 71): ALT_HOLD keeps it 5 s.
            let (s, c) = (0.5 * heading).sin_cos();
            let heading_target = MavMessage::SET_ATTITUDE_TARGET(SET_ATTITUDE_TARGET_DATA {
                time_boot_ms,
                target_system: system,
                target_component: component,
                type_mask: AttitudeTargetTypemask::from_bits_truncate(71),
                q: [c as f32, 0.0, 0.0, s as f32],
                body_roll_rate: 0.0,
                body_pitch_rate: 0.0,
                body_yaw_rate: 0.0,
                thrust: 0.5,
            });
            link.send(&depth_target).and_then(|()| link.send(&heading_target))
        }
        AutopilotHold::Guided => {
            // Position, velocity and yaw (type_mask 2496: accelerations and yaw rate ignored),
            // which streams smoothly (2552 restarts the planner at every message).
            link.send(&MavMessage::SET_POSITION_TARGET_LOCAL_NED(SET_POSITION_TARGET_LOCAL_NED_DATA {
                time_boot_ms,
                target_system: system,
                target_component: component,
                coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
                type_mask: PositionTargetTypemask::from_bits_truncate(2496),
                x: hold_xy.0 as f32,
                y: hold_xy.1 as f32,
                z: depth as f32,
                vx: 0.0,
                vy: 0.0,
                vz: depth_rate as f32,
                afx: 0.0,
                afy: 0.0,
                afz: 0.0,
                yaw: heading as f32,
                yaw_rate: 0.0,
            }))
        }
    };
    sent.map_err(|e| Trigger::Link(e.to_string()))
}

/// Runs `scenario` on the vehicle: reads the autopilot's configuration (its outputs must take
/// the commands the way asked), arms (retrying while the autopilot refuses), waits (neutral
/// commands) until the autopilot's estimate is usable and the state estimate runs (or, with
/// `--wait-position`, for a position source), then one cycle per fresh state sample until the
/// scenario ends or a safety trigger stops it. The scenario's time 0 is the first cycle.
///
/// # Errors
/// Set-up: no vehicle file, a bad option, the link, no autopilot; these command nothing.
pub fn run<M: DiscreteModel + Clone>(
    mut flyer: Flyer<M>,
    scenario: &Scenario,
    o: &SessionOptions,
    log: &mut McapLog,
) -> Result<LiveRun, String> {
    // The thrusters: the vehicle file's, else those the fitted model carries.
    let thrusters = match (o.vehicle, o.fitted) {
        (Some(file), _) => (Thrusters::load(file).map_err(|e| e.to_string())?, file.display().to_string()),
        (None, Some(f)) => {
            let source = "the model's fitted thrusters";
            let t = Thrusters::from_toml(&f.thrusters_toml, Path::new(source))
                .map_err(|e| e.to_string())?
                .ok_or(format!("{source}: no [[thruster]] table"))?;
            (t, source.to_string())
        }
        (None, None) => {
            return Err("--connect needs --vehicle V.toml with the vehicle's [[thruster]] tables, or a model fitted \
                        by `pinc fit` (it carries them)"
                .into());
        }
    };
    let hold = match &flyer {
        Flyer::Autopilot { hold, .. } => Some(*hold),
        Flyer::Mpc(_) => None,
    };
    // The autopilot's own controller takes neutral pilot axes beside its targets.
    let mut drive_args = o.drive.clone();
    if hold.is_some() {
        drive_args.command_way = CommandWay::Manual.name().into();
    }
    let commander = drive_args.commander_of(thrusters.0, &thrusters.1)?;
    // The session arms and waits in MANUAL; the autopilot's own controller takes over when
    // control starts (GUIDED needs the position that may come only after arming).
    let settings = drive_args.settings()?;
    let wait_position = non_negative("--wait-position", o.drive.wait_position)?;
    // How long to wait (neutral) for a state to control on: --wait-position, else 30 s.
    let give_up = if wait_position.is_zero() { Duration::from_secs(30) } else { wait_position };
    let noise = o.estimator.noise(o.fitted.map(|f| &f.sensors))?;
    let model = flyer.model().clone();
    let dt = model.dt();
    let position_free = model.position_free();
    let estimator_model = match o.estimator.estimator_model.as_str() {
        "vehicle" => {
            let file = o.vehicle.ok_or("--estimator-model vehicle needs --vehicle V.toml")?;
            let params = VehicleParams::load(file).map_err(|e| e.to_string())?;
            EstimatorModel::Vehicle(Rk4Vehicle { params, ..Rk4Vehicle::with_dt(dt) })
        }
        _ => EstimatorModel::Controller(model),
    };
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed)).map_err(|e| format!("cannot catch Ctrl-C: {e}"))?;
    let (link, autopilot, assembler) = open(o.connect, o.link, |_| {})?;
    link.set_message_rate(SERVO_OUTPUT_RAW_ID, o.drive.outputs_rate).map_err(|e| e.to_string())?;
    if o.estimator.sim_truth {
        link.set_message_rate(SIM_STATE_ID, o.link.rate).map_err(|e| e.to_string())?;
    }
    let mut log_error: Option<LogError> = None;
    let estimator_line = if o.estimator.no_estimator {
        "no state estimator (the raw state; body velocities from the autopilot's EKF)".to_string()
    } else {
        format!(
            "state estimator on the {} model (depth std {} m, heading std {} rad)",
            o.estimator.estimator_model, noise.depth_std, noise.heading_std
        )
    };
    let flown_by = match hold {
        Some(h) => format!("the autopilot's own {} flies the references", h.name()),
        None => format!("pinc's MPC flies the references, commands by {}", commander.way().name()),
    };
    let line = format!(
        "live vehicle on {} (system {}), {flown_by}; {estimator_line}; {}",
        o.connect,
        autopilot.system_id,
        settings.limits.describe()
    );
    log_error = log_error.or(log.log(0.0, Level::Info, &line).err());
    // A fitted model whose report failed flies, but says why it may fly badly first.
    for w in o.fitted.map_or(&[][..], |f| &f.warnings[..]) {
        let line = format!("the model's fit report failed: {w}");
        eprintln!("warning: {line}");
        log_error = log_error.or(log.log(0.0, Level::Warning, &line).err());
    }
    let truths: RefCell<Vec<Truth>> = RefCell::new(Vec::new());
    let seen = |r: &Received, t: f64| {
        if let MavMessage::SIM_STATE(s) = &r.message {
            truths.borrow_mut().push(truth_of(t, s));
        }
    };
    let mut notes: Vec<Note> = Vec::new();
    let mut drive = match Drive::start(link, autopilot, assembler, commander, settings, stop, seen) {
        Ok(d) => d,
        Err(mut stopped) => {
            for n in std::mem::take(&mut stopped.notes) {
                log_error = log_error.or(log.log(0.0, n.level, &n.text).err());
            }
            let reason = stopped.trigger.map_or_else(|| "stopped".to_string(), |t| t.to_string());
            log_error = log_error.or(log.log(0.0, Level::Error, &reason).err());
            eprintln!("{reason}");
            return Ok(LiveRun { samples: Vec::new(), log_error, stopped: Some(reason), live: None });
        }
    };
    let js_gain = drive.commander().js_gain();
    let mut estimator = match estimator_model {
        EstimatorModel::Controller(m) => AnyEstimator::Controller(Estimator::new(m, noise)),
        EstimatorModel::Vehicle(v) => AnyEstimator::<M>::Vehicle(Estimator::new(v, noise)),
    };
    let (n, (lo, hi)) = match &flyer {
        Flyer::Mpc(mpc) => (mpc.config().horizon, mpc.bounds()),
        Flyer::Autopilot { .. } => (1, (Input::repeat(f64::NEG_INFINITY), Input::repeat(f64::INFINITY))),
    };
    let mut samples: Vec<Sample> = Vec::new();
    let waited = Instant::now();
    let mut t0: Option<f64> = None;
    let mut refs = vec![scenario.reference(0.0); n];
    let mut horizontal_before: Option<bool> = None;
    let (mut ages, mut latencies) = (Vec::new(), Vec::new());
    let (mut estimates, mut all_truths): (Vec<Estimate>, Vec<Truth>) = (Vec::new(), Vec::new());
    let mut control_after: Option<f64> = None;
    // Per channel: sum of applied x asked, of asked^2, and the count (a least-squares gain of
    // the outputs on the commands), and the last command with its autopilot time.
    let mut delivered = [(0.0f64, 0.0f64, 0usize); NU];
    let mut last_command: Option<(f64, Input)> = None;
    let mut last_applied = Input::zeros();
    // The autopilot's word on its own estimate: the reasons it is not ready (printed once
    // each), whether its position is measured, and the heading it reports.
    let mut not_ready_said: Vec<String> = Vec::new();
    let mut position_measured_before: Option<bool> = None;
    let mut dead_reckoned = 0u64;
    // The autopilot's vertical velocities taken (its reader counts those its EKF did not vouch
    // for).
    let mut vertical_velocities = 0u64;
    let mut heading_reference: Option<HeadingReference> = None;
    let mut hold_xy = (0.0, 0.0);
    // When the hold's mode was last asked for, and whether the autopilot is in it.
    let mut mode_asked: Option<f64> = None;
    let mut mode_entered: Option<f64> = None;
    // The raw depth sensor's reading at each cycle (autopilot time), against the truth.
    let mut raw_depths: Vec<(f64, f64)> = Vec::new();

    let t_log = |at: f64, t0: Option<f64>| t0.map_or(0.0, |s| (at - s).max(0.0));
    let outcome: Result<(), Trigger> = loop {
        let fresh = match drive.next_state(seen) {
            Ok(f) => f,
            Err(t) => break Err(t),
        };
        notes.extend(drive.take_notes());
        // A position the autopilot only dead-reckons (its source lost) or holds is no
        // measurement: it is not fused.
        let position_measured = drive.position_measured();
        if position_measured_before.is_some_and(|b| b != position_measured) {
            notes.push(Note {
                t: fresh.state.t,
                level: if position_measured { Level::Info } else { Level::Warning },
                text: if position_measured {
                    "the autopilot measures its position again (EKF_STATUS_REPORT): its position is fused".into()
                } else {
                    "the autopilot no longer measures its position (its GPS lost the fix, or EKF_STATUS_REPORT \
                     says dead reckoning or held): LOCAL_POSITION_NED is no longer fused"
                        .into()
                },
                from_autopilot: false,
            });
        }
        position_measured_before = Some(position_measured);
        let vertical_velocity_valid = drive.assembler().reader().vertical_velocity_valid();
        for mut ob in drive.drain_observations() {
            match ob {
                // A dead-reckoned position's vertical velocity is still the EKF's estimate from
                // its accelerometers and depth: that part is kept.
                Observation::Measured(Measurement::VelocityNed { t, vd, .. })
                    if !position_measured && vertical_velocity_valid =>
                {
                    dead_reckoned += 1;
                    vertical_velocities += 1;
                    ob = Observation::Measured(Measurement::VerticalVelocity { t, vd });
                }
                Observation::Measured(Measurement::Position { .. } | Measurement::VelocityNed { .. })
                    if !position_measured =>
                {
                    dead_reckoned += 1;
                    continue;
                }
                Observation::Measured(Measurement::VerticalVelocity { .. }) => vertical_velocities += 1,
                Observation::Applied(t, applied) => {
                    last_applied = applied;
                    // The outputs the autopilot reports against what pinc asked for, once the
                    // command has had time to reach them (half a sample).
                    if let Some((sent_t, asked)) = last_command
                        && t > sent_t + 0.5 * dt
                    {
                        for j in 0..NU {
                            if asked[j].abs() > 0.05 * (hi[j] - lo[j]).abs() {
                                delivered[j].0 += applied[j] * asked[j];
                                delivered[j].1 += asked[j] * asked[j];
                                delivered[j].2 += 1;
                            }
                        }
                    }
                }
                _ => {}
            }
            each!(&mut estimator, tr => match ob {
                Observation::Measured(m) => tr.measure(m),
                Observation::Applied(t, u) => tr.applied(t, u),
                Observation::Unfused(_) => {}
            });
        }
        let estimate: Option<Estimate> = if o.estimator.no_estimator {
            None
        } else {
            match each!(&mut estimator, tr => tr.advance(fresh.state.t)) {
                Ok(e) => e,
                Err(e) => break Err(Trigger::Error(format!("state estimator: {e}"))),
            }
        };
        let horizontal = each!(&estimator, tr => tr.horizontal_observed(fresh.state.t));
        if horizontal_before.is_some_and(|b| b != horizontal) || (horizontal && horizontal_before.is_none()) {
            let text = if horizontal {
                "position source present: position and velocity fused into the estimate"
            } else {
                "position source lost: running on the estimate (depth, heading, yaw rate and the model)"
            };
            notes.push(Note {
                t: fresh.state.t,
                level: if horizontal { Level::Info } else { Level::Warning },
                text: text.into(),
                from_autopilot: false,
            });
        }
        horizontal_before = Some(horizontal);
        // What the controller runs on: the estimate, or without one the raw full state.
        let state: Option<SimState> = match (&estimate, o.estimator.no_estimator) {
            (Some(e), _) if horizontal || position_free => Some(e.sim),
            (None, true) if fresh.state.capability == super::state::Capability::Full => {
                Some(SimState::from(fresh.state.sim))
            }
            _ => None,
        };
        let start = match t0 {
            Some(s) => s,
            None => {
                // The autopilot's own estimate first: attitude and heading usable.
                let not_ready: Vec<String> = match drive.ekf_status() {
                    Some(s) => s.not_ready(),
                    None if waited.elapsed() < EKF_STATUS_WAIT => {
                        vec!["no EKF_STATUS_REPORT from the autopilot yet".to_string()]
                    }
                    None => Vec::new(),
                };
                for why in &not_ready {
                    if !not_ready_said.contains(why) {
                        let text = format!("waiting for the autopilot: {why}");
                        eprintln!("{text}");
                        notes.push(Note { t: fresh.state.t, level: Level::Warning, text, from_autopilot: false });
                        not_ready_said.push(why.clone());
                    }
                }
                let waiting_for_position = !horizontal && waited.elapsed() < wait_position;
                if state.is_none() || waiting_for_position || !not_ready.is_empty() {
                    if waited.elapsed() > give_up && (state.is_none() || !not_ready.is_empty()) {
                        if !not_ready.is_empty() {
                            break Err(Trigger::NotReady(format!(
                                "the autopilot's estimate was not usable after {:.0} s: {}",
                                waited.elapsed().as_secs_f64(),
                                not_ready.join("; ")
                            )));
                        }
                        let why = if o.estimator.no_estimator {
                            format!(
                                "no full state: {}; the estimator (on by default) needs only depth and heading",
                                fresh.state.capability
                            )
                        } else if !position_free {
                            "the model needs x, y (it is not position-free) and no position source came".to_string()
                        } else {
                            format!("the state estimate did not start: {}", fresh.state.capability)
                        };
                        break Err(Trigger::Error(format!(
                            "no state to control on after {:.0} s: {why}",
                            waited.elapsed().as_secs_f64()
                        )));
                    }
                    match drive.send_neutral(&fresh) {
                        Ok(_) => {
                            each!(&mut estimator, tr => tr.commanded(Input::zeros()));
                            continue;
                        }
                        Err(t) => break Err(t),
                    }
                }
                if not_ready_said.is_empty() && drive.ekf_status().is_none() {
                    notes.push(Note {
                        t: fresh.state.t,
                        level: Level::Warning,
                        text: "the autopilot sent no EKF_STATUS_REPORT: its estimate's health is unknown".into(),
                        from_autopilot: false,
                    });
                }
                let reference =
                    HeadingReference::of(drive.params(), drive.ekf_status().is_some_and(|s| s.absolute_position()));
                let level = if reference == HeadingReference::Magnetic { Level::Warning } else { Level::Info };
                if level == Level::Warning {
                    eprintln!("{}", reference.describe());
                }
                notes.push(Note { t: fresh.state.t, level, text: reference.describe(), from_autopilot: false });
                heading_reference = Some(reference);
                notes.push(Note {
                    t: fresh.state.t,
                    level: Level::Info,
                    text: format!(
                        "control starts {:.1} s after arming, on the {}{}",
                        waited.elapsed().as_secs_f64(),
                        if estimate.is_some() { "state estimate" } else { "raw state" },
                        if horizontal {
                            " with a position source"
                        } else {
                            " without a position source (depth and heading)"
                        }
                    ),
                    from_autopilot: false,
                });
                control_after = Some(waited.elapsed().as_secs_f64());
                if let Some(s) = &state {
                    hold_xy = (s[0], s[1]);
                }
                *t0.insert(fresh.state.t)
            }
        };
        for note in notes.drain(..) {
            log_error = log_error.or(log.log(t_log(note.t, t0), note.level, &note.text).err());
        }
        let Some(state) = state else {
            let why = if o.estimator.no_estimator {
                format!("the raw state lost a part: {}", fresh.state.capability)
            } else {
                "the state estimate stopped (a gap in the measurements longer than 2 s)".to_string()
            };
            break Err(Trigger::Error(why));
        };
        // An estimate that no longer follows what the vehicle measures steers a vehicle it has
        // lost: stop.
        if let Some(lost) = each!(&estimator, tr => tr.ekf().health().lost()) {
            break Err(Trigger::EstimateLost(lost.to_string()));
        }
        let t = fresh.state.t - start;
        if t >= scenario.duration() - 1e-9 {
            break Ok(());
        }
        let (cycle, prediction, sent) = match &mut flyer {
            Flyer::Mpc(mpc) => {
                for (j, r) in refs.iter_mut().enumerate() {
                    *r = scenario.reference(t + (j + 1) as f64 * dt);
                }
                let cycle = mpc.step(&to_network(&state), &refs);
                let sent = match drive.send(&fresh, &cycle.input) {
                    Ok(s) => s,
                    Err(t) => break Err(t),
                };
                let asked = drive.commander().input_of(&sent.command);
                each!(&mut estimator, tr => tr.commanded(asked));
                last_command = Some((sent.autopilot_t, asked));
                (cycle, mpc.prediction().to_vec(), sent)
            }
            Flyer::Autopilot { hold, .. } => {
                // Into the hold's mode, asked for again every half second until the heartbeat
                // says so; an autopilot that will not enter it within 3 s is a refusal.
                if drive.mode() == hold.mode() as u32 {
                    mode_entered.get_or_insert(t);
                } else if mode_entered.is_some() {
                    break Err(Trigger::Refused(format!(
                        "the autopilot left {} for mode {} (the pilot or a failsafe)",
                        hold.name(),
                        SubMode::name_of(drive.mode())
                    )));
                } else if t > 3.0 {
                    break Err(Trigger::Refused(format!(
                        "the autopilot did not enter {} within 3 s (still in {}){}",
                        hold.name(),
                        SubMode::name_of(drive.mode()),
                        if *hold == AutopilotHold::Guided { "; GUIDED needs a position source" } else { "" }
                    )));
                } else if mode_asked.is_none_or(|m| t - m >= 0.5) {
                    if let Err(e) = drive.link().set_mode(hold.mode()) {
                        break Err(Trigger::Link(e.to_string()));
                    }
                    mode_asked = Some(t);
                }
                let next = scenario.reference(t + dt);
                let now = scenario.reference(t);
                let target = (next.depth, next.heading);
                let rate = (next.depth - now.depth) / dt;
                let boot_ms = (fresh.state.t * 1e3).round() as u32;
                if let Err(trigger) = send_targets(&drive, *hold, boot_ms, target, rate, hold_xy) {
                    break Err(trigger);
                }
                // Neutral pilot axes keep the pilot-input failsafe quiet.
                let sent = match drive.send_neutral(&fresh) {
                    Ok(s) => s,
                    Err(t) => break Err(t),
                };
                each!(&mut estimator, tr => tr.commanded(last_applied));
                let cycle = CycleReport {
                    input: last_applied,
                    saturated: [false; NU],
                    fallback: None,
                    envelope: EnvelopeStatus::default(),
                    status: clarabel::solver::SolverStatus::Unsolved,
                    iterations: 0,
                    objective: 0.0,
                    linearise_us: 0.0,
                    update_us: 0.0,
                    solve_us: 0.0,
                    cycle_us: 0.0,
                    deadline_missed: false,
                };
                (cycle, Vec::new(), sent)
            }
        };
        let u = cycle.input;
        let bound_violation = (0..NU).any(|j| !(u[j] >= lo[j] - 1e-9 && u[j] <= hi[j] + 1e-9));
        // The state's age when its command went out, and the arrival-to-send latency.
        let state_age = sent.autopilot_t - fresh.state.t;
        let latency = sent.at.saturating_duration_since(fresh.arrived).as_secs_f64();
        ages.push(state_age);
        latencies.push(latency);
        if fresh.state.sim[2].is_finite() {
            raw_depths.push((fresh.state.t, fresh.state.sim[2]));
        }
        if log_error.is_none() {
            log_error = log.link_cycle(t, state_age, latency, sent.autopilot_t).err();
        }
        for tr in truths.borrow_mut().drain(..) {
            if log_error.is_none() {
                let m = json!({"t_autopilot_s": tr.t, "z": tr.z, "psi": tr.psi, "u": tr.uvw[0], "v": tr.uvw[1], "w": tr.uvw[2], "r": tr.r});
                log_error = log.live("/truth", "pinc.SimulatorTruth", (tr.t - start).max(0.0), m).err();
            }
            all_truths.push(tr);
        }
        if let Some(e) = &estimate {
            estimates.push(*e);
            let raw: Vec<Option<f64>> = fresh.state.named().map(|(_, v)| v).collect();
            let scale = each!(&estimator, tr => tr.ekf().process_scale());
            let m = json!({
                "t_autopilot_s": e.t, "estimate": e.sim.as_slice(), "std": e.std,
                "disturbance": e.disturbance.as_slice(), "disturbance_std": e.disturbance_std, "raw": raw,
                "position_source": horizontal, "process_noise_scale": scale, "heave_gain": e.heave_gain.0,
            });
            if log_error.is_none() {
                log_error = log.live("/estimate", "pinc.Estimate", t, m).err();
            }
        }
        let sample = Sample { t, state, reference: scenario.reference(t), cycle, prediction, bound_violation };
        if log_error.is_none() {
            log_error = log.record(&sample).err();
        }
        samples.push(sample);
    };
    let stopped = match outcome {
        Ok(()) => drive.finish(),
        Err(trigger) => drive.abort(trigger),
    };
    notes.extend(drive.take_notes());
    for note in notes.drain(..) {
        log_error = log_error.or(log.log(t_log(note.t, t0), note.level, &note.text).err());
    }
    let reason = stopped.trigger.as_ref().map(|t| {
        format!(
            "{t}; neutral command sent{}{}",
            stopped.neutral_t.map_or(" (failed)".to_string(), |n| format!(" at {:.3} s", t_log(n, t0))),
            if stopped.disarm_sent { ", disarm sent" } else { "" }
        )
    });
    let t_end = t_log(stopped.t, t0);
    if let Some(r) = &reason {
        log_error = log_error.or(log.log(t_end, Level::Error, r).err());
        eprintln!("{r}");
    }
    if drive.out_of_order() > 0 {
        let line = format!("{} messages arrived out of order and were dropped", drive.out_of_order());
        log_error = log_error.or(log.log(t_end, Level::Warning, &line).err());
    }
    if dead_reckoned > 0 {
        let line = format!(
            "{dead_reckoned} position and velocity measurements were left out while the autopilot did not measure \
             its position"
        );
        log_error = log_error.or(log.log(t_end, Level::Warning, &line).err());
    }
    // What the thrusters delivered of what was asked (from SERVO_OUTPUT_RAW): a wrong pilot
    // gain or thruster table shows here as a ratio away from 1.
    let mut ratios = serde_json::Map::new();
    for (j, name) in crate::types::INPUT_NAMES.iter().enumerate() {
        let (num, den, count) = delivered[j];
        let ratio = (count >= 20 && den > 0.0).then(|| num / den);
        if let Some(r) = ratio
            && (r - 1.0).abs() > 0.25
        {
            let line = format!(
                "the thrusters delivered {r:.2} of the commanded {name} over {count} samples (SERVO_OUTPUT_RAW \
                 through the vehicle file): check the pilot gain ({js_gain}) against the autopilot's and the vehicle \
                 file's thrusters"
            );
            eprintln!("{line}");
            log_error = log_error.or(log.log(t_end, Level::Warning, &line).err());
        }
        ratios.insert(name.to_string(), json!(ratio));
    }
    // What the innovations said of the model, in words an owner acts on.
    let health: Health = each!(&estimator, tr => *tr.ekf().health());
    let misfits = if o.estimator.no_estimator { Vec::new() } else { health.misfits() };
    for line in &misfits {
        eprintln!("{line}");
        log_error = log_error.or(log.log(t_end, Level::Warning, line).err());
    }
    let counts = each!(&estimator, tr => (tr.counts(), tr.late(), tr.restarts()));
    let errors = errors_against_truth(&estimates, &all_truths);
    let names = ["u", "v", "w", "r", "z"];
    let estimate_rms: serde_json::Map<String, Value> =
        names.iter().zip(&errors).map(|(n, e)| (n.to_string(), json!(rms(e)))).collect();
    // The tracking against the truth: depth, the truth's heading (true north) and the raw
    // depth sensor beside the estimate.
    let (mut depth_err, mut heading_err, mut raw_depth_err) = (Vec::new(), Vec::new(), Vec::new());
    for s in &samples {
        let Some(start) = t0 else { break };
        if let Some(tr) = truth_at(&all_truths, s.t + start) {
            depth_err.push(tr.z - s.reference.depth);
            heading_err.push(crate::vehicle::wrap_angle(tr.psi - s.reference.heading).to_degrees());
        }
    }
    for &(t, z) in &raw_depths {
        if let Some(tr) = truth_at(&all_truths, t) {
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
    let live = json!({
        "flown_by": hold.map_or("pinc", AutopilotHold::name),
        "hold_mode_entered_s": mode_entered,
        "estimator": if o.estimator.no_estimator { Value::Null } else { json!(o.estimator.estimator_model) },
        "control_started_after_arming_s": control_after,
        "state_age_ms": percentiles_ms(&mut ages),
        "latency_ms": percentiles_ms(&mut latencies),
        "estimate_rms_error": estimate_rms,
        "truth_samples": errors[0].len(),
        "truth_rms": {"depth_m": rms(&depth_err), "heading_deg": rms(&heading_err), "samples": depth_err.len()},
        "raw_depth_rms_error": rms(&raw_depth_err),
        "delivered_to_commanded": ratios,
        "js_gain": js_gain,
        "heading_reference": heading_reference.map(|h| h.key()),
        "heading_reference_text": heading_reference.map(|h| h.describe()),
        "autopilot_not_ready": not_ready_said,
        "dead_reckoned_left_out": dead_reckoned,
        "vertical_velocity": {"taken": vertical_velocities,
            "left_out_ekf_not_ready": drive.assembler().reader().vertical_velocity_left_out()},
        "estimator_health": sensors,
        "process_noise_scale": each!(&estimator, tr => tr.ekf().process_scale()),
        "model_misfits": misfits,
        "fused": counts.0.fused, "rejected": counts.0.rejected, "reacquired": counts.0.reacquired, "late": counts.1, "restarts": counts.2,
        "disarm_sent": stopped.disarm_sent,
        "stop_trigger": stopped.trigger.as_ref().map(|t| t.key()),
        "stop_autopilot_s": stopped.trigger.as_ref().map(|_| stopped.t),
        "neutral_autopilot_s": stopped.neutral_t,
    });
    Ok(LiveRun { samples, log_error, stopped: reason, live: Some(live) })
}
