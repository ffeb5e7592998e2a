//! `pinc vpt-sweep`: mean valid prediction time against the sample period, for one or more
//! models on the same freshly generated sets (the preset's test excitation at each period).

use crate::{PresetName, load_model, load_vehicle};
use indicatif::{ProgressBar, ProgressStyle};
use pinc::dataset::generate_set;
use pinc::eval::vpt;
use pinc::plot::{Panel, Series, figure};
use pinc::runtime::Predictor;
use std::path::PathBuf;

/// Arguments of `pinc vpt-sweep`.
#[derive(clap::Args)]
pub struct SweepArgs {
    /// A .pinc model (repeat for several; each is labelled by its file stem).
    #[arg(long, required = true)]
    pub model: Vec<PathBuf>,
    /// Preset whose test set (`dev_eval`: initial states and excitation) is generated at each period.
    #[arg(long, value_enum, default_value = "paper")]
    pub preset: PresetName,
    /// Seed of the generated sets.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Trajectories per period.
    #[arg(long, default_value_t = 200)]
    pub count: usize,
    /// Shortest sample period (s).
    #[arg(long, default_value_t = 0.04)]
    pub t_min: f64,
    /// Longest sample period (s).
    #[arg(long, default_value_t = 0.12)]
    pub t_max: f64,
    /// Spacing of the periods (s).
    #[arg(long, default_value_t = 0.01)]
    pub t_step: f64,
    /// Vehicle the sets are simulated with [default: the first model's].
    #[arg(long)]
    pub vehicle: Option<PathBuf>,
    /// Plot path.
    #[arg(long, default_value = "vpt_sweep.png")]
    pub out: PathBuf,
    /// Print JSON: `periods_s`, `max_vpt_s`, and per model `vpt_s` (parallel to the periods).
    #[arg(long)]
    pub json: bool,
}

/// The periods `t_min, t_min + t_step, ..., <= t_max` (rounded to the microsecond).
fn periods(a: &SweepArgs) -> Result<Vec<f64>, String> {
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if !(ok(a.t_min) && ok(a.t_max) && ok(a.t_step) && a.t_min <= a.t_max) {
        return Err(format!(
            "--t-min {} --t-max {} --t-step {}: need 0 < t-min <= t-max and a positive step",
            a.t_min, a.t_max, a.t_step
        ));
    }
    let n = ((a.t_max - a.t_min) / a.t_step + 1e-9).floor() as usize + 1;
    if n > 1000 {
        return Err(format!("{n} periods: use a larger --t-step"));
    }
    Ok((0..n).map(|i| ((a.t_min + i as f64 * a.t_step) * 1e6).round() / 1e6).collect())
}

pub fn run_sweep(a: SweepArgs) -> Result<(), String> {
    if a.count == 0 {
        return Err("--count must be positive".into());
    }
    let ts = periods(&a)?;
    let models = a.model.iter().map(|p| load_model(p)).collect::<Result<Vec<_>, _>>()?;
    let vehicle = match &a.vehicle {
        Some(path) => load_vehicle(Some(path))?,
        None => models[0].vehicle,
    };
    let preset = a.preset.preset_for(vehicle);
    let template = preset.set("dev_eval").ok_or("the preset has no dev_eval set")?.clone();
    let bar = if a.json { ProgressBar::hidden() } else { ProgressBar::new((ts.len() * a.count) as u64) };
    bar.set_style(
        ProgressStyle::with_template("generating [{bar:40}] {pos}/{len} ({eta})")
            .expect("static template")
            .progress_chars("=> "),
    );
    let mut vpts = vec![Vec::with_capacity(ts.len()); models.len()];
    for &t in &ts {
        // Each period its own stream (the set name feeds the seed), so adding a period
        // leaves the others' trajectories as they were.
        let spec = pinc::dataset::SetSpec {
            name: format!("vpt_sweep_{:.0}us", t * 1e6),
            count: a.count,
            dt: t,
            collocation_points: 0,
            ..template.clone()
        };
        let set = generate_set(&spec, &vehicle, a.seed, || bar.inc(1));
        for (m, out) in models.iter().zip(&mut vpts) {
            let v = vpt(&Predictor::<f32>::new(m), &set).map_err(|e| format!("T = {t} s: {e}"))?;
            out.push(v.iter().sum::<f64>() / v.len() as f64);
        }
    }
    bar.finish_and_clear();
    let steps = (template.points - 1) as f64;
    let labels: Vec<String> =
        a.model.iter().map(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()).collect();
    let mut series: Vec<Series> = labels
        .iter()
        .zip(&vpts)
        .enumerate()
        .map(|(i, (label, v))| Series {
            label,
            points: ts.iter().copied().zip(v.iter().copied()).collect(),
            color: i,
            dashed: false,
        })
        .collect();
    let cap = format!("longest possible ({} T)", steps);
    series.push(Series { label: &cap, points: ts.iter().map(|&t| (t, steps * t)).collect(), color: 7, dashed: true });
    let title = format!("mean VPT, {} trajectories per period, seed {}", a.count, a.seed);
    let panel = Panel { title: &title, x_label: "sample period T (s)", y_label: "VPT (s)", log_y: false, series };
    figure(&a.out, 900, 560, 1, &[panel]).map_err(|e| format!("plot {}: {e}", a.out.display()))?;
    if a.json {
        let per_model: serde_json::Map<String, serde_json::Value> =
            labels.iter().zip(&vpts).map(|(l, v)| (l.clone(), serde_json::json!(v))).collect();
        let out = serde_json::json!({
            "periods_s": ts,
            "max_vpt_s": ts.iter().map(|t| steps * t).collect::<Vec<_>>(),
            "vpt_s": per_model,
            "seed": a.seed,
            "count": a.count,
            "plot": a.out.display().to_string(),
        });
        println!("{}", serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?);
    } else {
        print!("{:>8}", "T s");
        for l in &labels {
            print!(" {l:>14}");
        }
        println!();
        for (i, t) in ts.iter().enumerate() {
            print!("{t:>8.3}");
            for v in &vpts {
                print!(" {:>14.3}", v[i]);
            }
            println!();
        }
        println!("plot: {}", a.out.display());
    }
    Ok(())
}
