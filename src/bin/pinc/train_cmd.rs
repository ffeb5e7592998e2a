//! `pinc train`: progress bar, per-epoch CSV, training-curve plot, frozen best weights with
//! final metrics; Ctrl-C or a NaN loss stops cleanly and still writes the best weights.

use crate::eval_cmd::{eval_sets, print_metrics};
use crate::{PresetName, load_vehicle};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use pinc::dataset::{DatasetPreset, TrajectorySet, generate_set};
use pinc::eval::{Metrics, evaluate};
use pinc::model::Activation;
use pinc::train::curves::{EpochCsv, plot_history, read_history};
use pinc::train::{
    Backend, EpochRecord, GradCombine, LossKind, LrSchedule, MembersOutcome, StopReason, TrainConfig, TrainOutcome,
    train_members,
};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Arguments of `pinc train`.
#[derive(clap::Args)]
pub struct TrainArgs {
    /// Dataset preset (generated in memory from --seed).
    #[arg(long, value_enum, default_value = "paper")]
    pub preset: PresetName,
    /// Output .pinc file.
    #[arg(long)]
    pub out: PathBuf,
    /// Train on a dataset folder (`pinc dataset import`, or `pinc gen-data`): its train and dev
    /// splits, and the final metrics on its test split, instead of a generated preset.
    #[arg(long, conflicts_with = "preset")]
    pub data: Option<PathBuf>,
    /// With --data: what the network is fed at each point, and where rollouts start.
    /// `estimated`: the state pinc's estimator gives there from the samples before it in its
    /// run, on the --vehicle file's analytic model (docs/LOGS_CSV.md), so the correction
    /// learns what a controller will give it; the targets stay recorded. Windows with less
    /// than --start-history before them are left out; dev selection and the test figures
    /// start from the same estimates.
    #[arg(long, value_enum, default_value = "recorded", requires = "data")]
    pub start: crate::Start,
    /// With --start estimated: seconds of samples the estimator runs over before a point.
    #[arg(long, default_value_t = pinc::estimation::window_starts::DEFAULT_HISTORY_S, requires = "data")]
    pub start_history: f64,
    /// The train split's targets. `smoothed` (the default with --start estimated): its u, v,
    /// w, r the estimator's, smoothed over each run (velocities that agree with the recorded
    /// motion, where a recording's own disagree); `recorded`: as recorded. Dev selection and
    /// the test figures stay on the recorded targets.
    #[arg(long, value_enum)]
    pub targets: Option<crate::Targets>,
    /// Vehicle file: the physics losses use it (the model records it), a preset's data are
    /// simulated with it unless --plant says otherwise, and a --hybrid corrects it
    /// [default: the BlueROV2].
    #[arg(long)]
    pub vehicle: Option<PathBuf>,
    /// Train a hybrid model: the network learns a correction of --vehicle's RK4 step (an
    /// identified vehicle file, typically) instead of the whole transition, starting at zero,
    /// as the physics; selection on dev keeps the physics unless a correction beats it
    /// (docs/MODEL.md section 13).
    #[arg(long)]
    pub hybrid: bool,
    /// Vehicle file that simulates a preset's data when it is not --vehicle (a plant other
    /// than the model's physics: a perturbed BlueROV2 with the nominal one as --vehicle)
    /// [default: --vehicle].
    #[arg(long, conflicts_with = "data")]
    pub plant: Option<PathBuf>,
    /// Epochs [default: 1200].
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Trajectories per batch [default: 10].
    #[arg(long)]
    pub batch: Option<usize>,
    /// Gradient combination [default: normalize].
    #[arg(long, value_enum)]
    pub grad: Option<GradName>,
    /// Drop the physics, physics-rollout and initial-condition losses.
    #[arg(long)]
    pub no_physics: bool,
    /// Active losses, comma-separated, data first: data,physics,ic,rollout,physics_rollout [default: all].
    #[arg(long, value_delimiter = ',')]
    pub losses: Option<Vec<String>>,
    /// burn CPU backend.
    #[arg(long, value_enum, default_value = "ndarray")]
    pub backend: BackendName,
    /// Seed of data, initialisation and shuffling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Rollout-loss length [default: 20].
    #[arg(long)]
    pub rollout_steps: Option<usize>,
    /// Rollouts start at every N-th point [default: 1].
    #[arg(long)]
    pub rollout_stride: Option<usize>,
    /// Physics-loss collocation points per interval: 1 is t = T (the paper's best), more are a Latin hypercube in [0, T] [default: 1].
    #[arg(long)]
    pub collocation: Option<usize>,
    /// Initial learning rate [default: 8e-3; 1e-3 with --hybrid].
    #[arg(long)]
    pub lr: Option<f64>,
    /// Epochs without improvement of the smoothed dev loss before the rate halves [default: 100].
    #[arg(long)]
    pub patience: Option<usize>,
    /// Learning-rate schedule: reduce-on-plateau, or a cosine from --lr to 1e-4 over the
    /// budget (--time-limit, or --epochs) [default: plateau].
    #[arg(long, value_enum)]
    pub lr_schedule: Option<ScheduleName>,
    /// Measure each loss's gradient every N-th step and reuse the combination in between
    /// (one backward pass per step instead of one per loss) [default: 1].
    #[arg(long)]
    pub grad_refresh: Option<usize>,
    /// Weight of the physics, ic and physics-rollout losses (data and rollout keep 1)
    /// [default: the paper's 0.5].
    #[arg(long)]
    pub physics_weight: Option<f64>,
    /// Curriculum: the physics, ic and physics-rollout losses join after this fraction of the
    /// budget [default: 0].
    #[arg(long)]
    pub physics_after: Option<f64>,
    /// Wall-clock budget in minutes: stop after the epoch that reaches it.
    #[arg(long)]
    pub time_limit: Option<f64>,
    /// Gaussian noise sigma on the network's state and input features [default: 0].
    #[arg(long)]
    pub noise: Option<f64>,
    /// Hidden layers [default: 4].
    #[arg(long)]
    pub layers: Option<usize>,
    /// Neurons per hidden layer [default: 32].
    #[arg(long)]
    pub width: Option<usize>,
    /// Adaptive tanh instead of adaptive softplus.
    #[arg(long)]
    pub tanh: bool,
    /// Keep the position (x, y, z) out of the network input; the dynamics do not depend on
    /// it, so the model is not confined to the positions it was trained at.
    #[arg(long)]
    pub position_free: bool,
    /// Keep the heading out of the network input too: it sees the body velocities and the
    /// input only. For a hybrid's correction: the vehicle's dynamics do not depend on where it
    /// points, and a correction that could would hand the controller a heading-dependent bias.
    #[arg(long)]
    pub heading_free: bool,
    /// Use only the first N training trajectories' worth (a smaller generated set).
    #[arg(long)]
    pub train_count: Option<usize>,
    /// Dev trajectories used for selection [default: the preset's].
    #[arg(long)]
    pub dev_count: Option<usize>,
    /// Trajectories per set for the final evaluation [default: 1000].
    #[arg(long)]
    pub eval_count: Option<usize>,
    /// Train N members side by side (one thread each, each with the whole --time-limit and
    /// its own initialisation and shuffling on the same data) and keep the one with the best
    /// dev VPT; each member's curves go to OUT.memberI.csv [default: 1].
    #[arg(long, default_value_t = 1)]
    pub members: usize,
    /// Print the summary as JSON (no progress bar).
    #[arg(long)]
    pub json: bool,
}

