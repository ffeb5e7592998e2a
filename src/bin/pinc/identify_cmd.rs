//! `pinc identify`: the vehicle's coefficients from a dataset's train split.

use crate::load_vehicle;
use pinc::identify::{DOF, FIXED, identify};
use std::path::PathBuf;

/// Arguments of `pinc identify`.
#[derive(clap::Args)]
pub struct IdentifyArgs {
    /// Dataset folder (`pinc dataset import` or `pinc gen-data`); its train split is used.
    /// Repeat it to fit the train splits of several folders together.
    #[arg(long, required = true)]
    pub data: Vec<PathBuf>,
    /// Vehicle file giving m, g, rho and izz, and the values of coefficients the data do not
    /// excite [default: the BlueROV2].
    #[arg(long)]
    pub vehicle: Option<PathBuf>,
    /// Write the identified vehicle file here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print JSON: the coefficients by name, `std_err` and `rms_residual`.
    #[arg(long)]
    pub json: bool,
    /// The velocities identified from: `recorded`, or `estimated`: the states pinc's
    /// estimator gives from the samples before each point (the footing `pinc train --start
    /// estimated` and `pinc eval --start estimated` use), on the --vehicle file's model first,
    /// then on each pass's identified vehicle until no coefficient moves by 1 % (at most 6).
    #[arg(long, value_enum, default_value = "recorded")]
    pub start: crate::Start,
    /// With --start estimated: seconds of samples the estimator runs over before a point.
    #[arg(long, default_value_t = pinc::estimation::window_starts::DEFAULT_HISTORY_S)]
    pub start_history: f64,
    /// The velocities at each interval's end. `smoothed` (the default with --start
    /// estimated): the estimator's smoothed over the run, which agree with the recorded motion
    /// (the start stays the filter's, what a controller has); `recorded`: as recorded.
    #[arg(long, value_enum)]
    pub targets: Option<crate::Targets>,
}

/// Passes of estimate-then-identify at most, and the relative change of every coefficient
/// under which they stop (as `pinc fit` iterates).
const MAX_PASSES: usize = 6;
const PASS_TOLERANCE: f64 = 0.01;

/// The identification from the estimator's states, the estimator run on the vehicle the pass
/// before identified (the base first) until no coefficient moves by 1 %.
fn identify_on_estimates(
    a: &IdentifyArgs,
    folders: &[pinc::dataset::Dataset],
    base: &pinc::vehicle::VehicleParams,
) -> Result<pinc::identify::Identification, String> {
    let mut vehicle = *base;
    let mut pass = 0;
    loop {
        pass += 1;
        let mut trains = Vec::new();
        for (data, dir) in folders.iter().zip(&a.data) {
            let train = data.set("train").expect("checked by the caller");
            let (starts, settings) = pinc::estimation::window_starts::estimated_set(
                data,
                train,
                &vehicle,
                a.start_history,
                crate::targets_for(a.start, a.targets).into(),
            )
            .map_err(|e| format!("{}: {e}", dir.display()))?;
            if !a.json && pass == 1 {
                eprintln!("{}", settings.describe(&starts));
            }
            trains.push(starts.estimated);
        }
        let id = identify(&trains.iter().collect::<Vec<_>>(), &vehicle).map_err(|e| e.to_string())?;
        let moved = pinc::identify::any_moved(&vehicle, &id.vehicle, PASS_TOLERANCE);
        if !a.json {
            let r = id.rms_residual;
            eprintln!(
                "pass {pass}: RMS residual u {:.3e} m/s, v {:.3e}, w {:.3e}, r {:.3e} rad/s{}",
                r[0],
                r[1],
                r[2],
                r[3],
                if moved { "" } else { "; no coefficient moved by 1 %" }
            );
        }
        vehicle = id.vehicle;
        if !moved || pass == MAX_PASSES {
            return Ok(id);
        }
    }
}

