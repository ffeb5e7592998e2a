//! Closed-loop depth and heading tracking: the LTV-MPC on the frozen PINC (or, with
//! `--oracle`, on the analytic model) against the simulated BlueROV2.
//!
//! ```sh
//! cargo run --release --bin mpc_track                       # PINC-MPC, scenario default
//! cargo run --release --bin mpc_track -- --oracle --scenario disturbed --json
//! cargo run --release --bin mpc_track -- --reference examples/references/zigzag.csv
//! ```
//!
//! Prints a summary table (or `--json`) and writes a PNG of the run and its MCAP log (open it
//! in Foxglove) to `--out-dir`.
//!
//! With `--connect URL --vehicle V.toml` the plant is a live ArduSub vehicle instead
//! (docs/VEHICLE.md): one MPC cycle per fresh state, the wrench sent as commands, every
//! safety trigger stopping the run with the neutral command. That needs the `vehicle` feature
//! (`cargo run --release --features vehicle --bin mpc_track -- --connect URL ...`), `--foxglove`
//! the `live-view` feature; the default build leaves both out.

use clap::{Parser, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use pinc::Input;
use pinc::closed_loop::campaign::{Campaign, Controller, Settings, histogram, table};
use pinc::closed_loop::monte_carlo::Outcome;
use pinc::closed_loop::path_plan::PathFrame;
use pinc::closed_loop::{LogError, McapLog, RunInfo};
use pinc::closed_loop::{Sample, Scenario, Summary, run, summarise};
use pinc::mpc::{Mpc, MpcConfig, QpSolver};
use pinc::plot::{Panel, Series, figure};
use pinc::runtime::Predictor;
use pinc::traits::DiscreteModel;
use pinc::vehicle::{Rk4Vehicle, VehicleParams};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

#[derive(Parser)]
#[command(about = "Closed-loop depth and heading tracking with the LTV-MPC")]
struct Args {
    /// The frozen model inside the MPC (its training envelope bounds the inputs) [default: the
    /// built-in models/mpc_pinc_thrust.pinc, whose bytes are in this binary, so an installed
    /// mpc_track finds it wherever it runs; written to OUT_DIR/built_in_mpc_pinc_thrust.pinc for
    /// the run's log, which names and hashes that file].
    #[arg(long, value_name = "M.pinc")]
    model: Option<PathBuf>,
    /// Run the identical controller on the analytic vehicle model instead (bounds still from --model).
    #[arg(long)]
    oracle: bool,
    /// Which built-in scenario: depth and heading (`default`, `disturbed`), or on four axes
    /// in a 0.3 m/s current (`station`: hold where control starts through a depth step and a
    /// 45 deg turn; `hold`: hold the point, depth and heading where control starts, an hour
    /// unless --duration says (on a vehicle: its estimate's at the first cycle); `survey`: 4
    /// legs of 10 m, 2 m apart, 0.3 m/s, 2 m deep).
    #[arg(long, value_enum, default_value = "default", conflicts_with_all = ["reference", "path", "survey"])]
    scenario: ScenarioName,
    /// Follow a path: a CSV of waypoints with header north_m,east_m,depth_m and t (s) or
    /// speed_m_s (the leg's speed), optionally heading_deg (empty: along the leg).
    #[arg(long, value_name = "FILE", conflicts_with_all = ["reference", "survey"])]
    path: Option<PathBuf>,
    /// What the path's metres are measured from: `start` (where control starts) or `origin`
    /// (the autopilot's EKF origin, LOCAL_POSITION_NED's frame; the simulator starts there).
    #[arg(long, value_enum, default_value = "start")]
    path_frame: PathFrameArg,
    /// A lawnmower survey from the start: WIDTH,LENGTH,SPACING,SPEED,DEPTH (m, m, m, m/s, m):
    /// legs of LENGTH northwards and back, SPACING apart, across WIDTH eastwards.
    #[arg(long, value_name = "W,L,S,V,D", value_delimiter = ',', conflicts_with = "reference")]
    survey: Option<Vec<f64>>,
    /// The survey's heading (deg) [default: along each leg].
    #[arg(long, value_name = "DEG")]
    path_heading: Option<f64>,
    /// Water velocity NORTH,EAST (m/s) of the simulated plant [default: the scenario's; a path
    /// or survey: 0.3 m/s towards 30 deg].
    #[arg(long, value_name = "N,E", value_delimiter = ',', allow_hyphen_values = true)]
    current: Option<Vec<f64>>,
    /// The farthest the vehicle may go from where control starts (m): a path reaching past it
    /// is refused before anything moves; on a vehicle, crossing it stops the run (neutral,
    /// disarm, exit 1).
    #[arg(long, value_name = "M")]
    max_distance: Option<f64>,
    /// References from a CSV file with header t,depth_m,heading_deg (linear between rows, a
    /// step where two rows share a time, held after the last; examples/references/).
    #[arg(long)]
    reference: Option<PathBuf>,
    /// Length of the run (s) [default: the scenario's; a reference file's last time].
    #[arg(long)]
    duration: Option<f64>,
    /// Prediction horizon (samples).
    #[arg(long, default_value_t = 20)]
    horizon: usize,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
    /// Where the plot and the MCAP log go.
    #[arg(long, default_value = "out")]
    out_dir: PathBuf,
    /// Gain of the disturbance estimate (0: no offset-free action).
    #[arg(long, default_value_t = MpcConfig::default().disturbance_gain)]
    disturbance_gain: f64,
    /// Leave the predicted velocities unconstrained by the model's training envelope.
    #[arg(long)]
    no_envelope_constraints: bool,
    /// Linear penalty per unit of envelope slack.
    #[arg(long, default_value_t = MpcConfig::default().envelope_penalty)]
    envelope_penalty: f64,
    /// Fraction of each velocity range the envelope bounds sit inside the envelope.
    #[arg(long, default_value_t = MpcConfig::default().envelope_margin)]
    envelope_margin: f64,
    /// Weights on input changes between samples, X,Y,Z,Mz [default: MpcConfig's].
    #[arg(long, value_delimiter = ',')]
    input_rate: Option<Vec<f64>>,
    /// Wall-clock limit of one QP solve, s [default: MpcConfig's]; a solve that hits it falls
    /// back, so raise it where runs must repeat exactly on a loaded machine.
    #[arg(long)]
    solver_time_limit: Option<f64>,
    /// Steps per condensed block of the QP: only every N-th predicted state stays a variable
    /// (1: the sparse form, every state a variable) [default: MpcConfig's].
    #[arg(long, value_name = "N")]
    condensing_block: Option<usize>,
    /// Solve the QP as before partial condensing (every state a variable, tolerance 1e-5,
    /// equilibration and refinement on), for comparison.
    #[arg(long, conflicts_with = "condensing_block")]
    sparse_qp: bool,
    /// The QP solver of every cycle: `riccati` (the interior-point method built for this QP, a
    /// Riccati recursion per step; 3x faster) or `clarabel` (the general conic solver, the
    /// reference) [default: riccati; clarabel with --sparse-qp].
    #[arg(long, value_name = "NAME")]
    qp: Option<QpSolver>,
    /// Run N closed loops on perturbed plants (damping and added masses +-20 %, net buoyancy
    /// +-30 %, a current up to 0.2 m/s, sensor noise) for both controllers on the same draws,
    /// and summarise them instead of one run.
    #[arg(long, value_name = "N")]
    monte_carlo: Option<usize>,
    /// First seed of the Monte-Carlo draws (run i uses seed + i).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Threads for the Monte-Carlo runs [default: every core].
    #[arg(long)]
    jobs: Option<usize>,
    /// Vehicle file of the plant, and of the oracle's model (the oracle knows the plant)
    /// [default: the BlueROV2]; with --connect, its [[thruster]] tables turn the wrench into
    /// commands (a model fitted by `pinc fit` carries its vehicle's: no file needed).
    #[arg(long)]
    vehicle: Option<PathBuf>,
    /// Run on a live ArduSub vehicle at this MAVLink address (udpin:HOST:PORT, udpout:...,
    /// tcp:..., serial) instead of the simulator; the link and safety options below apply.
    #[cfg(feature = "vehicle")]
    #[arg(long)]
    connect: Option<String>,
    #[cfg(feature = "vehicle")]
    #[command(flatten)]
    link: pinc::link::cli::LinkOptions,
    #[cfg(feature = "vehicle")]
    #[command(flatten)]
    drive: pinc::link::cli::DriveArgs,
    #[cfg(feature = "vehicle")]
    #[command(flatten)]
    estimator: pinc::link::cli::EstimatorArgs,
    /// With --connect: fly the same references with the autopilot's own controller instead of
    /// pinc's MPC (ALT_HOLD: depth and heading targets; GUIDED: position, velocity, depth and
    /// heading streamed; POSHOLD: holds where it entered, depth and heading targets; both need
    /// a position source), logged in the same schema for the same summary and plot.
    #[cfg(feature = "vehicle")]
    #[arg(long, value_parser = ["althold", "guided", "poshold"], requires = "connect")]
    autopilot_hold: Option<String>,
    /// With --connect: print one JSON line per control cycle on stdout (time, depth, heading,
    /// position and their references), as `pinc serve` reads them.
    #[cfg(feature = "vehicle")]
    #[arg(long, requires = "connect")]
    stream_samples: bool,
    /// With --connect: the figures of a longer flight are those of its last S seconds (the log
    /// holds it all), so that an hour of pilot assist keeps its memory flat.
    #[cfg(feature = "vehicle")]
    #[arg(long, value_name = "S", default_value_t = pinc::link::session::DEFAULT_HISTORY_S, requires = "connect")]
    history: f64,
    /// With --connect: fly the pilot's sticks instead of the scenario's references: one JSON
    /// object per line {"surge","sway","heave","yaw"} (each -1..1: forward, starboard, down, a
    /// turn to starboard) from this file, `-` for stdin (docs/PILOT.md); `mavlink:SYSID`: the
    /// joystick of the ground station with that system id (Cockpit: 255), read from the
    /// MANUAL_CONTROL it sends the autopilot, whose SYSID_MYGCS pinc sets to its own
    /// --gcs-sysid for the flight (so the autopilot ignores that joystick) and back at every
    /// stop. On four axes (the station's set-up) wherever a position is known; centred sticks
    /// hold where the vehicle comes to rest; none for 0.5 s counts as centred. Runs --duration
    /// s [default: 3600]. With --autopilot-hold poshold or althold the sticks go to the
    /// autopilot instead.
    #[cfg(feature = "vehicle")]
    #[arg(long, value_name = "FILE|-|mavlink:SYSID", requires = "connect",
          conflicts_with_all = ["reference", "path", "survey"])]
    pilot: Option<String>,
    /// What full sticks ask for: SURGE,SWAY,HEAVE (m/s),YAW (deg/s), each up to the model's
    /// steady speed at full thrust [default: 0.8 of it].
    #[cfg(feature = "vehicle")]
    #[arg(long, value_name = "U,V,W,R", value_delimiter = ',', requires = "pilot")]
    pilot_speeds: Option<Vec<f64>>,
    /// With --connect --scenario hold: hold this depth (m) and heading (deg), and the position
    /// NORTH,EAST (m, the autopilot's local frame) where one is given, instead of where control
    /// starts: where the vehicle was when the pilot pressed "hold here" (`pinc serve` passes it).
    #[cfg(feature = "vehicle")]
    #[arg(long, value_name = "DEPTH,HEADING[,NORTH,EAST]", value_delimiter = ',', allow_hyphen_values = true)]
    hold_at: Option<Vec<f64>>,
    /// Serve the run live over Foxglove's WebSocket protocol at [HOST:]PORT (loopback unless a
    /// host is given; port 0 picks a free one): the MCAP log's topics as they are written, to
    /// open in Foxglove without a file. A simulated run then goes in real time.
    #[cfg(feature = "live-view")]
    #[arg(long, value_name = "[HOST:]PORT")]
    foxglove: Option<String>,
}

