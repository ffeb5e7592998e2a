//! Closed-loop depth and heading tracking: the LTV-MPC on the frozen PINC (or, with
//! `--oracle`, on the analytic model) against the simulated BlueROV2.
//!
//! ```sh
//! cargo run --release --example mpc_track                       # PINC-MPC, scenario default
//! cargo run --release --example mpc_track -- --oracle --scenario disturbed --json
//! cargo run --release --example mpc_track -- --reference examples/references/zigzag.csv
//! ```
//!
//! Prints a summary table (or `--json`) and writes a PNG of the run and its MCAP log (open it
//! in Foxglove) to `--out-dir`.
//!
//! With `--connect URL --vehicle V.toml` the plant is a live ArduSub vehicle instead
//! (docs/VEHICLE.md): one MPC cycle per fresh state, the wrench sent as commands, every
//! safety trigger stopping the run with the neutral command.

use clap::{Parser, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use pinc::Input;
use pinc::closed_loop::campaign::{Campaign, Controller, Settings, histogram, table};
use pinc::closed_loop::monte_carlo::Outcome;
use pinc::closed_loop::{LogError, McapLog, RunInfo};
use pinc::closed_loop::{Sample, Scenario, Summary, run, summarise};
use pinc::mpc::{Mpc, MpcConfig};
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
    /// The frozen model inside the MPC (its training envelope bounds the inputs).
    #[arg(long, default_value = "models/mpc_pinc_thrust.pinc")]
    model: PathBuf,
    /// Run the identical controller on the analytic vehicle model instead (bounds still from --model).
    #[arg(long)]
    oracle: bool,
    /// Which built-in scenario.
    #[arg(long, value_enum, default_value = "default", conflicts_with = "reference")]
    scenario: ScenarioName,
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
    /// commands.
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
}

#[derive(Clone, Copy, ValueEnum)]
enum ScenarioName {
    Default,
    Disturbed,
}

