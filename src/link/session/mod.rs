//! The live session: references flown on a vehicle over MAVLink, by pinc's MPC or by the
//! autopilot's own depth and heading hold, with one home for everything around the loop:
//! connect, check the autopilot's configuration, arm (each refusal printed), wait until the
//! autopilot's own estimate is usable, estimate the state, command, every safety stop, the
//! MCAP log (the same schema for both controllers, so one summary, plot and table compare
//! them) and the summary's live figures. `mpc_track --connect` runs it.
//!
//! The stages, each in its own place: the set-up (thrusters and command way, limits, the
//! estimator's noise and model: `Setup`), the link and the session's first log lines
//! (`connect`), arming and the autopilot's readiness (the drive's start, then
//! `Flight::wait_to_start`), every cycle's measurements, estimate and command (module
//! `flight`), the stop and the summary's figures (module `summary`).

use super::cli::{DriveArgs, EstimatorArgs, LinkOptions, non_negative, open};
use super::command::CommandWay;
use super::drive::Drive;
use super::link::{Received, SubMode};
use crate::closed_loop::{LogError, McapLog, Sample, Scenario};
use crate::estimation::Estimator;
use crate::mpc::Mpc;
use crate::traits::DiscreteModel;
use crate::vehicle::{Rk4Vehicle, Thrusters, VehicleParams};
use mavlink::dialects::ardupilotmega::MavMessage;
use serde_json::Value;
use std::cell::RefCell;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// `SERVO_OUTPUT_RAW`, whose outputs are the input the estimator is driven by.
const SERVO_OUTPUT_RAW_ID: u32 = 36;
/// `SIM_STATE`: the simulator's truth.
const SIM_STATE_ID: u32 = 108;
/// `SIMSTATE`: the simulator's truth, its position in integers of 1e-7 deg.
const SIMSTATE_ID: u32 = 164;
/// The estimator's position (m) and NED velocity (m/s) standard deviations where the
/// references have a horizontal goal, unless given.
pub const HORIZONTAL_GOAL_POSITION_STD: f64 = 0.02;
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
    /// POSHOLD: the position it entered at held by the autopilot (needs a position source);
    /// depth and heading targets are sent as for ALT_HOLD, and ArduSub ignores them there.
    PosHold,
}

impl AutopilotHold {
    /// `althold` or `guided`.
    pub fn name(self) -> &'static str {
        match self {
            AutopilotHold::AltHold => "althold",
            AutopilotHold::Guided => "guided",
            AutopilotHold::PosHold => "poshold",
        }
    }

    fn mode(self) -> SubMode {
        match self {
            AutopilotHold::AltHold => SubMode::AltHold,
            AutopilotHold::Guided => SubMode::Guided,
            AutopilotHold::PosHold => SubMode::PosHold,
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
    /// The farthest the vehicle may go from where control starts (m), with a position source.
    pub max_distance: Option<f64>,
    /// One JSON line per control cycle on stdout (the time, depth, heading and position with
    /// their references): what `pinc serve` plots live.
    pub stream_samples: bool,
    /// The figures of a longer flight are those of its last this many seconds (the log holds
    /// it all): an hour's dive keeps its memory flat.
    pub history_s: f64,
    /// Fly the pilot's sticks instead of the scenario's references (pinc's MPC), or pass them
    /// to the autopilot's POSHOLD or ALT_HOLD.
    pub pilot: Option<&'a PilotOptions>,
    /// A scenario held from where it starts holds this instead (`--hold-at`).
    pub hold_at: Option<HoldAt>,
}

/// Where "hold here" was pressed: the depth (m), heading (rad) and, where a position was known,
/// north and east (m, the autopilot's local frame) the vehicle had then.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HoldAt {
    /// Depth (m).
    pub depth: f64,
    /// Heading (rad).
    pub heading: f64,
    /// North and east (m), where a position was known.
    pub north_east: Option<(f64, f64)>,
}