/// A hybrid's default initial learning rate (docs/MODEL.md section 13).
const HYBRID_LR: f64 = 1e-3;

/// Gradient combination scheme names on the command line.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum GradName {
    Sum,
    Normalize,
    Config,
}

/// Learning-rate schedules on the command line.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum ScheduleName {
    Plateau,
    Cosine,
}

/// burn backends on the command line.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum BackendName {
    Ndarray,
    Flex,
}

fn config(a: &TrainArgs) -> Result<TrainConfig, String> {
    let mut cfg = TrainConfig::paper();
    if a.layers.is_some() || a.width.is_some() {
        let default = &cfg.architecture;
        cfg.architecture = pinc::model::Architecture::paper(
            a.layers.unwrap_or(default.hidden_layers),
            a.width.unwrap_or(default.width),
        );
    }
    if a.tanh {
        cfg.architecture.activation = Activation::Tanh;
    }
    if a.position_free {
        cfg.architecture.state_inputs = (3..pinc::NX as u8).collect();
    }
    if a.heading_free {
        cfg.architecture.state_inputs = (5..pinc::NX as u8).collect();
    }
    if let Some(list) = &a.losses {
        let mut keep = Vec::new();
        for name in list {
            keep.push(LossKind::from_name(name.trim()).ok_or_else(|| {
                format!("--losses: unknown loss {name:?} (data, physics, ic, rollout, physics_rollout)")
            })?);
        }
        cfg = cfg.with_losses(&keep);
    }
    if a.no_physics {
        // Drops the physics-informed terms; a data rollout loss, if active, stays.
        cfg = cfg.with_losses(&[LossKind::Data, LossKind::Rollout]);
    }
    cfg.epochs = a.epochs.unwrap_or(cfg.epochs);
    cfg.batch = a.batch.unwrap_or(cfg.batch);
    if let Some(g) = a.grad {
        cfg.grad = match g {
            GradName::Sum => GradCombine::Sum,
            GradName::Normalize => GradCombine::Normalize,
            GradName::Config => GradCombine::Config,
        };
    }
    cfg.rollout_steps = a.rollout_steps.unwrap_or(cfg.rollout_steps);
    cfg.rollout_stride = a.rollout_stride.unwrap_or(cfg.rollout_stride);
    // A correction is small: a hybrid starts slower than a PINC.
    cfg.lr = a.lr.unwrap_or(if a.hybrid { HYBRID_LR } else { cfg.lr });
    cfg.patience = a.patience.unwrap_or(cfg.patience);
    cfg.time_limit_s = a.time_limit.map(|m| m * 60.0);
    if let Some(sched) = a.lr_schedule {
        cfg.lr_schedule = match sched {
            ScheduleName::Plateau => LrSchedule::Plateau,
            ScheduleName::Cosine => LrSchedule::Cosine,
        };
    }
    cfg.grad_refresh = a.grad_refresh.unwrap_or(cfg.grad_refresh);
    if let Some(w) = a.physics_weight {
        if !(w.is_finite() && w > 0.0) {
            return Err(format!("--physics-weight {w}: need a positive number"));
        }
        for (k, weight) in cfg.losses.iter().zip(&mut cfg.weights) {
            if TrainConfig::is_physics(*k) {
                *weight = w;
            }
        }
    }
    cfg.physics_after = a.physics_after.unwrap_or(cfg.physics_after);
    cfg.input_noise = a.noise.unwrap_or(cfg.input_noise);
    cfg.backend = match a.backend {
        BackendName::Ndarray => Backend::Ndarray,
        BackendName::Flex => Backend::Flex,
    };
    cfg.seed = a.seed;
    cfg.check()?;
    Ok(cfg)
}