/// The model `mpc_track` flies when `--model` is not given: `models/mpc_pinc_thrust.pinc`, built
/// into the binary so that an installed `mpc_track` finds it outside a checkout.
const BUILT_IN_MODEL: &[u8] = include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/models/mpc_pinc_thrust.pinc"));

/// Where the built-in model is written in `--out-dir`: the library loads a model and hashes it
/// for the log by its path, so the run names a file that holds exactly what it flew.
const BUILT_IN_MODEL_FILE: &str = "built_in_mpc_pinc_thrust.pinc";

/// Why the built-in model could not be put where the run reads it.
#[derive(Debug, thiserror::Error)]
enum BuiltInModelError {
    /// The output folder could not be made.
    #[error("{path}: cannot create the output folder for the built-in model: {source}")]
    Folder {
        /// The folder.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The model's bytes could not be written.
    #[error("{path}: cannot write the built-in model (give --model M.pinc or another --out-dir): {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

/// The model the run flies: `--model`'s file, or the built-in model written to `out_dir` (left
/// alone when it already holds the same bytes; otherwise written beside it and renamed over it,
/// so a reader never sees half a file).
fn model_file(given: Option<&Path>, out_dir: &Path) -> Result<(PathBuf, bool), BuiltInModelError> {
    if let Some(path) = given {
        return Ok((path.to_owned(), false));
    }
    std::fs::create_dir_all(out_dir)
        .map_err(|source| BuiltInModelError::Folder { path: out_dir.to_owned(), source })?;
    let path = out_dir.join(BUILT_IN_MODEL_FILE);
    if std::fs::read(&path).is_ok_and(|bytes| bytes == BUILT_IN_MODEL) {
        return Ok((path, true));
    }
    let partial = out_dir.join(format!("{BUILT_IN_MODEL_FILE}.{}.partial", std::process::id()));
    let written = std::fs::write(&partial, BUILT_IN_MODEL).and_then(|()| std::fs::rename(&partial, &path));
    if let Err(source) = written {
        let _ = std::fs::remove_file(&partial);
        return Err(BuiltInModelError::Write { path, source });
    }
    Ok((path, true))
}

/// A run's samples, a log write error, why it stopped early, and (on a vehicle) the live figures.
type RunOutcome = (Vec<Sample>, Option<LogError>, Option<String>, Option<serde_json::Value>);

#[derive(Clone, Copy, ValueEnum)]
enum ScenarioName {
    Default,
    Disturbed,
    Station,
    Hold,
    Survey,
}

#[derive(Clone, Copy, ValueEnum)]
enum PathFrameArg {
    Start,
    Origin,
}

fn main() -> ExitCode {
    pinc::broken_pipe::exit_quietly_on_broken_pipe();
    if let Some(e) = left_out_flag() {
        eprintln!("error: {e}");
        return ExitCode::from(2);
    }
    match try_main(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if pinc::broken_pipe::is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}

/// A flag of a feature this build left out, with the command that builds it in (clap would
/// only say that the flag is unknown).
fn left_out_flag() -> Option<String> {
    let flags =
        [("--connect", "vehicle", cfg!(feature = "vehicle")), ("--foxglove", "live-view", cfg!(feature = "live-view"))];
    let given = |flag: &str| {
        let given_as = |a: &str| a == flag || a.strip_prefix(flag).is_some_and(|rest| rest.starts_with('='));
        std::env::args_os().skip(1).any(|a| a.to_str().is_some_and(given_as))
    };
    let (flag, feature, _) = flags.into_iter().find(|&(flag, _, built)| !built && given(flag))?;
    Some(format!(
        "{flag} needs the `{feature}` feature, which this build left out: \
         cargo run --release --features {feature} --bin mpc_track -- {flag} ..."
    ))
}

/// How long `--pilot` flies unless `--duration` says (s).
#[cfg(feature = "vehicle")]
const PILOT_DURATION_S: f64 = 3600.0;

/// The closed loop's settings from the flags: the controller and scenario come from the
/// library's one set-up path (shared with the Python package, so a seed's run is the same
/// everywhere).
fn settings(a: &Args, model: &Path) -> Result<Settings, String> {
    // The pilot's sticks fly on the station's four-axis set-up, an hour unless told.
    #[cfg(feature = "vehicle")]
    let (scenario, duration) = match a.pilot {
        Some(_) => (ScenarioName::Station, a.duration.or(Some(PILOT_DURATION_S))),
        None => (a.scenario, a.duration),
    };
    #[cfg(not(feature = "vehicle"))]
    let (scenario, duration) = (a.scenario, a.duration);
    Ok(Settings {
        model: model.to_owned(),
        vehicle: a.vehicle.clone(),
        scenario: match scenario {
            ScenarioName::Default => "default",
            ScenarioName::Disturbed => "disturbed",
            ScenarioName::Station => "station",
            ScenarioName::Hold => "hold",
            ScenarioName::Survey => "survey",
        }
        .into(),
        reference: a.reference.clone(),
        path: a.path.clone(),
        path_frame: match a.path_frame {
            PathFrameArg::Start => PathFrame::Start,
            PathFrameArg::Origin => PathFrame::Origin,
        },
        survey: match &a.survey {
            Some(v) => Some(
                v.clone()
                    .try_into()
                    .map_err(|_| "--survey: five numbers WIDTH,LENGTH,SPACING,SPEED,DEPTH".to_string())?,
            ),
            None => None,
        },
        path_heading: a.path_heading,
        current: match &a.current {
            Some(v) => Some(v.clone().try_into().map_err(|_| "--current: two speeds NORTH,EAST (m/s)".to_string())?),
            None => None,
        },
        max_distance: a.max_distance,
        duration,
        horizon: a.horizon,
        disturbance_gain: a.disturbance_gain,
        envelope_constraints: !a.no_envelope_constraints,
        envelope_penalty: a.envelope_penalty,
        envelope_margin: a.envelope_margin,
        input_rate: match &a.input_rate {
            Some(v) => Some(v.clone().try_into().map_err(|_| "--input-rate: four weights X,Y,Z,Mz".to_string())?),
            None => None,
        },
        solver_time_limit: a.solver_time_limit,
        condensing_block: a.condensing_block,
        sparse_qp: a.sparse_qp,
        qp: a.qp,
    })
}

/// Who flies: `oracle`, `pinc` or the autopilot's hold.
fn controller_name(a: &Args) -> &str {
    let controller = if a.oracle { "oracle" } else { "pinc" };
    #[cfg(feature = "vehicle")]
    let controller = a.autopilot_hold.as_deref().unwrap_or(controller);
    controller
}

/// The run's files' name: `mpc_<scenario>_<controller>`.
fn run_name(a: &Args, scenario: &Scenario) -> String {
    format!("mpc_{}_{}", scenario.name(), controller_name(a))
}

fn try_main(a: Args) -> Result<(), String> {
    let (model_path, built_in) = model_file(a.model.as_deref(), &a.out_dir).map_err(|e| e.to_string())?;
    let settings = settings(&a, &model_path)?;
    let campaign = Campaign::new(&settings).map_err(|e| e.to_string())?;
    // Said once the inputs are read: bad input stays a one-line error.
    if built_in && !a.json {
        eprintln!(
            "model: the built-in models/mpc_pinc_thrust.pinc (no --model given), written to {}",
            model_path.display()
        );
    }
    let Campaign { model, vehicle, scenario, config: cfg, bounds } = &campaign;
    let (model, vehicle, scenario, cfg, bounds) = (model, *vehicle, scenario, cfg.clone(), *bounds);
    let predictor = Predictor::reference(model);
    std::fs::create_dir_all(&a.out_dir).map_err(|e| format!("{}: {e}", a.out_dir.display()))?;
    if let Some(n) = a.monte_carlo {
        return monte_carlo(&a, n, &campaign);
    }
    let controller = controller_name(&a);
    let name = run_name(&a, scenario);
    let png = a.out_dir.join(format!("{name}.png"));
    let mcap = a.out_dir.join(format!("{name}.mcap"));
    let info = RunInfo {
        controller,
        model_path: &model_path,
        scenario,
        config: &cfg,
        bounds,
        dt: model.dt,
        vehicle: &vehicle,
    };
    #[cfg(feature = "live-view")]
    let mut log = match &a.foxglove {
        Some(address) => {
            let view = pinc::closed_loop::live_view::LiveView::start(address).map_err(|e| e.to_string())?;
            // Scripts (and the tests) read the port from this line.
            eprintln!("live view: ws://127.0.0.1:{} (open it in Foxglove)", view.port());
            McapLog::create_with_view(&mcap, &info, view).map_err(|e| e.to_string())?
        }
        None => McapLog::create(&mcap, &info).map_err(|e| e.to_string())?,
    };
    #[cfg(not(feature = "live-view"))]
    let mut log = McapLog::create(&mcap, &info).map_err(|e| e.to_string())?;
    if built_in {
        log.log(
            0.0,
            pinc::closed_loop::Level::Info,
            "model: the built-in models/mpc_pinc_thrust.pinc (no --model given)",
        )
        .map_err(|e| format!("{}: {e}", mcap.display()))?;
    }
    // A run watched live goes at the vehicle's pace.
    #[cfg(feature = "live-view")]
    let real_time = a.foxglove.is_some();
    #[cfg(not(feature = "live-view"))]
    let real_time = false;
    // On a live vehicle (--connect) the plant is the vehicle (pinc::link::session); otherwise
    // the simulator. A run that cannot start (no link, no autopilot, a bad option) commanded
    // nothing and leaves no log.
    #[cfg(feature = "vehicle")]
    let live_run = match &a.connect {
        Some(link) => Some(live(
            &a,
            link,
            Mpc::new(predictor.clone(), cfg.clone()),
            scenario,
            &vehicle,
            model.fitted.as_ref(),
            &mut log,
        ))
        .transpose(),
        None => Ok(None),
    }
    .inspect_err(|_| {
        let _ = std::fs::remove_file(&mcap);
    })?;
    #[cfg(not(feature = "vehicle"))]
    let live_run: Option<RunOutcome> = None;
    let (samples, log_error, stopped, live) = match live_run {
        Some(run) => run,
        None => {
            let (samples, log_error) = if a.oracle {
                let oracle = Rk4Vehicle::for_control(vehicle, predictor.dt());
                closed_loop(
                    Mpc::new(oracle, cfg.clone()).map_err(|e| e.to_string())?,
                    scenario,
                    &vehicle,
                    (a.json, real_time),
                    &mut log,
                )
            } else {
                closed_loop(
                    Mpc::new(predictor, cfg.clone()).map_err(|e| e.to_string())?,
                    scenario,
                    &vehicle,
                    (a.json, real_time),
                    &mut log,
                )
            };
            (samples, log_error, None, None)
        }
    };
    let summary = summarise(&samples, scenario, a.horizon as f64 * model.dt);
    // The log is finished even when a write failed mid-run, so what was written stays readable.
    let t_end = samples.last().map_or(0.0, |s| s.t);
    let finished = log.finish(&summary, t_end);
    let stats = match (log_error, finished) {
        (Some(e), _) | (None, Err(e)) => return Err(format!("{}: {e}", mcap.display())),
        (None, Ok(stats)) => stats,
    };
    let log_bytes = std::fs::metadata(&mcap).map_err(|e| format!("{}: {e}", mcap.display()))?.len();
    plot(
        &png,
        &samples,
        bounds,
        &format!("{} MPC, scenario {}", if a.oracle { "oracle" } else { "PINC" }, scenario.name()),
        scenario,
    )?;
    if a.json {
        let mut v = serde_json::to_value(&summary).map_err(|e| e.to_string())?;
        let o = v.as_object_mut().expect("summary is an object");
        o.insert("scenario".into(), scenario.name().into());
        o.insert(
            "controller_model".into(),
            if a.oracle { "analytic".into() } else { model_path.display().to_string().into() },
        );
        o.insert("model_built_in".into(), built_in.into());
        o.insert("horizon".into(), a.horizon.into());
        o.insert("plot".into(), png.display().to_string().into());
        o.insert("log".into(), mcap.display().to_string().into());
        o.insert("log_bytes".into(), log_bytes.into());
        o.insert("log_messages".into(), stats.messages.into());
        o.insert("stopped".into(), stopped.clone().into());
        o.insert("live".into(), live.clone().unwrap_or(serde_json::Value::Null));
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
    } else {
        print_summary(&summary);
        if let Some(l) = &live {
            print_live(l);
        }
        if built_in {
            println!("model: built in (models/mpc_pinc_thrust.pinc), as {}", model_path.display());
        }
        println!("plot: {}", png.display());
        println!("log:  {} ({log_bytes} bytes, {} messages; open it in Foxglove)", mcap.display(), stats.messages);
    }
    match stopped {
        Some(reason) => Err(reason),
        None => Ok(()),
    }
}

/// The live figures in the summary table's style.
fn print_live(l: &serde_json::Value) {
    let ms = |k: &str| {
        let v = &l[k];
        match (v["median"].as_f64(), v["p99"].as_f64(), v["max"].as_f64()) {
            (Some(a), Some(b), Some(c)) => format!("median {a:.1} ms, p99 {b:.1} ms, max {c:.1} ms"),
            _ => "none (no cycle ran)".into(),
        }
    };
    let h = &l["history"];
    if let Some(n) = h["cycles_forgotten"].as_u64().filter(|&n| n > 0) {
        println!(
            "figures over            the last {} s; {n} cycles before (in the log), {} deadline misses among them",
            h["kept_s"], h["deadline_misses_forgotten"]
        );
    }
    println!("state age at command    {}", ms("state_age_ms"));
    println!("arrival to command      {}", ms("latency_ms"));
    let e = &l["estimate_rms_error"];
    if l["truth_samples"].as_u64().unwrap_or(0) > 0 {
        let f = |k: &str| e[k].as_f64().map_or("-".into(), |v| format!("{v:.3}"));
        println!(
            "estimate vs truth RMS   u {} v {} w {} m/s, r {} rad/s, z {} m ({} samples)",
            f("u"),
            f("v"),
            f("w"),
            f("r"),
            f("z"),
            l["truth_samples"]
        );
    }
    println!(
        "estimator               {} fused, {} rejected, {} reacquired, {} late, {} restarts",
        l["fused"], l["rejected"], l["reacquired"], l["late"], l["restarts"]
    );
    let truth = &l["truth_rms"];
    if let (Some(d), Some(h)) = (truth["depth_m"].as_f64(), truth["heading_deg"].as_f64()) {
        println!("against the truth RMS   depth {d:.4} m, heading {h:.3} deg (true north)");
    }
    let h = &l["truth_horizontal"];
    if let (Some(rms), Some(max)) = (h["rms_m"].as_f64(), h["max_m"].as_f64()) {
        println!("horizontal vs truth     RMS {rms:.4} m, max {max:.4} m ({})", h["judged"].as_str().unwrap_or(""));
        if let Some(end) = h["schedule_end_s"].as_f64() {
            let done = h["finished_s"].as_f64().map_or("never".to_string(), |f| format!("{f:.2} s"));
            println!("path finished           {done} (schedule {end:.2} s)");
        }
    }
    if let Some(text) = l["heading_reference_text"].as_str() {
        println!("{text}");
    }
    for line in l["model_misfits"].as_array().into_iter().flatten() {
        println!("{}", line.as_str().unwrap_or_default());
    }
}

/// Runs the loop with a progress bar, logging every sample; Ctrl-C ends it early with the
/// samples so far. A log write error stops the logging, not the loop, and is returned.
fn closed_loop<M: DiscreteModel>(
    mut mpc: Mpc<M>,
    scenario: &Scenario,
    vehicle: &VehicleParams,
    (quiet, real_time): (bool, bool),
    log: &mut McapLog,
) -> (Vec<Sample>, Option<LogError>) {
    let started = std::time::Instant::now();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed));
    let total = (scenario.duration() / mpc.model().dt()).round() as u64;
    let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new(total) };
    bar.set_style(
        ProgressStyle::with_template("t {msg} [{bar:40}] {pos}/{len} samples ({eta})")
            .expect("static template")
            .progress_chars("=> "),
    );
    let mut log_error = None;
    let samples = run(&mut mpc, scenario, vehicle, |s| {
        if log_error.is_none() {
            log_error = log.record(s).err();
        }
        bar.set_message(format!("{:5.1} s  z {:5.2} m  solve {:5.2} ms", s.t, s.state[2], s.cycle.solve_us / 1e3));
        bar.inc(1);
        if real_time {
            let due = started + std::time::Duration::from_secs_f64(s.t);
            std::thread::sleep(due.saturating_duration_since(std::time::Instant::now()));
        }
        !stop.load(Ordering::Relaxed)
    });
    bar.finish_and_clear();
    (samples, log_error)
}

