//! `pinc fit`: recordings of a vehicle to a model that flies it, with its report (docs/FIT.md).

use indicatif::{ProgressBar, ProgressStyle};
use pinc::fit::{FitSettings, Stage, fit, report, stage_text};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Arguments of `pinc fit`.
#[derive(clap::Args)]
pub struct FitArgs {
    /// A recording of the vehicle: a `.tlog` (QGroundControl, MAVProxy), the MCAP of `pinc
    /// vehicle excite` / `record`, or the autopilot's `.BIN`. Repeat for several; a stock
    /// vehicle's (no velocities) is fine: the estimator gives them.
    #[arg(long = "recording", required = true)]
    pub recordings: Vec<PathBuf>,
    /// The starting vehicle file: its thrusters, mass and inertia, and the values of what the
    /// recordings cannot determine.
    #[arg(long)]
    pub vehicle: PathBuf,
    /// Output folder (written whole or not at all): vehicle.toml, model.pinc, report.md,
    /// report.json, report.png, training.csv.
    #[arg(long)]
    pub out: PathBuf,
    /// Training epochs of the hybrid (its whole budget: the schedule follows them).
    #[arg(long, default_value_t = FitSettings::new(Vec::new(), PathBuf::new()).epochs)]
    pub epochs: usize,
    /// Seed of the split's collocation times, the initialisation and the batches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Stop training after this many minutes whatever the epochs (the report says so; the
    /// model then depends on the machine's speed).
    #[arg(long)]
    pub time_cap: Option<f64>,
    /// Sample period of the model (s).
    #[arg(long, default_value_t = pinc::DEFAULT_DT)]
    pub dt: f64,
    /// Hidden layers of the correction.
    #[arg(long, default_value_t = 2)]
    pub layers: usize,
    /// Neurons per hidden layer of the correction.
    #[arg(long, default_value_t = 32)]
    pub width: usize,
    /// Surface pressure (hPa) for depth from pressure.
    #[arg(long, default_value_t = 1013.25)]
    pub surface_pressure: f64,
    /// Water density (kg/m^3) for depth from pressure.
    #[arg(long, default_value_t = 1000.0)]
    pub water_density: f64,
    /// A vehicle file scored on the same held-out windows beside the fit (a simulator's own
    /// file, an earlier fit), for comparison only: nothing of it enters the fit.
    #[arg(long, value_name = "FILE")]
    pub reference: Option<PathBuf>,
    /// Where each prediction starts, for the identification, the training and the held-out
    /// figures: `smoothed` (the smoothed estimate, the targets' own states) or `estimated`
    /// (the filter's estimate as it was at that point: what a controller starts from).
    #[arg(long, value_enum, default_value = "smoothed")]
    pub start: pinc::fit::FitStart,
    /// Fit nothing: replay `pinc vehicle excite`'s watch over the recording (one, `.tlog` or
    /// MCAP) with a look every this many seconds of it (the first at twice that): when the
    /// fit's report would have passed, and since when each coefficient was determined.
    #[arg(long, value_name = "SECONDS")]
    pub watch_every: Option<f64>,
    /// Print the report as JSON (no progress display).
    #[arg(long)]
    pub json: bool,
}

pub fn run_fit(a: FitArgs) -> Result<(), String> {
    let mut settings = FitSettings::new(a.recordings.clone(), a.vehicle.clone());
    settings.epochs = a.epochs;
    settings.seed = a.seed;
    settings.time_cap_s = a.time_cap.map(|m| m * 60.0);
    settings.dt = a.dt;
    settings.layers = a.layers;
    settings.width = a.width;
    settings.surface_pressure = a.surface_pressure;
    settings.water_density = a.water_density;
    settings.reference = a.reference.clone();
    settings.start = a.start;
    if let Some(every) = a.watch_every {
        return run_watch_replay(&settings, every, a.json);
    }
    let command = std::env::args().map(|s| if s.contains(' ') { format!("{s:?}") } else { s }).collect::<Vec<_>>();
    let command = command.join(" ");
    let interrupt = Arc::new(AtomicBool::new(false));
    {
        let flag = interrupt.clone();
        let _ = ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed));
    }
    let bar = if a.json { ProgressBar::hidden() } else { ProgressBar::new_spinner() };
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let epoch_style = ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} epochs ({elapsed}, ETA {eta})")
        .expect("static template")
        .progress_chars("=> ");
    let on_stage = |stage: Stage| {
        if let Stage::Train(n) = stage {
            bar.set_style(epoch_style.clone());
            bar.set_length(n as u64);
        }
        bar.set_message(stage_text(&stage));
    };
    let on_epoch = |r: &pinc::train::EpochRecord| {
        bar.set_position(r.epoch as u64);
        bar.set_message(format!("training the hybrid (dev VPT {:.2} s)", r.dev_vpt));
    };
    let result = fit(&settings, &interrupt, on_stage, on_epoch).map_err(|e| e.to_string());
    bar.finish_and_clear();
    let result = result?;
    if interrupt.load(Ordering::Relaxed) {
        return Err("interrupted: nothing written".into());
    }
    let written = report::write(&result, &a.out, &command).map_err(|e| e.to_string())?;
    if a.json {
        let text = std::fs::read_to_string(&written.report_json).map_err(|e| e.to_string())?;
        let mut v: serde_json::Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
        v["files"] = serde_json::to_value(&written).map_err(|e| e.to_string())?;
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
        return Ok(());
    }
    print!("{}", std::fs::read_to_string(&written.report_md).map_err(|e| e.to_string())?);
    println!(
        "\n-> {} (model.pinc: `mpc_track --connect URL --model {}` needs no other flag)",
        written.folder.display(),
        written.model.display()
    );
    Ok(())
}

/// `pinc fit --watch-every S`: the excite's watch replayed over one recording.
fn run_watch_replay(settings: &FitSettings, every: f64, json: bool) -> Result<(), String> {
    if !(every.is_finite() && every > 0.0) {
        return Err(format!("--watch-every must be a positive number of seconds, got {every}"));
    }
    let [path] = settings.recordings.as_slice() else {
        return Err("--watch-every replays one recording (a .tlog or a pinc MCAP)".into());
    };
    let log = pinc::dataset::import::mavlink_log(path).map_err(|e| e.to_string())?;
    let mut looks = Vec::new();
    let progress = pinc::fit::watch::replay(settings, &log.messages, every, |look| match look {
        Ok(v) => {
            if !json {
                println!("{}", v.line());
            }
            looks.push(serde_json::json!({"at_s": v.at, "passes": v.passes(), "axes": v.findings.axes,
                "warnings": v.findings.warnings}));
        }
        Err(e) => {
            if !json {
                println!("the fit cannot look yet: {e}");
            }
            looks.push(serde_json::json!({"error": e}));
        }
    });
    let first_pass = looks.iter().find(|l| l["passes"] == true).and_then(|l| l["at_s"].as_f64());
    if json {
        let v = serde_json::json!({"recording": path.display().to_string(), "every_s": every, "looks": looks,
            "passes_from_s": first_pass, "determined_since_s": progress.since});
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
    } else if let Some(line) = progress.summary() {
        println!("{line}");
    }
    Ok(())
}