fn sibling(out: &Path, ext: &str) -> PathBuf {
    out.with_extension(ext)
}

pub fn run_train(a: TrainArgs) -> Result<(), String> {
    let mut cfg = config(&a)?;
    cfg.vehicle = load_vehicle(a.vehicle.as_deref())?;
    let plant = match &a.plant {
        Some(p) => load_vehicle(Some(p))?,
        None => cfg.vehicle,
    };
    let preset = a.preset.preset_for(plant);
    let folder = a.data.as_deref().map(|d| pinc::dataset::load(d).map_err(|e| e.to_string())).transpose()?;
    let (train_set, dev) = match &folder {
        Some(data) => folder_sets(&a, data, &cfg.vehicle)?,
        None => training_sets(&a, &preset)?,
    };
    if a.hybrid {
        // A correction that sees the body velocities only is anchored at rest, so the vehicle
        // at rest steps as its physics (docs/MODEL.md section 13).
        cfg.hybrid = Some(pinc::model::HybridPhysics::for_period(train_set.dt, a.heading_free));
        cfg.check()?;
    }
    let interrupt = Arc::new(AtomicBool::new(false));
    {
        let flag = interrupt.clone();
        // A second handler cannot be installed (tests call run_train once per process).
        let _ = ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed));
    }
    let csv_path = sibling(&a.out, "csv");
    let source = match &a.data {
        Some(d) => format!("pinc train --data {}", d.display()),
        None => format!("pinc train --preset {}", preset.name),
    } + if a.hybrid { " --hybrid" } else { "" }
        + if a.start == crate::Start::Estimated { " --start estimated" } else { "" };
    let all = train_with_progress(&a, &cfg, &train_set, &dev, &source, &interrupt, &csv_path)?;
    let outcome = all.best();
    report_stop(outcome);
    let physics_kept = a.hybrid && outcome.best_epoch == 0;
    if physics_kept && !a.json {
        eprintln!(
            "hybrid: no epoch's correction beat the physics clearly on dev (per-window VPT and 10-step MSE gains \
             above twice their standard error): the model is its physics, the network's output zero; more data \
             (longer or more runs) let a correction show"
        );
    }
    if a.members > 1 {
        report_members(&all, a.json);
    }
    let final_metrics = match &folder {
        Some(data) => FinalMetrics::Test(
            data.set("test")
                .filter(|s| s.count > 0)
                .map(|t| start_set(&a, data, t, &cfg.vehicle, crate::Targets::Recorded))
                .transpose()?
                .map(|t| pinc::eval::evaluate_set(&outcome.model, &t, &outcome.model.vehicle))
                .transpose()
                .map_err(|e| format!("final evaluation failed: {e}"))?,
        ),
        None => {
            let sets = eval_sets(&preset, a.seed, a.eval_count, a.json);
            FinalMetrics::Paper(evaluate(&outcome.model, &sets).map_err(|e| format!("final evaluation failed: {e}"))?)
        }
    };
    save_with_metrics(&a.out, &all, &final_metrics)?;
    let png = sibling(&a.out, "png");
    plot_history(&png, &outcome.history).map_err(|e| format!("plot {}: {e}", png.display()))?;
    if a.json {
        let mut v = serde_json::json!({
            "model": a.out.display().to_string(),
            "best_epoch": outcome.best_epoch,
            "epochs_run": outcome.history.len(),
            "train_seconds": outcome.seconds,
            "step_ms": outcome.step_ms,
            "backend": cfg.backend,
            "stop": outcome.stop,
            "members": all.members.iter().map(|m| m.model.provenance.metrics["dev_vpt_s"]).collect::<Vec<_>>(),
            "member_kept": all.chosen,
            "hybrid": a.hybrid,
            "hybrid_physics_kept": physics_kept,
            "csv": csv_path.display().to_string(),
            "plot": png.display().to_string(),
        });
        match &final_metrics {
            FinalMetrics::Paper(m) => v["metrics"] = serde_json::to_value(m).map_err(|e| e.to_string())?,
            FinalMetrics::Test(m) => v["test"] = serde_json::to_value(m).map_err(|e| e.to_string())?,
        }
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
    } else {
        println!(
            "{} epochs in {:.1} s ({:.2} ms per step, {:?} backend); best on dev: epoch {} -> {}",
            outcome.history.len(),
            outcome.seconds,
            outcome.step_ms,
            cfg.backend,
            outcome.best_epoch,
            a.out.display()
        );
        match &final_metrics {
            FinalMetrics::Paper(m) => print_metrics(&format!("seed {} eval", a.seed), m),
            FinalMetrics::Test(Some(m)) => crate::eval_cmd::print_set_metrics(m),
            FinalMetrics::Test(None) => println!("no test split to evaluate on"),
        }
        println!("metrics per epoch: {}  curves: {}", csv_path.display(), png.display());
    }
    Ok(())
}