/// `--monte-carlo N`: both controllers on the same N perturbed plants, on every core.
fn monte_carlo(a: &Args, n: usize, campaign: &Campaign) -> Result<(), String> {
    use pinc::closed_loop::monte_carlo::robustness;
    use rayon::prelude::*;
    let scenario = &campaign.scenario;
    if n == 0 {
        return Err("--monte-carlo: at least one run".into());
    }
    let pool =
        rayon::ThreadPoolBuilder::new().num_threads(a.jobs.unwrap_or(0)).build().map_err(|e| format!("--jobs: {e}"))?;
    let bar = if a.json { ProgressBar::hidden() } else { ProgressBar::new(2 * n as u64) };
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} runs ({elapsed}, ETA {eta})")
            .expect("static template")
            .progress_chars("=> "),
    );
    bar.set_message(format!("Monte Carlo, {} threads", pool.current_num_threads()));
    let seeds: Vec<u64> = (0..n as u64).map(|i| a.seed + i).collect();
    // Each run builds its own controller: the model's nominal coefficients, never the draw's.
    let one = |seed: u64, controller: Controller| -> Outcome {
        let outcome = campaign.monte_carlo_run(seed, controller);
        bar.inc(1);
        outcome
    };
    let (pinc, oracle): (Vec<Outcome>, Vec<Outcome>) =
        pool.install(|| seeds.par_iter().map(|&s| (one(s, Controller::Pinc), one(s, Controller::Oracle))).unzip());
    bar.finish_and_clear();
    let (rp, ro) = (robustness(&pinc), robustness(&oracle));
    let png = a.out_dir.join(format!("mpc_{}_monte_carlo.png", scenario.name()));
    histogram(&png, &pinc, &oracle, n)?;
    let per_run: Vec<serde_json::Value> = pinc
        .iter()
        .zip(&oracle)
        .map(|(p, o)| {
            let figures = |x: &Outcome| serde_json::json!({"success": x.success, "rms_depth_m": x.rms_depth_m, "rms_heading_deg": x.rms_heading_deg});
            serde_json::json!({"seed": p.seed, "pinc": figures(p), "oracle": figures(o)})
        })
        .collect();
    let json = serde_json::json!({
        "runs": n, "seed": a.seed, "scenario": scenario.name(),
        "pinc": rp, "oracle": ro, "plot": png.display().to_string(),
    });
    let mut file_json = json.clone();
    file_json["per_run"] = per_run.into();
    let text = serde_json::to_string_pretty(&json).map_err(|e| e.to_string())?;
    let json_path = a.out_dir.join(format!("mpc_{}_monte_carlo.json", scenario.name()));
    let file_text = serde_json::to_string_pretty(&file_json).map_err(|e| e.to_string())?;
    std::fs::write(&json_path, file_text).map_err(|e| format!("{}: {e}", json_path.display()))?;
    if a.json {
        println!("{text}");
        return Ok(());
    }
    print!("{}", table(n, a.seed, scenario, &rp, &ro, &json_path));
    println!("histogram: {}\nfigures:   {}", png.display(), json_path.display());
    Ok(())
}