/// Where the pilot's sticks come from and what full deflection asks for.
#[derive(Debug, Clone, PartialEq)]
pub struct PilotOptions {
    /// A file or named pipe of one JSON object per line; `-` for stdin; a ground station's
    /// joystick, `mavlink:SYSID` or a mavlink2rest address (its `MANUAL_CONTROL`, as
    /// `session::joystick` reads it).
    pub source: String,
    /// Caps on full deflection: surge, sway, heave (m/s), yaw rate (rad/s); `None` leaves
    /// [`StickLimits::of_model`](crate::pilot::StickLimits::of_model)'s share of the model's
    /// steady speed.
    pub speeds: [Option<f64>; 4],
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
    /// The navigation against a simulator's truth, for its plot (with `--sim-truth`).
    pub navigation: Option<NavigationTrack>,
}

/// The process model of the estimator.
pub(super) enum EstimatorModel<M> {
    Controller(M),
    Vehicle(Rk4Vehicle),
}

/// Either model behind one estimator type.
pub(super) enum AnyEstimator<M: DiscreteModel> {
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

pub use flight::DEFAULT_HISTORY_S;
pub use joystick::ground_station_of;
pub use navigation_plot::NavigationTrack;

// After the macro: the stages use it.
/// A stick reading as it arrived (pinc's clock), from any of the pilot feed's sources: the
/// feed's own reader or a ground station's joystick.
type Arrived = (std::time::Instant, Result<crate::pilot::Sticks, crate::pilot::StickError>);

mod flight;
mod joystick;
mod navigation_plot;
mod noise_window;
mod pilot_feed;
mod summary;
mod targets;
mod truth;

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
    // First: a hand-back asked while the link opens must not end the process (SIGUSR1's default).
    let hand_back = hand_back_flag()?;
    let setup = Setup::new(&flyer, o, scenario.horizontal.is_some())?;
    // Refused before the link opens (a hold that ignores sticks, a model that fails).
    let mut pilot = pilot_feed(&flyer, o)?;
    let (link, autopilot, mut assembler) = connect(o)?;
    assembler.set_fix_latency(o.estimator.fix_latency);
    let mut flight = flight::Flight::new(&setup, log);
    flight.say_start(o, &setup, &autopilot);
    let truths: RefCell<truth::Feed> = RefCell::new(truth::Feed::default());
    let joystick = RefCell::new(pilot.as_mut().and_then(|p| p.joystick_tap(autopilot.system_id)));
    let seen = |r: &Received, t: f64| match &r.message {
        MavMessage::SIM_STATE(s) => truths.borrow_mut().states.push(truth::truth_of(t, s)),
        MavMessage::SIMSTATE(s) => truths.borrow_mut().positions.push(truth::position_of(t, s)),
        MavMessage::MANUAL_CONTROL(_) => {
            if let Some(tap) = joystick.borrow_mut().as_mut() {
                tap.see(r);
            }
        }
        _ => {}
    };
    let stop = ctrl_c_flag()?;
    flight.hand_back = Some(hand_back);
    let Setup { commander, settings, estimator_model, noise, dead_reckoning_bound, .. } = setup;
    let mut drive = match Drive::start(link, autopilot, assembler, commander, settings, stop, seen) {
        Ok(d) => d,
        Err(stopped) => return Ok(flight.refused(stopped)),
    };
    let mut estimator = match estimator_model {
        EstimatorModel::Controller(m) => {
            AnyEstimator::Controller(Estimator::new(m, noise).with_dead_reckoning_bound(dead_reckoning_bound))
        }
        EstimatorModel::Vehicle(v) => {
            AnyEstimator::<M>::Vehicle(Estimator::new(v, noise).with_dead_reckoning_bound(dead_reckoning_bound))
        }
    };
    // The DVL's mounting where the owner measured it; the rest stays estimated.
    let (yaw, scale) = (o.estimator.dvl_yaw_deg, o.estimator.dvl_scale);
    if yaw.is_some() || scale.is_some() {
        let e = each!(&estimator, tr => tr.ekf().estimate());
        let (yaw, yaw_std) = yaw.map_or(e.dvl_yaw, |d| (d.to_radians(), 0.0));
        let (scale, scale_std) = scale.map_or(e.dvl_scale, |k| (k - 1.0, 0.0));
        each!(&mut estimator, tr => tr.set_dvl_mounting(yaw, yaw_std, scale, scale_std));
    }
    let outcome = flight.fly(&mut drive, &mut estimator, &mut flyer, scenario, pilot.as_mut(), o, &truths, seen);
    Ok(summary::end(flight, drive, outcome, &estimator, o))
}