/// Runs the training (its members side by side when there are several) with one progress
/// bar and one per-epoch CSV per member, and writes the kept member's curves to `csv_path`.
fn train_with_progress(
    a: &TrainArgs,
    cfg: &TrainConfig,
    train_set: &TrajectorySet,
    dev: &TrajectorySet,
    source: &str,
    interrupt: &AtomicBool,
    csv_path: &Path,
) -> Result<MembersOutcome, String> {
    let paths: Vec<PathBuf> = if a.members == 1 {
        vec![csv_path.to_path_buf()]
    } else {
        (0..a.members).map(|i| sibling(&a.out, &format!("member{i}.csv"))).collect()
    };
    let csvs =
        paths.iter().map(|p| EpochCsv::create(p, cfg).map(std::sync::Mutex::new)).collect::<Result<Vec<_>, _>>()?;
    let multi = MultiProgress::new();
    let style = ProgressStyle::with_template("{prefix}epoch {pos}/{len} [{bar:30}] {elapsed} (ETA {eta}) {msg}")
        .expect("static template")
        .progress_chars("=> ");
    let bars: Vec<ProgressBar> = (0..a.members)
        .map(|i| {
            let bar = if a.json { ProgressBar::hidden() } else { multi.add(ProgressBar::new(cfg.epochs as u64)) };
            bar.set_style(style.clone());
            if a.members > 1 {
                bar.set_prefix(format!("member {i} "));
            }
            bar
        })
        .collect();
    let on_epoch = |i: usize, r: &EpochRecord| {
        let losses: Vec<String> = r.train.iter().map(|(k, v)| format!("{}={v:.2e}", k.name())).collect();
        bars[i].set_message(format!(
            "{} | dev roll10 {:.2e} VPT {:.2} s | lr {:.1e}",
            losses.join(" "),
            r.dev_rollout10,
            r.dev_vpt,
            r.lr
        ));
        bars[i].inc(1);
        csvs[i].lock().expect("csv lock").row(r);
    };
    let all = train_members(cfg, a.members, train_set, dev, source, interrupt, &on_epoch).map_err(|e| e.to_string())?;
    bars.iter().for_each(ProgressBar::finish_and_clear);
    for (csv, path) in csvs.into_iter().zip(&paths) {
        if let Some(e) = csv.into_inner().expect("csv lock").error {
            eprintln!("warning: {}: {e}", path.display());
        }
    }
    if a.members > 1 {
        let mut kept = EpochCsv::create(csv_path, cfg)?;
        all.best().history.iter().for_each(|r| kept.row(r));
        if let Some(e) = kept.error {
            eprintln!("warning: {}: {e}", csv_path.display());
        }
    }
    Ok(all)
}