fn print_summary(s: &Summary) {
    let secs = |v: &[f64]| v.iter().map(|t| format!("{t:.2}")).collect::<Vec<_>>().join(" / ");
    println!("samples                 {}", s.samples);
    if let Some(h) = &s.horizontal {
        let what = if h.judged == "station" { "from the point held" } else { "cross-track" };
        println!("horizontal error        RMS {:.4} m, max {:.4} m {what} ({} samples)", h.rms_m, h.max_m, h.samples);
        if let Some(end) = h.schedule_end_s {
            match h.finished_s {
                Some(f) => println!("path finished           {f:.2} s (schedule {end:.2} s)"),
                None => println!("path finished           never (schedule {end:.2} s)"),
            }
        }
    }
    println!("RMS depth error         {:.4} m", s.rms_depth_m);
    println!("RMS heading error       {:.3} deg", s.rms_heading_deg);
    println!(
        "max overshoot           {:.4} m depth, {:.3} deg heading",
        s.max_overshoot_depth_m, s.max_overshoot_heading_deg
    );
    println!(
        "settling (5 %)          depth {} s, heading {} s",
        secs(&s.settling_depth_s),
        secs(&s.settling_heading_s)
    );
    println!(
        "solve time              median {:.3} ms, p99 {:.3} ms, max {:.3} ms",
        s.solve_ms_median, s.solve_ms_p99, s.solve_ms_max
    );
    println!("cycle time              median {:.3} ms, p99 {:.3} ms", s.cycle_ms_median, s.cycle_ms_p99);
    println!("fallbacks               {}", s.fallbacks);
    println!("deadline misses         {}", s.deadline_misses);
    println!("bound violations        {}", s.bound_violations);
    println!("samples at a bound      {}", s.saturated_samples);
    let tv = &s.input_total_variation;
    println!(
        "input total variation   X {:.1} N, Y {:.1} N, Z {:.1} N, Mz {:.2} N m",
        tv["X"], tv["Y"], tv["Z"], tv["Mz"]
    );
    println!("held heading error max  {:.3} deg", s.held_heading_error_max_deg);
    println!(
        "steady error            depth {:.2} mm, heading {:.4} deg",
        s.steady_depth_error_m * 1e3,
        s.steady_heading_error_deg
    );
    println!("envelope exits          {} cycles", s.envelope_exits);
    println!("heading off unit circle {} cycles", s.heading_off_circle);
}

