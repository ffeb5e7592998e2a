//! `pinc eval`: the paper's metrics on freshly generated sets, and a plot of rollouts.

use crate::{PresetName, load_model, load_vehicle};
use indicatif::{ProgressBar, ProgressStyle};
use pinc::dataset::DatasetPreset;
use pinc::eval::{
    EvalSets, Evaluated, Metrics, StartFrom, VPT_THRESHOLD_M, evaluate, evaluate_recorded, plot_rollouts,
};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `pinc eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// The .pinc model; with --data it may be given several times (one table row each).
    #[arg(long)]
    pub model: Vec<PathBuf>,
    /// Dataset preset whose evaluation sets are generated.
    #[arg(long, value_enum, default_value = "paper")]
    pub preset: PresetName,
    /// Seed of the generated sets.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Trajectories per set [default: the preset's, 1000].
    #[arg(long)]
    pub count: Option<usize>,
    /// Print JSON (keys l1..l5, vpt1..vpt3, ...).
    #[arg(long)]
    pub json: bool,
    /// Rollout plot path [default: <model stem>_eval_seed<S>.png].
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Skip the plot.
    #[arg(long)]
    pub no_plot: bool,
    /// Vehicle file the evaluation sets are simulated with [default: the vehicle the model
    /// records, which its physics loss used]; with --data, the vehicle of the models' physics
    /// residual, and its analytic model is evaluated as one more row.
    #[arg(long)]
    pub vehicle: Option<PathBuf>,
    /// Evaluate on the test split of this dataset folder (`pinc dataset import`) instead of
    /// generated sets: one-step and 10-step MSE, physics residual, VPT, for each --model and
    /// for the --vehicle file's analytic model.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// With --data: the set of the folder to evaluate on (a generated folder, `pinc gen-data`,
    /// has `dev_eval` and the VPT sets instead of a test split).
    #[arg(long, default_value = "test", requires = "data")]
    pub set: String,
    /// With --data: where predictions start. `recorded`: at the recorded states. `estimated`:
    /// at the state pinc's estimator gives at each point from the samples before it in its
    /// run (their positions, depth, heading, yaw rate and inputs; never the recorded
    /// velocities, nothing of the point itself), on the --vehicle file's analytic model (else
    /// the first model's vehicle), so every row starts from the same states; scored against
    /// the recorded states as ever. `both`: the two, and the recorded start on the estimated
    /// windows alone.
    #[arg(long, value_enum, default_value = "recorded", requires = "data")]
    pub start: StartFrom,
    /// With --start estimated|both: seconds of samples the estimator runs over before each
    /// window (windows with fewer before them are left out, and counted).
    #[arg(long, default_value_t = pinc::estimation::window_starts::DEFAULT_HISTORY_S, requires = "data")]
    pub start_history: f64,
}

/// Generates the sets with a progress bar.
pub fn eval_sets(preset: &DatasetPreset, seed: u64, count: Option<usize>, quiet: bool) -> EvalSets {
    let total: usize =
        ["dev_eval", "interp", "extrap"].iter().filter_map(|n| preset.set(n)).map(|s| count.unwrap_or(s.count)).sum();
    let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new(total as u64) };
    bar.set_style(
        ProgressStyle::with_template("generating eval sets [{bar:40}] {pos}/{len} ({eta})")
            .expect("static template")
            .progress_chars("=> "),
    );
    let sets = EvalSets::generate(preset, seed, count, || bar.inc(1));
    bar.finish_and_clear();
    sets
}

/// Prints metrics as a paper-style table row.
pub fn print_metrics(label: &str, m: &Metrics) {
    println!(
        "{:<28} {:>6} {:>6} {:>6} {:>6} {:>6} {:>7} {:>7} {:>7}",
        "", "L1", "L2", "L3", "L4", "L5", "VPT1 s", "VPT2 s", "VPT3 s"
    );
    println!(
        "{:<28} {:>6.2} {:>6.2} {:>6.2} {:>6.2} {:>6.2} {:>7.2} {:>7.2} {:>7.2}",
        label, m.l1, m.l2, m.l3, m.l4, m.l5, m.vpt1, m.vpt2, m.vpt3
    );
}

pub fn run_eval(a: EvalArgs) -> Result<(), String> {
    if let Some(dir) = &a.data {
        return eval_on_data(&a, dir);
    }
    let model_path = match a.model.as_slice() {
        [one] => one.clone(),
        [] => return Err("--model is required (without --data, the sets are generated for one model)".into()),
        _ => return Err("several --model need --data (a dataset's test split to compare them on)".into()),
    };
    let model = load_model(&model_path)?;
    let vehicle = match &a.vehicle {
        Some(path) => load_vehicle(Some(path))?,
        None => model.vehicle,
    };
    let start = Instant::now();
    let sets = eval_sets(&a.preset.preset_for(vehicle), a.seed, a.count, a.json);
    let metrics = evaluate(&model, &sets).map_err(|e| format!("evaluation failed: {e}"))?;
    let seconds = start.elapsed().as_secs_f64();
    let plot =
        (!a.no_plot).then(|| a.plot.clone().unwrap_or_else(|| default_plot(&model_path, &format!("seed{}", a.seed))));
    if let Some(path) = &plot {
        plot_rollouts(path, &model, &sets.dev).map_err(|e| format!("plot {}: {e}", path.display()))?;
    }
    if a.json {
        let mut v = serde_json::to_value(metrics).map_err(|e| e.to_string())?;
        let obj = v.as_object_mut().expect("metrics serialise to an object");
        obj.insert("model".into(), model_path.display().to_string().into());
        obj.insert("preset".into(), a.preset.preset().name.into());
        obj.insert("seed".into(), a.seed.into());
        obj.insert("trajectories_per_set".into(), sets.dev.count.into());
        obj.insert("vpt_threshold_m".into(), VPT_THRESHOLD_M.into());
        obj.insert("seconds".into(), seconds.into());
        if let Some(p) = &plot {
            obj.insert("plot".into(), p.display().to_string().into());
        }
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
    } else {
        println!(
            "{} on preset {}, seed {}, {} trajectories per set ({:.1} s)",
            model_path.display(),
            a.preset.preset().name,
            a.seed,
            sets.dev.count,
            seconds
        );
        print_metrics(&model_path.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default(), &metrics);
        if let Some(p) = &plot {
            println!("plot: {}", p.display());
        }
    }
    Ok(())
}

/// One row of `pinc eval --data`: a model or the analytic vehicle, from one kind of start.
struct Row {
    kind: &'static str,
    path: PathBuf,
    start: &'static str,
    metrics: pinc::eval::SetMetrics,
}

/// [`pinc::eval::evaluate_recorded`] of each model, and of the `--vehicle` file's analytic
/// model, on a set of a dataset folder: a table, or `--json`.
fn eval_on_data(a: &EvalArgs, dir: &Path) -> Result<(), String> {
    if a.model.is_empty() && a.vehicle.is_none() {
        return Err("--data needs a --model or a --vehicle to evaluate".into());
    }
    let data = pinc::dataset::load(dir).map_err(|e| e.to_string())?;
    let test = data.set(&a.set).filter(|s| s.count > 0).ok_or_else(|| match a.set.as_str() {
        "test" => format!("{}: the dataset has no test windows (imported with a zero test fraction?)", dir.display()),
        other => format!("{}: the dataset has no set {other:?} (or it is empty)", dir.display()),
    })?;
    let vehicle = a.vehicle.as_deref().map(|p| load_vehicle(Some(p))).transpose()?;
    let models = a.model.iter().map(|p| load_model(p).map(|m| (p, m))).collect::<Result<Vec<_>, _>>()?;
    for (path, model) in &models {
        if (test.dt - model.dt).abs() > 1e-12 {
            eprintln!("warning: the data's sample period is {} s, {}'s {} s", test.dt, path.display(), model.dt);
        }
    }
    let refs: Vec<&pinc::model::PincModel> = models.iter().map(|(_, m)| m).collect();
    let evaluation =
        evaluate_recorded(&data, &a.set, &refs, vehicle.as_ref(), a.start, a.start_history).map_err(|e| match e {
            pinc::eval::RecordedEvalError::Model { index, source } => {
                format!("{} on {}: {source}", models[index].0.display(), dir.display())
            }
            other => format!("{}: {other}", dir.display()),
        })?;
    if let Some(line) = &evaluation.estimator {
        eprintln!("{line}");
    }
    let rows: Vec<Row> = evaluation
        .rows
        .iter()
        .map(|r| {
            let (kind, path) = match r.evaluated {
                Evaluated::Model(i) => ("model", models[i].0.clone()),
                Evaluated::Vehicle => ("vehicle", a.vehicle.clone().unwrap_or_default()),
            };
            Row { kind, path, start: r.start, metrics: r.metrics }
        })
        .collect();
    let first_model = models.first().map(|(p, m)| ((*p).clone(), m.clone()));
    let plot = first_model
        .as_ref()
        .filter(|_| !a.no_plot)
        .map(|(path, model)| (a.plot.clone().unwrap_or_else(|| default_plot(path, "data")), model));
    if let Some((path, model)) = &plot {
        plot_rollouts(path, model, test).map_err(|e| format!("plot {}: {e}", path.display()))?;
    }
    let plot = plot.map(|(p, _)| p);
    if a.json {
        let mut out = Vec::new();
        for r in &rows {
            let mut v = serde_json::to_value(r.metrics).map_err(|e| e.to_string())?;
            let obj = v.as_object_mut().expect("metrics serialise to an object");
            obj.insert(r.kind.into(), r.path.display().to_string().into());
            obj.insert("data".into(), dir.display().to_string().into());
            obj.insert("vpt_threshold_m".into(), VPT_THRESHOLD_M.into());
            obj.insert("start".into(), r.start.into());
            if let (Some(p), "model") = (&plot, r.kind) {
                obj.insert("plot".into(), p.display().to_string().into());
            }
            out.push(v);
        }
        // One model alone prints its object, as before rows were added; otherwise an array.
        let v = if out.len() == 1 && a.vehicle.is_none() && a.start == StartFrom::Recorded {
            out.remove(0)
        } else {
            serde_json::Value::Array(out)
        };
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
    } else {
        println!(
            "{} set of {} ({} windows of {} points at {} s)",
            a.set,
            dir.display(),
            test.count,
            test.points,
            test.dt
        );
        print_set_rows(&rows);
        if let Some(p) = &plot {
            println!("plot: {}", p.display());
        }
    }
    Ok(())
}

/// Prints [`pinc::eval::SetMetrics`] rows as one table (the physics residual is n/a for the
/// analytic vehicle).
fn print_set_rows(rows: &[Row]) {
    println!(
        "{:<58} {:>12} {:>12} {:>12} {:>8} {:>10} {:>8}",
        "", "one-step", "10-step", "physics", "VPT s", "median s", "windows"
    );
    for r in rows {
        let m = &r.metrics;
        let name = r.path.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let label = if r.kind == "vehicle" { format!("{name} (analytic)") } else { name };
        let label = if r.start == "recorded" { label } else { format!("{label} [{}]", r.start) };
        let physics = if m.physics_mse.is_nan() { "n/a".to_string() } else { format!("{:.3e}", m.physics_mse) };
        println!(
            "{:<58} {:>12.3e} {:>12.3e} {:>12} {:>8.2} {:>10.2} {:>8}",
            label, m.one_step_mse, m.rollout10_mse, physics, m.vpt_s, m.vpt_median_s, m.windows
        );
    }
}

/// Prints [`pinc::eval::SetMetrics`] as one table row.
#[cfg_attr(not(feature = "train"), allow(dead_code))]
pub fn print_set_metrics(m: &pinc::eval::SetMetrics) {
    println!("{:>12} {:>12} {:>12} {:>8} {:>10}", "one-step", "10-step", "physics", "VPT s", "median s");
    println!(
        "{:>12.3e} {:>12.3e} {:>12.3e} {:>8.2} {:>10.2}",
        m.one_step_mse, m.rollout10_mse, m.physics_mse, m.vpt_s, m.vpt_median_s
    );
}

fn default_plot(model: &Path, what: &str) -> PathBuf {
    let stem = model.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "model".into());
    PathBuf::from(format!("{stem}_eval_{what}.png"))
}
