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
    let trains: Vec<&pinc::dataset::TrajectorySet> = folders.iter().filter_map(|d| d.set("train")).collect();
    let shown: Vec<String> = a.data.iter().map(|d| d.display().to_string()).collect();
    let shown = shown.join(", ");
    let id = identify(&trains, &base).map_err(|e| format!("{shown}: {e}"))?;
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