fn plot(
    path: &Path,
    samples: &[Sample],
    (lo, hi): (Input, Input),
    title: &str,
    scenario: &Scenario,
) -> Result<(), String> {
    let series = |label, color, dashed, f: &dyn Fn(&Sample) -> f64| Series {
        label,
        points: samples.iter().map(|s| (s.t, f(s))).collect(),
        color,
        dashed,
    };
    let bound = |label, color, v: f64| Series {
        label,
        points: vec![(0.0, v), (samples.last().map_or(0.0, |s| s.t), v)],
        color,
        dashed: true,
    };
    let names = ["X (N)", "Y (N)", "Z (N)"];
    let mut forces: Vec<Series> =
        (0..3).map(|j| series(names[j], j, false, &move |s: &Sample| s.cycle.input[j])).collect();
    for j in 0..3 {
        forces.push(bound("", j, lo[j]));
        forces.push(bound("", j, hi[j]));
    }
    let panels = vec![
        Panel {
            title,
            x_label: "t (s)",
            y_label: "depth z (m, down)",
            log_y: false,
            series: vec![series("reference", 6, true, &|s| s.reference.depth), series("z", 0, false, &|s| s.state[2])],
        },
        Panel {
            title: "heading",
            x_label: "t (s)",
            y_label: "psi (deg)",
            log_y: false,
            series: vec![
                series("reference", 6, true, &|s| s.reference.heading.to_degrees()),
                series("psi", 1, false, &|s| s.state[3].to_degrees()),
            ],
        },
        Panel { title: "forces, bounds dashed", x_label: "t (s)", y_label: "N", log_y: false, series: forces },
        Panel {
            title: "yaw moment, bounds dashed",
            x_label: "t (s)",
            y_label: "N m",
            log_y: false,
            series: vec![series("Mz", 3, false, &|s| s.cycle.input[3]), bound("", 3, lo[3]), bound("", 3, hi[3])],
        },
        Panel {
            title: "QP solve time",
            x_label: "t (s)",
            y_label: "ms",
            log_y: false,
            series: vec![series("solve", 4, false, &|s| s.cycle.solve_us / 1e3)],
        },
        Panel {
            title: "cycle time (rollout, linearise, update, solve)",
            x_label: "t (s)",
            y_label: "ms",
            log_y: false,
            series: vec![series("cycle", 5, false, &|s| s.cycle.cycle_us / 1e3)],
        },
    ];
    let mut panels = panels;
    if let Some(plan) = &scenario.horizontal {
        // The track seen from above: east to the right, north up.
        let goal: Vec<(f64, f64)> =
            samples.iter().filter_map(|s| s.reference.horizontal.map(|h| (h.east, h.north))).collect();
        panels.push(Panel {
            title: "track from above",
            x_label: "east (m)",
            y_label: "north (m)",
            log_y: false,
            series: vec![
                Series { label: "reference", points: goal, color: 6, dashed: true },
                Series {
                    label: "vehicle",
                    points: samples.iter().map(|s| (s.state[1], s.state[0])).collect(),
                    color: 0,
                    dashed: false,
                },
            ],
        });
        panels.push(Panel {
            title: if plan.station { "distance from the point held" } else { "cross-track error" },
            x_label: "t (s)",
            y_label: "m",
            log_y: false,
            series: vec![series("error", 2, false, &|s| plan.cross_track(s.state[0], s.state[1]))],
        });
    }
    let height = if panels.len() > 6 { 1600 } else { 1200 };
    figure(path, 1400, height, 2, &panels)
}