/// What a session is set up with before the link opens: every option checked, nothing sent.
struct Setup<M> {
    /// The command way, the vehicle's thrusters and the pilot gain.
    commander: super::command::Commander,
    settings: super::drive::DriveSettings,
    /// The autopilot's own controller, if it flies.
    hold: Option<AutopilotHold>,
    /// How long to wait (neutral) for a position source; and for a state at all.
    wait_position: Duration,
    give_up: Duration,
    noise: crate::estimation::NoiseSettings,
    estimator_model: EstimatorModel<M>,
    dt: f64,
    position_free: bool,
    max_distance: Option<f64>,
    /// The dead reckoning's bound (m): `--dead-reckoning-bound`.
    dead_reckoning_bound: f64,
    stream_samples: bool,
    history_s: f64,
}

impl<M: DiscreteModel + Clone> Setup<M> {
    fn new(flyer: &Flyer<M>, o: &SessionOptions, horizontal_goal: bool) -> Result<Self, String> {
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
                return Err("--connect needs --vehicle V.toml with the vehicle's [[thruster]] tables, or a model \
                            fitted by `pinc fit` (it carries them)"
                    .into());
            }
        };
        let hold = match flyer {
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
        let mut settings = drive_args.settings()?;
        // A ground station's joystick as the sticks: pinc takes that station's place as the one
        // whose pilot axes the autopilot obeys, so exactly one source commands the thrusters.
        if let Some(p) = o.pilot
            && let Some(ground) = ground_station_of(&p.source)?
        {
            settings.replaces_ground_station = Some(ground);
        }
        let wait_position = non_negative("--wait-position", o.drive.wait_position)?;
        // How long to wait (neutral) for a state to control on: --wait-position, else 30 s.
        let give_up = if wait_position.is_zero() { Duration::from_secs(30) } else { wait_position };
        let mut noise = o.estimator.noise(o.fitted.map(|f| &f.sensors))?;
        // Holding a point, the estimate follows the autopilot's position closely: its default
        // 0.3 m (a GPS at the surface) let the estimate lag a vehicle the current pushes (12.6
        // cm RMS against the truth on the firmware's station, 5.8 cm with 0.02; the position
        // itself is 5.0 cm from the truth there).
        if horizontal_goal {
            noise.position_std = o.estimator.position_std.unwrap_or(HORIZONTAL_GOAL_POSITION_STD);
            noise.velocity_ned_std = o.estimator.velocity_ned_std.unwrap_or(HORIZONTAL_GOAL_POSITION_STD);
        }
        let model = flyer.model().clone();
        let (dt, position_free) = (model.dt(), model.position_free());
        let estimator_model = match o.estimator.estimator_model.as_str() {
            "vehicle" => {
                let file = o.vehicle.ok_or("--estimator-model vehicle needs --vehicle V.toml")?;
                let params = VehicleParams::load(file).map_err(|e| e.to_string())?;
                EstimatorModel::Vehicle(Rk4Vehicle { params, ..Rk4Vehicle::with_dt(dt) })
            }
            _ => EstimatorModel::Controller(model),
        };
        if let Some(d) = o.max_distance
            && !(d.is_finite() && d > 0.0)
        {
            return Err(format!("--max-distance must be a positive number of metres, got {d}"));
        }
        if !(o.history_s.is_finite() && o.history_s >= 10.0) {
            return Err(format!("--history must be at least 10 s, got {}", o.history_s));
        }
        Ok(Self {
            commander,
            settings,
            hold,
            wait_position,
            give_up,
            noise,
            estimator_model,
            dt,
            position_free,
            max_distance: o.max_distance,
            dead_reckoning_bound: o.estimator.dead_reckoning_bound,
            stream_samples: o.stream_samples,
            history_s: o.history_s,
        })
    }
}