pub fn run_identify(a: IdentifyArgs) -> Result<(), String> {
    let base = load_vehicle(a.vehicle.as_deref())?;
    let mut folders = Vec::new();
    for dir in &a.data {
        let data = pinc::dataset::load(dir).map_err(|e| e.to_string())?;
        if data.set("train").is_none_or(|s| s.count == 0) {
            return Err(format!(
                "{}: the dataset has no train windows (imported with a zero train fraction?)",
                dir.display()
            ));
        }
        folders.push(data);
    }
    let shown: Vec<String> = a.data.iter().map(|d| d.display().to_string()).collect();
    let shown = shown.join(", ");
    let recorded: Vec<&pinc::dataset::TrajectorySet> = folders.iter().filter_map(|d| d.set("train")).collect();
    let id = match a.start {
        crate::Start::Recorded if a.targets == Some(crate::Targets::Smoothed) => {
            return Err("--targets smoothed needs --start estimated (the targets come from the same filter)".into());
        }
        crate::Start::Recorded => identify(&recorded, &base).map_err(|e| format!("{shown}: {e}"))?,
        crate::Start::Estimated => identify_on_estimates(&a, &folders, &base).map_err(|e| format!("{shown}: {e}"))?,
    };
    if let Some(out) = &a.out {
        let header = format!(
            "# Identified by `pinc identify` from {} ({} sample periods of its train split).\n\
             # m, g, rho, izz from the base vehicle{}.\n",
            shown,
            id.samples,
            if id.not_identifiable.is_empty() {
                String::new()
            } else {
                format!("; not identifiable from these data, kept from the base: {}", id.not_identifiable.join(", "))
            }
        );
        // The base file's thrusters and their curves carry over: the identified file then
        // commands the vehicle (`--connect`) as the base did.
        let thrusters = match a.vehicle.as_deref() {
            Some(path) => match pinc::vehicle::standalone_thruster_tables(path).map_err(|e| e.to_string())? {
                t if t.is_empty() => t,
                t => format!("\n# The thrusters of {} (curves inline).\n{t}", path.display()),
            },
            None => String::new(),
        };
        // Written beside and renamed, so a reader never sees half a file.
        let partial = out.with_extension("toml.partial");
        std::fs::write(&partial, header + &id.vehicle.to_toml() + &thrusters)
            .and_then(|_| std::fs::rename(&partial, out))
            .map_err(|e| format!("{}: {e}", out.display()))?;
    }
    if a.json {
        let mut v = serde_json::Map::new();
        for (k, x) in id.vehicle.named() {
            v.insert(k.into(), x.into());
        }
        let mut se = serde_json::Map::new();
        for (k, _) in id.vehicle.named() {
            se.insert(k.into(), id.std_err_of(k).into());
        }
        v.insert("std_err".into(), se.into());
        let rms: serde_json::Map<String, serde_json::Value> =
            DOF.iter().zip(id.rms_residual).map(|(k, r)| (k.to_string(), r.into())).collect();
        v.insert("rms_residual".into(), rms.into());
        v.insert("not_identifiable".into(), id.not_identifiable.clone().into());
        v.insert("fixed".into(), FIXED.to_vec().into());
        v.insert("samples".into(), id.samples.into());
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
        return Ok(());
    }
    println!("{} sample periods from {shown}", id.samples);
    println!("{:<8} {:>14} {:>12} {:>14}", "", "identified", "std. error", "base");
    let base_named = base.named();
    for ((k, x), (_, b)) in id.vehicle.named().into_iter().zip(base_named) {
        let note = match id.std_err_of(k) {
            Some(se) => format!("{se:>12.4e}"),
            None if FIXED.contains(&k) => format!("{:>12}", "fixed"),
            None => format!("{:>12}", "not ident."),
        };
        println!("{k:<8} {x:>14.6} {note} {b:>14.6}");
    }
    println!(
        "RMS residual {} periods ahead: u {:.3e} m/s, v {:.3e} m/s, w {:.3e} m/s, r {:.3e} rad/s",
        pinc::identify::HORIZON,
        id.rms_residual[0],
        id.rms_residual[1],
        id.rms_residual[2],
        id.rms_residual[3]
    );
    if !id.not_identifiable.is_empty() {
        println!(
            "not identifiable (the data do not excite them; kept from the base): {}",
            id.not_identifiable.join(", ")
        );
    }
    if let Some(out) = &a.out {
        println!("vehicle file: {}", out.display());
    }
    Ok(())
}
