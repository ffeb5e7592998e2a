//! `pinc thrusters`: a vehicle file's thrusters, their allocation matrix and the body inputs
//! they can give.

use pinc::vehicle::Thrusters;
use std::path::PathBuf;

/// Arguments of `pinc thrusters`.
#[derive(clap::Args)]
pub struct ThrustersArgs {
    /// The vehicle file with [[thruster]] tables.
    #[arg(long)]
    pub vehicle: PathBuf,
    /// Print JSON (thrusters, matrix rows X Y Z K M N, the reachable box).
    #[arg(long)]
    pub json: bool,
}

const WRENCH: [&str; 6] = ["X", "Y", "Z", "K", "M", "N"];

pub fn run_thrusters(a: ThrustersArgs) -> Result<(), String> {
    let t = Thrusters::load(&a.vehicle).map_err(|e| e.to_string())?;
    let b = t.allocation_matrix();
    let (lo, hi) = t.input_bounds();
    if a.json {
        let thrusters: Vec<serde_json::Value> = t
            .list
            .iter()
            .map(|th| {
                let (min, max) = th.thrust_range();
                serde_json::json!({
                    "name": th.name, "channel": th.channel, "position_m": th.position,
                    "direction": th.direction, "reversed": th.reversed, "curve": th.curve.name,
                    "thrust_min_n": min, "thrust_max_n": max, "deadband": [th.curve.deadband.0, th.curve.deadband.1],
                    "mix": th.mix,
                })
            })
            .collect();
        let rows: serde_json::Map<String, serde_json::Value> =
            WRENCH.iter().enumerate().map(|(i, n)| (n.to_string(), b.row(i).iter().copied().collect())).collect();
        let v = serde_json::json!({
            "vehicle": a.vehicle.display().to_string(),
            "thrusters": thrusters,
            "allocation_matrix": rows,
            "input_min": {"X": lo[0], "Y": lo[1], "Z": lo[2], "Mz": lo[3]},
            "input_max": {"X": hi[0], "Y": hi[1], "Z": hi[2], "Mz": hi[3]},
        });
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
        return Ok(());
    }
    println!("{}: {} thrusters", a.vehicle.display(), t.list.len());
    println!(
        "{:<6} {:>3} {:>26} {:>26} {:>14} {:>11}",
        "name", "ch", "position m (FRD)", "direction (FRD)", "thrust N", "deadband"
    );
    for th in &t.list {
        let (min, max) = th.thrust_range();
        let v3 = |v: [f64; 3]| format!("({:+.3}, {:+.3}, {:+.3})", v[0], v[1], v[2]);
        println!(
            "{:<6} {:>3} {:>26} {:>26} {:>14} {:>11}{}",
            th.name,
            th.channel,
            v3(th.position),
            v3(th.direction),
            format!("{min:.1}..{max:.1}"),
            format!("{}..{}", th.curve.deadband.0, th.curve.deadband.1),
            if th.reversed { " reversed" } else { "" }
        );
    }
    println!("\nallocation matrix (rows X Y Z K M N: N and N m per N of thrust; columns the thrusters):");
    for (i, name) in WRENCH.iter().enumerate() {
        let row: Vec<String> = b.row(i).iter().map(|v| format!("{v:+8.4}")).collect();
        let note = if matches!(i, 3 | 4) { "   (roll, pitch: reported, not modelled)" } else { "" };
        println!("  {name}  {}{note}", row.join(" "));
    }
    println!("\nreachable with the least-norm allocation, each input alone:");
    for (j, (name, unit)) in [("X", "N"), ("Y", "N"), ("Z", "N"), ("Mz", "N m")].iter().enumerate() {
        println!("  {name:<3} {:>8.2} .. {:>7.2} {unit}", lo[j], hi[j]);
    }
    Ok(())
}