/// The pilot's sticks' reader and assist, with `--pilot`: full deflection from the MPC's model
/// and bounds, the depth reference within the surface and `--max-depth`.
fn pilot_feed<M: DiscreteModel>(flyer: &Flyer<M>, o: &SessionOptions) -> Result<Option<pilot_feed::PilotFeed>, String> {
    let Some(p) = o.pilot else { return Ok(None) };
    let mpc = match flyer {
        Flyer::Mpc(mpc) => mpc,
        // The autopilot's holds that take a pilot: the sticks go to it as its pilot axes.
        Flyer::Autopilot { hold: hold @ (AutopilotHold::PosHold | AutopilotHold::AltHold), .. } => {
            let any = crate::pilot::StickLimits { surge: 1.0, sway: 1.0, heave: 1.0, yaw_rate: 1.0 };
            eprintln!("pilot: the sticks go to the autopilot's {} as MANUAL_CONTROL", hold.name());
            return pilot_feed::PilotFeed::open(&p.source, crate::pilot::PilotAssist::new(any, (0.0, 0.0))).map(Some);
        }
        Flyer::Autopilot { hold, .. } => {
            return Err(format!("--pilot: the autopilot's {} ignores the pilot's sticks", hold.name()));
        }
    };
    let limits = crate::pilot::StickLimits::of_model(mpc.model(), mpc.bounds(), p.speeds)?;
    let band = (0.0, o.drive.max_depth.unwrap_or(f64::INFINITY));
    let still: Vec<&str> =
        crate::pilot::AXES.into_iter().zip(limits.axes()).filter(|(_, l)| *l == 0.0).map(|(a, _)| a).collect();
    if !still.is_empty() {
        eprintln!("pilot assist: the model cannot move in {}: those sticks ask for nothing", still.join(", "));
    }
    eprintln!(
        "pilot assist: full sticks ask for {:.2} m/s surge, {:.2} m/s sway, {:.2} m/s heave, {:.1} deg/s yaw; \
         centred sticks hold where the vehicle comes to rest; none for {} s counts as centred",
        limits.surge,
        limits.sway,
        limits.heave,
        limits.yaw_rate.to_degrees(),
        crate::pilot::DEADMAN_S
    );
    pilot_feed::PilotFeed::open(&p.source, crate::pilot::PilotAssist::new(limits, band)).map(Some)
}

/// Ctrl-C stops the session (with neutral and the disarm it owes).
fn ctrl_c_flag() -> Result<Arc<AtomicBool>, String> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed)).map_err(|e| format!("cannot catch Ctrl-C: {e}"))?;
    Ok(stop)
}

/// SIGUSR1 ends the flight by handing the vehicle back as the pilot had it (`pinc serve`'s
/// "resume", a hold or pilot assist ended without STOP): [`Drive::hand_back`].
fn hand_back_flag() -> Result<Arc<AtomicBool>, String> {
    let flag = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGUSR1, flag.clone())
        .map_err(|e| format!("cannot catch SIGUSR1: {e}"))?;
    Ok(flag)
}

/// The link to the autopilot, with the outputs (and the simulator's truth, if asked) streamed.
fn connect(
    o: &SessionOptions,
) -> Result<(super::link::VehicleLink, super::link::Autopilot, super::state::StateAssembler), String> {
    let (link, autopilot, assembler) = open(o.connect, o.link, |_| {})?;
    link.set_message_rate(SERVO_OUTPUT_RAW_ID, o.drive.outputs_rate).map_err(|e| e.to_string())?;
    if o.estimator.sim_truth {
        link.set_message_rate(SIM_STATE_ID, o.link.rate).map_err(|e| e.to_string())?;
        link.set_message_rate(SIMSTATE_ID, o.link.rate).map_err(|e| e.to_string())?;
    }
    Ok((link, autopilot, assembler))
}