/// `--pilot-speeds U,V,W,R` (m/s, m/s, m/s, deg/s) as the assist's caps (yaw in rad/s).
#[cfg(feature = "vehicle")]
fn pilot_speeds(given: Option<&[f64]>) -> Result<[Option<f64>; 4], String> {
    let Some(v) = given else { return Ok([None; 4]) };
    let [u, v, w, r]: [f64; 4] =
        v.try_into().map_err(|_| "--pilot-speeds: four speeds SURGE,SWAY,HEAVE (m/s),YAW (deg/s)".to_string())?;
    if [u, v, w, r].iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(format!("--pilot-speeds: each speed must be a positive number, got {u},{v},{w},{r}"));
    }
    Ok([Some(u), Some(v), Some(w), Some(r.to_radians())])
}

/// `--hold-at DEPTH,HEADING[,NORTH,EAST]`, checked: only for a scenario held from where it starts.
#[cfg(feature = "vehicle")]
fn hold_at(given: Option<&[f64]>, scenario: &Scenario) -> Result<Option<pinc::link::session::HoldAt>, String> {
    let Some(v) = given else { return Ok(None) };
    if !scenario.from_start {
        return Err(format!("--hold-at is for --scenario hold, not {}", scenario.name()));
    }
    if !(v.len() == 2 || v.len() == 4) || v.iter().any(|x| !x.is_finite()) {
        return Err(format!("--hold-at: DEPTH,HEADING or DEPTH,HEADING,NORTH,EAST as numbers, got {v:?}"));
    }
    Ok(Some(pinc::link::session::HoldAt {
        depth: v[0],
        heading: v[1].to_radians(),
        north_east: (v.len() == 4).then(|| (v[2], v[3])),
    }))
}

