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

use clap::{Parser, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use pinc::Input;
use pinc::closed_loop::monte_carlo::Outcome;
use pinc::closed_loop::{LogError, McapLog, RunInfo};
use pinc::closed_loop::{Sample, Scenario, Summary, run, summarise};
use pinc::model::PincModel;
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
    /// [default: the BlueROV2].
    #[arg(long)]
    vehicle: Option<PathBuf>,
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
    let mut scenario = match (&a.reference, a.scenario) {
        (Some(path), _) => Scenario::from_file(path, a.duration).map_err(|e| e.to_string())?,
        (None, ScenarioName::Default) => Scenario::default(),
        (None, ScenarioName::Disturbed) => Scenario::disturbed(),
    };
    // A reference file took --duration above (checked there); the built-ins take it here.
    if a.reference.is_none()
        && let Some(d) = a.duration
    {
        if !(d.is_finite() && d > 0.0) {
            return Err(format!("--duration must be a positive number of seconds, got {d}"));
        }
        scenario.duration = d;
    }
    let model = PincModel::load(&a.model).map_err(|e| format!("{}: {e}", a.model.display()))?;
    let vehicle = match &a.vehicle {
        Some(path) => VehicleParams::load(path).map_err(|e| e.to_string())?,
        None => VehicleParams::default(),
    };
    let predictor = Predictor::reference(&model);
    let bounds = predictor
        .input_bounds()
        .ok_or_else(|| format!("{}: no training envelope to bound the inputs", a.model.display()))?;
    let defaults = MpcConfig::default();
    let input_rate = match &a.input_rate {
        Some(v) => v.clone().try_into().map_err(|_| "--input-rate: four weights X,Y,Z,Mz".to_string())?,
        None => defaults.input_rate,
    };
    let cfg = MpcConfig {
        input_rate,
        horizon: a.horizon,
        bounds: Some(bounds),
        disturbance_gain: a.disturbance_gain,
        envelope_constraints: !a.no_envelope_constraints,
        envelope_penalty: a.envelope_penalty,
        envelope_margin: a.envelope_margin,
        ..MpcConfig::default()
    };
    std::fs::create_dir_all(&a.out_dir).map_err(|e| format!("{}: {e}", a.out_dir.display()))?;
    if let Some(n) = a.monte_carlo {
        return monte_carlo(&a, n, &model, &cfg, &scenario, &vehicle);
    }
    let controller = if a.oracle { "oracle" } else { "pinc" };
    let name = format!("mpc_{}_{controller}", scenario.name());
    let png = a.out_dir.join(format!("{name}.png"));
    let mcap = a.out_dir.join(format!("{name}.mcap"));
    let info = RunInfo {
        controller,
        model_path: &a.model,
        scenario: &scenario,
        config: &cfg,
        bounds,
        dt: model.dt,
        vehicle: &vehicle,
    };
    let mut log = McapLog::create(&mcap, &info).map_err(|e| e.to_string())?;
    let (samples, log_error) = if a.oracle {
        let oracle = Rk4Vehicle { params: vehicle, ..Rk4Vehicle::with_dt(predictor.dt()) };
        closed_loop(Mpc::new(oracle, cfg.clone()).map_err(|e| e.to_string())?, &scenario, &vehicle, a.json, &mut log)
    } else {
        closed_loop(Mpc::new(predictor, cfg.clone()).map_err(|e| e.to_string())?, &scenario, &vehicle, a.json, &mut log)
    };
    let summary = summarise(&samples, &scenario, a.horizon as f64 * model.dt);
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
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
    } else {
        print_summary(&summary);
        println!("plot: {}", png.display());
        println!("log:  {} ({log_bytes} bytes, {} messages; open it in Foxglove)", mcap.display(), stats.messages);
    }
    Ok(())
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
fn monte_carlo(
    a: &Args,
    n: usize,
    model: &PincModel,
    cfg: &MpcConfig,
    scenario: &Scenario,
    vehicle: &VehicleParams,
) -> Result<(), String> {
    use pinc::closed_loop::monte_carlo::{draw, robustness, run_perturbed};
    use rayon::prelude::*;
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
    let draws: Vec<_> = (0..n as u64).map(|i| draw(vehicle, a.seed + i)).collect();
    // Each run builds its own controller: the model's nominal coefficients, never the draw's.
    let one = |d: &pinc::closed_loop::monte_carlo::Draw, oracle: bool| -> Outcome {
        let outcome = if oracle {
            let m = Rk4Vehicle { params: *vehicle, ..Rk4Vehicle::with_dt(model.dt) };
            match Mpc::new(m, cfg.clone()) {
                Ok(mut mpc) => run_perturbed(&mut mpc, scenario, d),
                Err(e) => setup_failure(d.seed, e),
            }
        } else {
            match Mpc::new(Predictor::reference(model), cfg.clone()) {
                Ok(mut mpc) => run_perturbed(&mut mpc, scenario, d),
                Err(e) => setup_failure(d.seed, e),
            }
        };
        bar.inc(1);
        outcome
    };
    let (pinc, oracle): (Vec<Outcome>, Vec<Outcome>) =
        pool.install(|| draws.par_iter().map(|d| (one(d, false), one(d, true))).unzip());
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
    println!("{n} perturbed runs of scenario {} (seeds {}..{})", scenario.name(), a.seed, a.seed + n as u64 - 1);
    println!("{:<28} {:>26} {:>26}", "", "PINC", "oracle");
    println!("{:<28} {:>25.1}% {:>25.1}%", "success rate", 100.0 * rp.success_rate, 100.0 * ro.success_rate);
    let spread = |s: &pinc::closed_loop::monte_carlo::Spread, f: f64| {
        format!("{:.3} / {:.3} / {:.3}", s.median * f, s.p95 * f, s.max * f)
    };
    println!(
        "{:<28} {:>26} {:>26}",
        "RMS depth, cm (med/p95/max)",
        spread(&rp.rms_depth_m, 100.0),
        spread(&ro.rms_depth_m, 100.0)
    );
    println!(
        "{:<28} {:>26} {:>26}",
        "RMS heading, deg",
        spread(&rp.rms_heading_deg, 1.0),
        spread(&ro.rms_heading_deg, 1.0)
    );
    println!("{:<28} {:>26.3} {:>26.3}", "solve time p99, ms", rp.solve_ms_p99, ro.solve_ms_p99);
    for (name, r) in [("PINC", &rp), ("oracle", &ro)] {
        for (seed, why) in r.failures.iter().take(10) {
            println!("  {name} failed, seed {seed}: {why}");
        }
        if r.failures.len() > 10 {
            println!("  ... and {} more {name} failures (all in {})", r.failures.len() - 10, json_path.display());
        }
    }
    println!("histogram: {}\nfigures:   {}", png.display(), json_path.display());
    Ok(())
}