/// Says which member was kept and every member's dev VPT.
fn report_members(all: &MembersOutcome, json: bool) {
    if json {
        return;
    }
    for (i, m) in all.members.iter().enumerate() {
        eprintln!(
            "member {i} (seed {}): dev VPT {:.3} s at epoch {} of {}{}",
            m.model.provenance.seed,
            m.model.provenance.metrics["dev_vpt_s"],
            m.best_epoch,
            m.history.len(),
            if i == all.chosen { "  <- kept" } else { "" }
        );
    }
}

/// The preset's training and dev sets, generated from the seed, with the counts and
/// collocation points the arguments override.
fn training_sets(a: &TrainArgs, preset: &DatasetPreset) -> Result<(TrajectorySet, TrajectorySet), String> {
    let spec = |name: &str, count: Option<usize>| {
        let mut s = preset.set(name).expect("preset has train and dev sets").clone();
        if let Some(c) = count {
            s.count = c;
        }
        s
    };
    let mut train_spec = spec("train", a.train_count);
    if let Some(m) = a.collocation {
        if m == 0 {
            return Err("--collocation: at least one point per interval".into());
        }
        train_spec.collocation_points = m;
    }
    let v = &preset.vehicle;
    Ok((generate_set(&train_spec, v, a.seed, || {}), generate_set(&spec("dev", a.dev_count), v, a.seed, || {})))
}

/// `set` as `--start` asks: as recorded, or its windows with the estimator's states as starts.
fn start_set(
    a: &TrainArgs,
    data: &pinc::dataset::Dataset,
    set: &TrajectorySet,
    vehicle: &pinc::vehicle::VehicleParams,
    targets: crate::Targets,
) -> Result<TrajectorySet, String> {
    if a.start == crate::Start::Recorded {
        if targets == crate::Targets::Smoothed {
            return Err("--targets smoothed needs --start estimated (the targets come from the same filter)".into());
        }
        return Ok(set.clone());
    }
    let (starts, settings) =
        pinc::estimation::window_starts::estimated_set(data, set, vehicle, a.start_history, targets.into())
            .map_err(|e| e.to_string())?;
    if !a.json {
        eprintln!("{}", settings.describe(&starts));
    }
    Ok(starts.estimated)
}

