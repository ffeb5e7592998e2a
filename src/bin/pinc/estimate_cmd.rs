//! `pinc estimate`: the state estimator on a recorded `.tlog` (a stock vehicle's log has no
//! body velocities), forward and then smoothed backward, written as pinc's CSV log
//! (`t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz`) that `pinc dataset import` reads.

use mavlink::dialects::ardupilotmega::MavMessage;
use pinc::dataset::import::{TlogMessages, tlog_messages};
use pinc::estimation::mavlink::{MavlinkMeasurements, Observation};
use pinc::estimation::{Estimator, NoiseSettings};
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

/// The MAVLink messages a `pinc vehicle record` MCAP holds (`/mavlink/<NAME>`, JSON with the
/// sender in `header`), in log order.
#[cfg(feature = "vehicle")]
fn mcap_messages(path: &std::path::Path) -> Result<TlogMessages, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let stream = mcap::MessageStream::new(&bytes).map_err(|e| format!("{}: not an MCAP file: {e}", path.display()))?;
    let mut out = TlogMessages { messages: Vec::new(), damaged: 0, torn: false };
    for m in stream {
        let m = m.map_err(|e| format!("{}: {e}", path.display()))?;
        if !m.channel.topic.starts_with("/mavlink/") {
            continue;
        }
        // A message this build's dialect cannot read back is counted, not fatal.
        let value: serde_json::Value = match serde_json::from_slice(&m.data) {
            Ok(v) => v,
            Err(_) => {
                out.damaged += 1;
                continue;
            }
        };
        let sys = value["header"]["system_id"].as_u64().unwrap_or(0) as u8;
        match serde_json::from_value::<MavMessage>(value) {
            Ok(message) => out.messages.push((m.log_time / 1000, sys, message)),
            Err(_) => out.damaged += 1,
        }
    }
    if out.messages.is_empty() {
        return Err(format!("{}: no /mavlink/* messages (record it with `pinc vehicle record`)", path.display()));
    }
    Ok(out)
}

#[cfg(not(feature = "vehicle"))]
fn mcap_messages(path: &std::path::Path) -> Result<TlogMessages, String> {
    Err(format!("{}: reading MAVLink from MCAP needs the `vehicle` feature", path.display()))
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
    let is_mcap = a.log.extension().is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    let log = if is_mcap { mcap_messages(&a.log)? } else { tlog_messages(&a.log).map_err(|e| e.to_string())? };
    // The autopilot is the system that sends ATTITUDE.
    let autopilot = log
        .messages
        .iter()
        .find_map(|(_, sys, m)| matches!(m, MavMessage::ATTITUDE(_)).then_some(*sys))
        .ok_or_else(|| format!("{}: no ATTITUDE message: no heading, no clock to estimate on", a.log.display()))?;
    let mut measurements = MavlinkMeasurements::new(a.surface_pressure, a.water_density, Some(thrusters));
    let model = Rk4Vehicle { params, ..Rk4Vehicle::with_dt(a.dt) };
    let mut estimator = Estimator::new(model, noise).keep_history();
    let (mut now, mut next_sample, mut horizontal) = (0.0f64, f64::NEG_INFINITY, false);
    for (_, sys, message) in &log.messages {
        if *sys != autopilot || (a.ignore_position && matches!(message, MavMessage::LOCAL_POSITION_NED(_))) {
            continue;
        }
        let mut attitude_t = None;
        measurements.observe(now, message, |o| match o {
            Observation::Measured(m) => {
                horizontal |= m.observes_horizontal();
                if let pinc::estimation::Measurement::Heading { t, .. } = m {
                    attitude_t = Some(t);
                }
                estimator.measure(m);
            }
            Observation::Applied(t, u) => estimator.applied(t, u),
        });
        // ATTITUDE is the clock: a sample every dt of its time.
        if let Some(t) = attitude_t {
            now = t;
            if t >= next_sample - 1e-9 {
                estimator.advance(t).map_err(|e| format!("{}: the estimator at {t:.3} s: {e}", a.log.display()))?;
                next_sample = if estimator.started() { estimator.ekf().t() + a.dt } else { t };
            }
        }
    }
    let steps = if a.no_smooth { estimator.filtered() } else { estimator.smoothed() };
    if steps.is_empty() {
        return Err(format!(
            "{}: the estimator never started (it needs ATTITUDE and a depth: SCALED_PRESSURE2, SCALED_PRESSURE or LOCAL_POSITION_NED)",
            a.log.display()
        ));
    }
    // The input of each row: what the filter applied until the next row (the mean of the
    // outputs reported in the step), held over the end of a run.
    let partial = a.out.with_extension("csv.partial");
    let file = std::fs::File::create(&partial).map_err(|e| format!("{}: {e}", partial.display()))?;
    let mut w = std::io::BufWriter::new(file);
    let io = |e: std::io::Error| format!("{}: {e}", partial.display());
    writeln!(w, "t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz").map_err(io)?;
    let mut last_u = pinc::Input::zeros();
    for s in &steps {
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
        "position_source": horizontal, "restarts": estimator.restarts(), "late": estimator.late(),
        "damaged_frames": log.damaged, "torn_last_frame": log.torn,
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