/// A controller that cannot be built from a configuration that built before is a bug, but a
/// Monte-Carlo batch reports it as that run's failure rather than stopping.
fn setup_failure(seed: u64, e: pinc::mpc::MpcError) -> Outcome {
    Outcome {
        seed,
        success: false,
        failure: Some(format!("controller set-up: {e}")),
        rms_depth_m: f64::INFINITY,
        rms_heading_deg: f64::INFINITY,
        solve_ms: Vec::new(),
    }
}

/// Histograms (as step outlines) of the runs' RMS depth and heading errors, both controllers.
fn histogram(path: &Path, pinc: &[Outcome], oracle: &[Outcome], n: usize) -> Result<(), String> {
    let bins = 30usize.min(n.max(5));
    let outline = |values: Vec<f64>, (lo, hi): (f64, f64)| -> Vec<(f64, f64)> {
        let w = (hi - lo) / bins as f64;
        let mut counts = vec![0usize; bins];
        for v in values.into_iter().filter(|v| v.is_finite()) {
            counts[(((v - lo) / w) as usize).min(bins - 1)] += 1;
        }
        let mut pts = vec![(lo, 0.0)];
        for (i, c) in counts.iter().enumerate() {
            pts.push((lo + i as f64 * w, *c as f64));
            pts.push((lo + (i + 1) as f64 * w, *c as f64));
        }
        pts.push((hi, 0.0));
        pts
    };
    // The range of both controllers' finite values, widened by 5 % on each side.
    let range = |f: &dyn Fn(&Outcome) -> f64| {
        let v: Vec<f64> = pinc.iter().chain(oracle).map(f).filter(|v| v.is_finite()).collect();
        let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        let pad = 0.05 * (hi - lo).max(1e-9);
        if lo.is_finite() { ((lo - pad).max(0.0), hi + pad) } else { (0.0, 1.0) }
    };
    let mut panels = Vec::new();
    type Measure = fn(&Outcome) -> f64;
    let quantities: [(&str, &str, Measure); 2] = [
        ("RMS depth error per run", "cm", |o| o.rms_depth_m * 100.0),
        ("RMS heading error per run", "deg", |o| o.rms_heading_deg),
    ];
    for (title, unit, f) in quantities {
        let span = range(&f);
        panels.push(Panel {
            title,
            x_label: unit,
            y_label: "runs",
            log_y: false,
            series: vec![
                Series { label: "PINC", points: outline(pinc.iter().map(f).collect(), span), color: 0, dashed: false },
                Series {
                    label: "oracle",
                    points: outline(oracle.iter().map(f).collect(), span),
                    color: 1,
                    dashed: true,
                },
            ],
        });
    }
    figure(path, 1400, 560, 2, &panels)
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