/// `--connect`: the live session flies the scenario, with pinc's MPC (on the model, or the
/// analytic vehicle with `--oracle`) or the autopilot's own controller.
#[cfg(feature = "vehicle")]
fn live(
    a: &Args,
    connect: &str,
    mpc: Result<Mpc<Predictor<f64>>, impl std::fmt::Display>,
    scenario: &Scenario,
    vehicle: &VehicleParams,
    // What a model fitted by `pinc fit` carries of its vehicle (thrusters, sensors).
    fitted: Option<&pinc::model::FittedVehicle>,
    log: &mut McapLog,
) -> Result<RunOutcome, String> {
    use pinc::link::session::{AutopilotHold, Flyer, PilotOptions, SessionOptions, run};
    let pilot = match &a.pilot {
        Some(source) => Some(PilotOptions { source: source.clone(), speeds: pilot_speeds(a.pilot_speeds.as_deref())? }),
        None => None,
    };
    let options = SessionOptions {
        connect,
        vehicle: a.vehicle.as_deref(),
        fitted,
        link: &a.link,
        drive: &a.drive,
        estimator: &a.estimator,
        max_distance: a.max_distance,
        stream_samples: a.stream_samples,
        history_s: a.history,
        pilot: pilot.as_ref(),
        hold_at: hold_at(a.hold_at.as_deref(), scenario)?,
    };
    let mpc = mpc.map_err(|e| e.to_string())?;
    let hold = match a.autopilot_hold.as_deref() {
        Some("guided") => Some(AutopilotHold::Guided),
        Some("poshold") => Some(AutopilotHold::PosHold),
        Some(_) => Some(AutopilotHold::AltHold),
        None => None,
    };
    let outcome = if a.oracle {
        let oracle = Rk4Vehicle::for_control(*vehicle, mpc.model().dt());
        let flyer = match hold {
            Some(hold) => Flyer::Autopilot { hold, model: oracle },
            None => Flyer::Mpc(Box::new(Mpc::new(oracle, mpc.config().clone()).map_err(|e| e.to_string())?)),
        };
        run(flyer, scenario, &options, log)?
    } else {
        let flyer = match hold {
            Some(hold) => Flyer::Autopilot { hold, model: mpc.model().clone() },
            None => Flyer::Mpc(Box::new(mpc)),
        };
        run(flyer, scenario, &options, log)?
    };
    // The navigation against the simulator's truth, drawn (with --sim-truth).
    let mut live = outcome.live;
    if let (Some(track), Some(serde_json::Value::Object(o))) = (&outcome.navigation, live.as_mut()) {
        let navigation_png = &a.out_dir.join(format!("{}_navigation.png", run_name(a, scenario)));
        track.plot(navigation_png, &format!("{}, scenario {}", hold.map_or("pinc", |h| h.name()), scenario.name()))?;
        o.insert("navigation_plot".into(), navigation_png.display().to_string().into());
    }
    Ok((outcome.samples, outcome.log_error, outcome.stopped, live))
}
