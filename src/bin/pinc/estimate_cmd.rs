//! `pinc estimate`: the state estimator on a recorded `.tlog` (a stock vehicle's log has no
//! body velocities), forward and then smoothed backward, written as pinc's CSV log
//! (`t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz`) that `pinc dataset import` reads.

use pinc::dataset::import::mavlink_log;
use pinc::estimation::NoiseSettings;
use pinc::estimation::replay::{ReplaySettings, replay};
use pinc::vehicle::{Rk4Vehicle, Thrusters, VehicleParams};
use serde_json::json;
use std::io::Write;
use std::path::PathBuf;

/// Arguments of `pinc estimate`.
#[derive(clap::Args)]
pub struct EstimateArgs {
    /// The recorded log: a QGroundControl / MAVProxy `.tlog`, or a `pinc vehicle record` /
    /// `excite` MCAP (its /mavlink/* messages).
    #[arg(long)]
    pub log: PathBuf,
    /// Vehicle file: its analytic vehicle is the process model, its [[thruster]] tables turn
    /// SERVO_OUTPUT_RAW into the applied input.
    #[arg(long)]
    pub vehicle: PathBuf,
    /// Output CSV (pinc's log format: `pinc dataset import` reads it).
    #[arg(long)]
    pub out: PathBuf,
    /// Sample period of the estimate (s).
    #[arg(long, default_value_t = pinc::DEFAULT_DT)]
    pub dt: f64,
    /// Write the filter's estimate as it was at each sample, not smoothed.
    #[arg(long)]
    pub no_smooth: bool,
    /// Surface pressure (hPa) for depth from pressure.
    #[arg(long, default_value_t = 1013.25)]
    pub surface_pressure: f64,
    /// Water density (kg/m^3) for depth from pressure.
    #[arg(long, default_value_t = 1000.0)]
    pub water_density: f64,
    /// Standard deviation of the depth sensor (m).
    #[arg(long, default_value_t = NoiseSettings::default().depth_std)]
    pub depth_std: f64,
    /// Leave LOCAL_POSITION_NED out: what a vehicle without a position source would have
    /// known (to compare with a log that has one).
    #[arg(long)]
    pub ignore_position: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// What such data determine: with a position source, every coefficient; without one, the
/// surge and sway velocities are the model's own, so only heave and yaw can be identified.
fn determinable(horizontal: bool) -> (Vec<&'static str>, Vec<&'static str>) {
    let heave_yaw = vec!["volume", "z_wd", "z_w", "z_ww", "n_rd", "n_r", "n_rr"];
    let surge_sway = vec!["x_ud", "y_vd", "x_u", "y_v", "x_uu", "y_vv"];
    if horizontal { ([heave_yaw, surge_sway].concat(), Vec::new()) } else { (heave_yaw, surge_sway) }
}

pub fn run_estimate(a: EstimateArgs) -> Result<(), String> {
    if !(a.dt.is_finite() && a.dt > 0.0) {
        return Err(format!("--dt must be a positive number of seconds, got {}", a.dt));
    }
    let noise = NoiseSettings { depth_std: a.depth_std, ..NoiseSettings::default() };
    noise.validate()?;
    let params = VehicleParams::load(&a.vehicle).map_err(|e| e.to_string())?;
    let thrusters = Thrusters::load(&a.vehicle).map_err(|e| e.to_string())?;
    let log = mavlink_log(&a.log).map_err(|e| e.to_string())?;
    let settings = ReplaySettings {
        dt: a.dt,
        surface_pressure: a.surface_pressure,
        water_density: a.water_density,
        noise,
        ignore_position: a.ignore_position,
    };
    let model = Rk4Vehicle { params, ..Rk4Vehicle::with_dt(a.dt) };
    let run =
        replay(&log.messages, model, Some(thrusters), &settings).map_err(|e| format!("{}: {e}", a.log.display()))?;
    let steps = if a.no_smooth { &run.filtered } else { &run.smoothed };
    let horizontal = run.horizontal;
    // The input of each row: what the filter applied until the next row (the mean of the
    // outputs reported in the step), held over the end of a run.
    let partial = a.out.with_extension("csv.partial");
    let file = std::fs::File::create(&partial).map_err(|e| format!("{}: {e}", partial.display()))?;
    let mut w = std::io::BufWriter::new(file);
    let io = |e: std::io::Error| format!("{}: {e}", partial.display());
    writeln!(w, "t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz").map_err(io)?;
    let mut last_u = pinc::Input::zeros();
    for s in steps {
        last_u = s.input.unwrap_or(last_u);
        let x = s.state;
        writeln!(
            w,
            "{:.3},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}",
            s.t, x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], last_u[0], last_u[1], last_u[2], last_u[3]
        )
        .map_err(io)?;
    }
    w.flush().map_err(io)?;
    drop(w);
    std::fs::rename(&partial, &a.out).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let (can, cannot) = determinable(horizontal);
    let mean_std = |i: usize| steps.iter().map(|s| s.std[i]).sum::<f64>() / steps.len() as f64;
    let report = json!({
        "log": a.log.display().to_string(), "out": a.out.display().to_string(), "samples": steps.len(),
        "span_s": [steps[0].t, steps[steps.len() - 1].t], "smoothed": !a.no_smooth,
        "position_source": horizontal, "restarts": run.restarts, "late": run.late,
        "damaged_frames": log.damaged, "torn_last_frame": log.torn,
        "cut": log.cut.map(|c| json!({"byte": c.byte, "length": c.length, "last_log_time_s": c.last_log_time.map(|t| t as f64 * 1e-9), "text": c.to_string()})),
        "mean_std": {"z": mean_std(2), "u": mean_std(4), "v": mean_std(5), "w": mean_std(6), "r": mean_std(7)},
        "identifiable": can, "not_identifiable": cannot,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?);
    } else {
        println!(
            "{} samples at {} s over {:.1}-{:.1} s ({}) -> {}",
            steps.len(),
            a.dt,
            steps[0].t,
            steps[steps.len() - 1].t,
            if a.no_smooth { "filtered" } else { "smoothed" },
            a.out.display()
        );
        if let Some(c) = &log.cut {
            println!("{}: {c}", a.log.display());
        }
        println!(
            "mean std: z {:.3} m, u {:.3} v {:.3} w {:.3} m/s, r {:.4} rad/s",
            mean_std(2),
            mean_std(4),
            mean_std(5),
            mean_std(6),
            mean_std(7)
        );
        if horizontal {
            println!("a position source was fused: every coefficient can be identified from this estimate");
        } else {
            println!(
                "no position source: u and v are the model's own (driven by the thrust), so `pinc identify` on this \
                 estimate determines heave and yaw ({}) and not surge and sway ({}: they would echo the vehicle file)",
                can.join(", "),
                cannot.join(", ")
            );
        }
    }
    Ok(())
}