fn main() -> ExitCode {
    pinc::broken_pipe::exit_quietly_on_broken_pipe();
    match try_main(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if pinc::broken_pipe::is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}

fn try_main(a: Args) -> Result<(), String> {
    // The controller and scenario come from the library's one set-up path (shared with the
    // Python package, so a seed's run is the same everywhere).
    let settings = Settings {
        model: a.model.clone(),
        vehicle: a.vehicle.clone(),
        scenario: match a.scenario {
            ScenarioName::Default => "default",
            ScenarioName::Disturbed => "disturbed",
        }
        .into(),
        reference: a.reference.clone(),
        duration: a.duration,
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
    };
    let campaign = Campaign::new(&settings).map_err(|e| e.to_string())?;
    let Campaign { model, vehicle, scenario, config: cfg, bounds } = &campaign;
    let (model, vehicle, scenario, cfg, bounds) = (model, *vehicle, scenario, cfg.clone(), *bounds);
    let predictor = Predictor::reference(model);
    std::fs::create_dir_all(&a.out_dir).map_err(|e| format!("{}: {e}", a.out_dir.display()))?;
    if let Some(n) = a.monte_carlo {
        return monte_carlo(&a, n, &campaign);
    }
    let controller = if a.oracle { "oracle" } else { "pinc" };
    let name = format!("mpc_{}_{controller}", scenario.name());
    let png = a.out_dir.join(format!("{name}.png"));
    let mcap = a.out_dir.join(format!("{name}.mcap"));
    let info =
        RunInfo { controller, model_path: &a.model, scenario, config: &cfg, bounds, dt: model.dt, vehicle: &vehicle };
    let mut log = McapLog::create(&mcap, &info).map_err(|e| e.to_string())?;
    // On a live vehicle (--connect) the plant is the vehicle; otherwise the simulator. A run
    // that cannot start (no link, no autopilot, a bad option) commanded nothing and leaves no log.
    #[cfg(feature = "vehicle")]
    let live_run = match &a.connect {
        Some(link) if a.oracle => {
            let oracle = Rk4Vehicle { params: vehicle, ..Rk4Vehicle::with_dt(predictor.dt()) };
            Some(
                Mpc::new(oracle, cfg.clone())
                    .map_err(|e| e.to_string())
                    .and_then(|mpc| live::run(mpc, scenario, link, &a, &mut log)),
            )
        }
        Some(link) => Some(
            Mpc::new(predictor.clone(), cfg.clone())
                .map_err(|e| e.to_string())
                .and_then(|mpc| live::run(mpc, scenario, link, &a, &mut log)),
        ),
        None => None,
    }
    .transpose()
    .inspect_err(|_| {
        let _ = std::fs::remove_file(&mcap);
    })?;
    #[cfg(not(feature = "vehicle"))]
    let live_run: Option<LiveRun> = None;
    let (samples, log_error, stopped, live) = match live_run {
        Some(run) => run,
        None => {
            let (samples, log_error) = if a.oracle {
                let oracle = Rk4Vehicle { params: vehicle, ..Rk4Vehicle::with_dt(predictor.dt()) };
                closed_loop(
                    Mpc::new(oracle, cfg.clone()).map_err(|e| e.to_string())?,
                    scenario,
                    &vehicle,
                    a.json,
                    &mut log,
                )
            } else {
                closed_loop(
                    Mpc::new(predictor, cfg.clone()).map_err(|e| e.to_string())?,
                    scenario,
                    &vehicle,
                    a.json,
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
    )?;
    if a.json {
        let mut v = serde_json::to_value(&summary).map_err(|e| e.to_string())?;
        let o = v.as_object_mut().expect("summary is an object");
        o.insert("scenario".into(), scenario.name().into());
        o.insert(
            "controller_model".into(),
            if a.oracle { "analytic".into() } else { a.model.display().to_string().into() },
        );
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
}

/// Runs the loop with a progress bar, logging every sample; Ctrl-C ends it early with the
/// samples so far. A log write error stops the logging, not the loop, and is returned.
fn closed_loop<M: DiscreteModel>(
    mut mpc: Mpc<M>,
    scenario: &Scenario,
    vehicle: &VehicleParams,
    quiet: bool,
    log: &mut McapLog,
) -> (Vec<Sample>, Option<LogError>) {
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

fn plot(path: &Path, samples: &[Sample], (lo, hi): (Input, Input), title: &str) -> Result<(), String> {
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
    figure(path, 1400, 1200, 2, &panels)
}

/// A run on a live vehicle: its samples, a log write error, why it stopped early, and the
/// live figures (latencies, the estimator's, its errors against a simulator's truth).
type LiveRun = (Vec<Sample>, Option<LogError>, Option<String>, Option<serde_json::Value>);

/// The closed loop on a live vehicle over MAVLink (`--connect`).
#[cfg(feature = "vehicle")]
mod live {
    use super::Args;
    use mavlink::dialects::ardupilotmega::{MavMessage, SIM_STATE_DATA};
    use pinc::closed_loop::{Level, LogError, McapLog, Sample, Scenario};
    use pinc::estimation::mavlink::Observation;
    use pinc::estimation::{Estimate, Measurement, Tracker};
    use pinc::link::cli::{non_negative, open};
    use pinc::link::{Capability, Drive, Note, Received, Trigger};
    use pinc::mpc::Mpc;
    use pinc::traits::DiscreteModel;
    use pinc::types::{NU, SimState};
    use pinc::vehicle::{Rk4Vehicle, VehicleParams, to_network};
    use serde_json::{Value, json};
    use std::cell::RefCell;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::time::Instant;

    /// `SERVO_OUTPUT_RAW`, whose outputs are the input the estimator is driven by.
    const SERVO_OUTPUT_RAW_ID: u32 = 36;
    /// `SIM_STATE`: the simulator's truth.
    const SIM_STATE_ID: u32 = 108;

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

    /// The process model of the estimator.
    enum EstimatorModel<M> {
        Controller(M),
        Vehicle(Rk4Vehicle),
    }

    /// Either model behind one tracker type.
    enum AnyTracker<M: DiscreteModel> {
        Controller(Tracker<M>),
        Vehicle(Tracker<Rk4Vehicle>),
    }

    macro_rules! each {
        ($t:expr, $x:ident => $body:expr) => {
            match $t {
                AnyTracker::Controller($x) => $body,
                AnyTracker::Vehicle($x) => $body,
            }
        };
    }

    /// The estimate's errors `u v w r z` against the truth interpolated at each estimate's time
    /// (SIM_STATE has no time stamp of its own: its arrival's autopilot time is used, and an
    /// estimate is compared only between two truths at most 0.2 s apart). Heading is left out:
    /// ATTITUDE's is magnetic where the autopilot knows no declination (no GPS), the truth's true.
    fn errors_against_truth(estimates: &[Estimate], truths: &[Truth]) -> [Vec<f64>; 5] {
        let mut errors: [Vec<f64>; 5] = Default::default();
        for e in estimates {
            let k = truths.partition_point(|tr| tr.t <= e.t);
            if k == 0 || k == truths.len() {
                continue;
            }
            let (a, b) = (&truths[k - 1], &truths[k]);
            if b.t - a.t > 0.2 || b.t <= a.t {
                continue;
            }
            let f = (e.t - a.t) / (b.t - a.t);
            let lerp = |x: f64, y: f64| x + f * (y - x);
            let truth = [
                lerp(a.uvw[0], b.uvw[0]),
                lerp(a.uvw[1], b.uvw[1]),
                lerp(a.uvw[2], b.uvw[2]),
                lerp(a.r, b.r),
                lerp(a.z, b.z),
            ];
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

    /// Runs `scenario` on the vehicle: arms (retrying while the autopilot refuses), waits
    /// (neutral commands) until the state estimate runs (or, with `--wait-position`, for a
    /// position source), then one MPC cycle per fresh state sample on the estimate, its wrench
    /// sent as commands, until the scenario ends or a safety trigger stops it. The scenario's
    /// time 0 is the first cycle. Returns the samples, a log write error, the stop's reason
    /// and the live figures.
    ///
    /// # Errors
    /// Set-up: no vehicle file, a bad option, the link, no autopilot; these command nothing.
    pub fn run<M: DiscreteModel + Clone>(
        mut mpc: Mpc<M>,
        scenario: &Scenario,
        connect: &str,
        a: &Args,
        log: &mut McapLog,
    ) -> Result<super::LiveRun, String> {
        let vehicle_file =
            a.vehicle.as_ref().ok_or("--connect needs --vehicle V.toml with the vehicle's [[thruster]] tables")?;
        let commander = a.drive.commander(vehicle_file)?;
        let settings = a.drive.settings()?;
        let wait_position = non_negative("--wait-position", a.drive.wait_position)?;
        // How long to wait (neutral) for a state to control on: --wait-position, else 30 s.
        let give_up = if wait_position.is_zero() { std::time::Duration::from_secs(30) } else { wait_position };
        let frozen_limit = pinc::link::cli::positive("--max-frozen", a.drive.max_frozen)?.as_secs_f64();
        let noise = a.estimator.noise()?;
        let position_free = mpc.model().position_free();
        let model = match a.estimator.estimator_model.as_str() {
            "vehicle" => {
                let params = VehicleParams::load(vehicle_file).map_err(|e| e.to_string())?;
                EstimatorModel::Vehicle(Rk4Vehicle { params, ..Rk4Vehicle::with_dt(mpc.model().dt()) })
            }
            _ => EstimatorModel::Controller(mpc.model().clone()),
        };
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed))
            .map_err(|e| format!("cannot catch Ctrl-C: {e}"))?;
        let (link, autopilot, estimator) = open(connect, &a.link, |_| {})?;
        link.set_message_rate(SERVO_OUTPUT_RAW_ID, a.drive.outputs_rate).map_err(|e| e.to_string())?;
        if a.estimator.sim_truth {
            link.set_message_rate(SIM_STATE_ID, a.link.rate).map_err(|e| e.to_string())?;
        }
        let mut log_error: Option<LogError> = None;
        let estimator_line = if a.estimator.no_estimator {
            "no state estimator (the raw state; body velocities from the autopilot's EKF)".to_string()
        } else {
            format!(
                "state estimator on the {} model (depth std {} m, heading std {} rad)",
                a.estimator.estimator_model, noise.depth_std, noise.heading_std
            )
        };
        let line = format!(
            "live vehicle on {connect} (system {}), commands by {}; {estimator_line}; {}",
            autopilot.system_id,
            a.drive.command_way,
            settings.limits.describe()
        );
        log_error = log_error.or(log.log(0.0, Level::Info, &line).err());
        let truths: RefCell<Vec<Truth>> = RefCell::new(Vec::new());
        let seen = |r: &Received, t: f64| {
            if let MavMessage::SIM_STATE(s) = &r.message {
                truths.borrow_mut().push(truth_of(t, s));
            }
        };
        let mut notes: Vec<Note> = Vec::new();
        let started = Drive::start(link, autopilot, estimator, commander.clone(), settings, stop, seen);
        let mut drive = match started {
            Ok(d) => d,
            Err(mut stopped) => {
                for n in std::mem::take(&mut stopped.notes) {
                    log_error = log_error.or(log.log(0.0, n.level, &n.text).err());
                }
                let reason = stopped.trigger.map_or_else(|| "stopped".to_string(), |t| t.to_string());
                log_error = log_error.or(log.log(0.0, Level::Error, &reason).err());
                eprintln!("{reason}");
                return Ok((Vec::new(), log_error, Some(reason), None));
            }
        };
        let mut tracker = match model {
            EstimatorModel::Controller(m) => AnyTracker::Controller(Tracker::new(m, noise)),
            EstimatorModel::Vehicle(v) => AnyTracker::<M>::Vehicle(Tracker::new(v, noise)),
        };
        let dt = mpc.model().dt();
        let n = mpc.config().horizon;
        let (lo, hi) = mpc.bounds();
        let mut samples: Vec<Sample> = Vec::new();
        let waited = Instant::now();
        let mut t0: Option<f64> = None;
        let mut refs = vec![scenario.reference(0.0); n];
        let mut horizontal_before: Option<bool> = None;
        let (mut ages, mut latencies) = (Vec::new(), Vec::new());
        let (mut estimates, mut all_truths): (Vec<Estimate>, Vec<Truth>) = (Vec::new(), Vec::new());
        let mut control_after: Option<f64> = None;
        let (mut last_depth, mut last_heading): (Option<f64>, Option<f64>) = (None, None);
        // The depth reading and when it last changed: a pressure sensor in water never repeats
        // the same value for long; ArduSub repeats the last one when its sensor is gone.
        let mut depth_changed: Option<(f64, f64)> = None;
        // Which of the last 25 readings changed, and whether the current run of repeats began
        // on a live sensor (one whose readings changed on at least 20 of the 25 before): a
        // simulator without sensor noise repeats its depth at rest and is not taken as frozen.
        const LIVE_WINDOW_MASK: u32 = (1 << 25) - 1;
        const LIVE_CHANGES: u32 = 20;
        let (mut depth_changes, mut frozen_from_live) = (0u32, false);
        // Per channel: sum of applied x asked, of asked^2, and the count (a least-squares gain of
        // the outputs on the commands), and the last command with its autopilot time.
        let mut delivered = [(0.0f64, 0.0f64, 0usize); NU];
        let mut last_command: Option<(f64, pinc::Input)> = None;

        let t_log = |at: f64, t0: Option<f64>| t0.map_or(0.0, |s| (at - s).max(0.0));
        let outcome: Result<(), Trigger> = loop {
            let fresh = match drive.next_state(seen) {
                Ok(f) => f,
                Err(t) => break Err(t),
            };
            notes.extend(drive.take_notes());
            for o in drive.drain_observations() {
                match o {
                    Observation::Measured(Measurement::Depth { t, z }) => {
                        last_depth = Some(t);
                        let changed = depth_changed.is_none_or(|(value, _)| value != z);
                        if changed {
                            depth_changed = Some((z, t));
                        } else if depth_changes.count_ones() >= LIVE_CHANGES {
                            // The first repeat of a sensor that was changing on nearly every
                            // reading: if the repeats go on, it froze.
                            frozen_from_live = true;
                        }
                        if changed {
                            frozen_from_live = false;
                        }
                        depth_changes = (depth_changes << 1 | u32::from(changed)) & LIVE_WINDOW_MASK;
                    }
                    Observation::Measured(Measurement::Position { t, z, .. }) if z.is_finite() => last_depth = Some(t),
                    Observation::Measured(Measurement::Heading { t, .. }) => last_heading = Some(t),
                    Observation::Applied(t, applied) => {
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
                each!(&mut tracker, tr => match o {
                    Observation::Measured(m) => tr.measure(m),
                    Observation::Applied(t, u) => tr.applied(t, u),
                });
            }
            let estimate: Option<Estimate> = if a.estimator.no_estimator {
                None
            } else {
                match each!(&mut tracker, tr => tr.advance(fresh.state.t)) {
                    Ok(e) => e,
                    Err(e) => break Err(Trigger::Error(format!("state estimator: {e}"))),
                }
            };
            let horizontal = each!(&tracker, tr => tr.horizontal_observed(fresh.state.t));
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
            let state: Option<SimState> = match (&estimate, a.estimator.no_estimator) {
                (Some(e), _) if horizontal || position_free => Some(e.sim),
                (None, true) if fresh.state.capability == Capability::Full => Some(SimState::from(fresh.state.sim)),
                _ => None,
            };
            let start = match t0 {
                Some(s) => s,
                None => {
                    let waiting_for_position = !horizontal && waited.elapsed() < wait_position;
                    if state.is_none() || waiting_for_position {
                        if state.is_none() && waited.elapsed() > give_up {
                            let why = if a.estimator.no_estimator {
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
                                each!(&mut tracker, tr => tr.commanded(pinc::Input::zeros()));
                                continue;
                            }
                            Err(t) => break Err(t),
                        }
                    }
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
                    *t0.insert(fresh.state.t)
                }
            };
            for n in notes.drain(..) {
                log_error = log_error.or(log.log(t_log(n.t, t0), n.level, &n.text).err());
            }
            let Some(state) = state else {
                let why = if a.estimator.no_estimator {
                    format!("the raw state lost a part: {}", fresh.state.capability)
                } else {
                    "the state estimate stopped (a gap in the measurements longer than 2 s)".to_string()
                };
                break Err(Trigger::Error(why));
            };
            // Depth and heading are what the controller cannot do without: their silence stops it
            // (the state sample's own clock goes on while either message keeps coming).
            let sensor_limit = a.link.max_age;
            let silent = [("depth", last_depth), ("heading", last_heading)]
                .into_iter()
                .map(|(sensor, last)| (sensor, last.map_or(f64::INFINITY, |l| fresh.state.t - l)))
                .find(|(_, age)| *age > sensor_limit);
            if let Some((sensor, age)) = silent {
                break Err(Trigger::SensorLost { sensor, age, limit: sensor_limit, frozen: false });
            }
            if let Some((_, since)) = depth_changed
                && frozen_from_live
                && fresh.state.t - since > frozen_limit
            {
                let age = fresh.state.t - since;
                break Err(Trigger::SensorLost { sensor: "depth", age, limit: frozen_limit, frozen: true });
            }
            let t = fresh.state.t - start;
            if t >= scenario.duration() - 1e-9 {
                break Ok(());
            }
            for (j, r) in refs.iter_mut().enumerate() {
                *r = scenario.reference(t + (j + 1) as f64 * dt);
            }
            let cycle = mpc.step(&to_network(&state), &refs);
            let sent = match drive.send(&fresh, &cycle.input) {
                Ok(s) => s,
                Err(t) => break Err(t),
            };
            let asked = commander.input_of(&sent.command);
            each!(&mut tracker, tr => tr.commanded(asked));
            last_command = Some((sent.autopilot_t, asked));
            let u = cycle.input;
            let bound_violation = (0..NU).any(|j| !(u[j] >= lo[j] - 1e-9 && u[j] <= hi[j] + 1e-9));
            // The state's age when its command went out, and the arrival-to-send latency.
            let state_age = sent.autopilot_t - fresh.state.t;
            let latency = sent.at.saturating_duration_since(fresh.arrived).as_secs_f64();
            ages.push(state_age);
            latencies.push(latency);
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
                let m = json!({
                    "t_autopilot_s": e.t, "estimate": e.sim.as_slice(), "std": e.std,
                    "disturbance": e.disturbance.as_slice(), "disturbance_std": e.disturbance_std, "raw": raw,
                    "position_source": horizontal,
                });
                if log_error.is_none() {
                    log_error = log.live("/estimate", "pinc.Estimate", t, m).err();
                }
            }
            let sample = Sample {
                t,
                state,
                reference: scenario.reference(t),
                cycle,
                prediction: mpc.prediction().to_vec(),
                bound_violation,
            };
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
        for n in notes.drain(..) {
            log_error = log_error.or(log.log(t_log(n.t, t0), n.level, &n.text).err());
        }
        let reason = stopped.trigger.as_ref().map(|t| {
            format!(
                "{t}; neutral command sent{}{}",
                stopped.neutral_t.map_or(" (failed)".to_string(), |n| format!(" at {:.3} s", t_log(n, t0))),
                if stopped.disarm_sent { ", disarm sent" } else { "" }
            )
        });
        if let Some(r) = &reason {
            log_error = log_error.or(log.log(t_log(stopped.t, t0), Level::Error, r).err());
            eprintln!("{r}");
        }
        if drive.out_of_order() > 0 {
            let line = format!("{} messages arrived out of order and were dropped", drive.out_of_order());
            log_error = log_error.or(log.log(t_log(stopped.t, t0), Level::Warning, &line).err());
        }
        // What the thrusters delivered of what was asked (from SERVO_OUTPUT_RAW): a wrong
        // --js-gain or thruster table shows here as a ratio away from 1.
        let mut ratios = serde_json::Map::new();
        for (j, name) in pinc::types::INPUT_NAMES.iter().enumerate() {
            let (num, den, n) = delivered[j];
            let ratio = (n >= 20 && den > 0.0).then(|| num / den);
            if let Some(r) = ratio
                && (r - 1.0).abs() > 0.25
            {
                let line = format!(
                    "the thrusters delivered {r:.2} of the commanded {name} over {n} samples (SERVO_OUTPUT_RAW through \
                     the vehicle file): check --js-gain against the autopilot's pilot gain (JS_GAIN_DEFAULT) and the \
                     vehicle file's thrusters"
                );
                eprintln!("{line}");
                log_error = log_error.or(log.log(t_log(stopped.t, t0), Level::Warning, &line).err());
            }
            ratios.insert(name.to_string(), json!(ratio));
        }
        let counts = each!(&tracker, tr => (tr.counts(), tr.late(), tr.restarts()));
        let errors = errors_against_truth(&estimates, &all_truths);
        let names = ["u", "v", "w", "r", "z"];
        let estimate_rms: serde_json::Map<String, Value> =
            names.iter().zip(&errors).map(|(n, e)| (n.to_string(), json!(rms(e)))).collect();
        let live = json!({
            "estimator": if a.estimator.no_estimator { Value::Null } else { json!(a.estimator.estimator_model) },
            "control_started_after_arming_s": control_after,
            "state_age_ms": percentiles_ms(&mut ages),
            "latency_ms": percentiles_ms(&mut latencies),
            "estimate_rms_error": estimate_rms,
            "truth_samples": errors[0].len(),
            "delivered_to_commanded": ratios,
            "fused": counts.0.fused, "rejected": counts.0.rejected, "reacquired": counts.0.reacquired, "late": counts.1, "restarts": counts.2,
            "disarm_sent": stopped.disarm_sent,
            "stop_trigger": stopped.trigger.as_ref().map(|t| t.key()),
            "stop_autopilot_s": stopped.trigger.as_ref().map(|_| stopped.t),
            "neutral_autopilot_s": stopped.neutral_t,
        });
        Ok((samples, log_error, reason, Some(live)))
    }
}