/// The train and dev splits of a dataset folder (started as `--start` asks, on `vehicle`), cut
/// to the counts the arguments give.
fn folder_sets(
    a: &TrainArgs,
    data: &pinc::dataset::Dataset,
    vehicle: &pinc::vehicle::VehicleParams,
) -> Result<(TrajectorySet, TrajectorySet), String> {
    let dir = a.data.as_deref().expect("called with --data").display();
    let split = |name: &str, count: Option<usize>| -> Result<TrajectorySet, String> {
        let whole = data
            .set(name)
            .filter(|s| s.count > 0)
            .ok_or_else(|| format!("{dir}: the {name} split is empty (training fits on train and selects on dev)"))?;
        // The estimates before the cut: a window's history is the windows before it.
        let targets = if name == "train" { crate::targets_for(a.start, a.targets) } else { crate::Targets::Recorded };
        let mut s = start_set(a, data, whole, vehicle, targets)?;
        if let Some(c) = count.filter(|&c| c < s.count) {
            let n = s.points - 1;
            if !s.starts.is_empty() {
                s.starts.truncate(c * s.points);
            }
            s.states.truncate(c * s.points);
            s.inputs.truncate(c * n);
            s.collocation.truncate(c * n * s.collocation_points);
            s.count = c;
        }
        Ok(s)
    };
    let train = split("train", a.train_count)?;
    if let Some(m) = a.collocation.filter(|&m| m != train.collocation_points) {
        return Err(format!(
            "--collocation {m}: {dir} holds {} collocation times per interval; import it again with --collocation {m}",
            train.collocation_points
        ));
    }
    if train.collocation_points == 0 && !a.no_physics {
        return Err(format!("{dir}: the train split has no collocation times for the physics loss"));
    }
    Ok((train, split("dev", a.dev_count)?))
}

/// Says on stderr why training stopped early, if it did.
fn report_stop(outcome: &TrainOutcome) {
    match &outcome.stop {
        StopReason::Completed => {}
        StopReason::Interrupted { epoch } => {
            eprintln!("interrupted in epoch {epoch}: writing the best weights so far (epoch {})", outcome.best_epoch)
        }
        StopReason::TimeLimit { epoch } => {
            eprintln!("time limit reached after epoch {epoch}; best on dev: epoch {}", outcome.best_epoch)
        }
        StopReason::NonFiniteLoss { epoch, loss } => eprintln!(
            "the {} loss became non-finite in epoch {epoch}: training stopped; writing the best weights so far (epoch {})",
            loss.name(),
            outcome.best_epoch
        ),
    }
}

/// The metrics of the kept weights: the paper's on fresh sets of the preset, or those of a
/// dataset folder's test split (none when it has no test windows).
enum FinalMetrics {
    Paper(Metrics),
    Test(Option<pinc::eval::SetMetrics>),
}

/// The kept model written to `out` with its final metrics, the run's timing and, for
/// several members, how many there were and which was kept.
fn save_with_metrics(out: &Path, all: &MembersOutcome, metrics: &FinalMetrics) -> Result<(), String> {
    let outcome = all.best();
    let mut model = outcome.model.clone();
    let m = &mut model.provenance.metrics;
    match metrics {
        FinalMetrics::Paper(p) => m.extend(p.entries().map(|(k, v)| (k.to_string(), v))),
        FinalMetrics::Test(Some(t)) => m.extend([
            ("test_one_step_mse".to_string(), t.one_step_mse),
            ("test_rollout10_mse".to_string(), t.rollout10_mse),
            ("test_physics_mse".to_string(), t.physics_mse),
            ("test_vpt_s".to_string(), t.vpt_s),
        ]),
        FinalMetrics::Test(None) => {}
    }
    m.insert("train_seconds".into(), outcome.seconds);
    m.insert("step_ms".into(), outcome.step_ms);
    m.insert("best_epoch".into(), outcome.best_epoch as f64);
    m.insert("epochs_run".into(), outcome.history.len() as f64);
    if all.members.len() > 1 {
        m.insert("members".into(), all.members.len() as f64);
        m.insert("member_kept".into(), all.chosen as f64);
    }
    model.save(out).map_err(|e| e.to_string())
}

/// Arguments of `pinc plot-training`.
#[derive(clap::Args)]
pub struct PlotTrainingArgs {
    /// The per-epoch CSV that `pinc train` wrote beside its model.
    pub csv: PathBuf,
    /// The PNG to write [default: the CSV's path with .png].
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Redraws the training curves from the per-epoch CSV.
pub fn run_plot_training(a: PlotTrainingArgs) -> Result<(), String> {
    let history = read_history(&a.csv).map_err(|e| format!("{}: {e}", a.csv.display()))?;
    let out = a.out.unwrap_or_else(|| sibling(&a.csv, "png"));
    plot_history(&out, &history).map_err(|e| format!("plot {}: {e}", out.display()))?;
    println!("{} epochs -> {}", history.len(), out.display());
    Ok(())
}
