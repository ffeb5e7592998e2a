//! The tracks of closed-loop runs seen from above, from their MCAP logs: each run's state
//! (`/vehicle/state` x, y: pinc's estimate, in the autopilot's local frame on a vehicle) and
//! the first run's horizontal goal (`/mpc/reference` north, east), one PNG.
//!
//! ```sh
//! cargo run --release --features tools --example track_plot -- docs/survey_track.png \
//!     "pinc=out/pinc/mpc_survey_oracle.mcap" "ArduSub GUIDED=out/guided/mpc_survey_guided.mcap"
//! ```

use pinc::plot::{Panel, Series, figure};
use std::path::Path;

/// `(east, north)` of the state and of the goal, in log order.
type Tracks = (Vec<(f64, f64)>, Vec<(f64, f64)>);

fn tracks(path: &Path) -> Result<Tracks, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let stream = mcap::MessageStream::new(&bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    let (mut state, mut goal) = (Vec::new(), Vec::new());
    for message in stream {
        let m = message.map_err(|e| format!("{}: {e}", path.display()))?;
        let topic = m.channel.topic.as_str();
        if topic != "/vehicle/state" && topic != "/mpc/reference" {
            continue;
        }
        let v: serde_json::Value =
            serde_json::from_slice(&m.data).map_err(|e| format!("{}: {topic}: {e}", path.display()))?;
        if topic == "/vehicle/state" {
            if let (Some(x), Some(y)) = (v["network"]["x"].as_f64(), v["network"]["y"].as_f64()) {
                state.push((y, x));
            }
        } else if let (Some(n), Some(e)) = (v["north_m"].as_f64(), v["east_m"].as_f64()) {
            goal.push((e, n));
        }
    }
    Ok((state, goal))
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some((out, runs)) = args.split_first().filter(|(_, r)| !r.is_empty()) else {
        return Err("usage: track_plot OUT.png LABEL=RUN.mcap [LABEL=RUN.mcap ...]".into());
    };
    let mut series = Vec::new();
    let mut path_drawn = false;
    for (i, run) in runs.iter().enumerate() {
        let (label, file) = run.split_once('=').ok_or_else(|| format!("{run}: not LABEL=RUN.mcap"))?;
        let (state, goal) = tracks(Path::new(file))?;
        if !path_drawn && !goal.is_empty() {
            series.push(Series { label: "path (the goal)", points: goal, color: 6, dashed: true });
            path_drawn = true;
        }
        series.push(Series { label, points: state, color: i, dashed: false });
    }
    let panel = Panel {
        title: "tracks from above (each run's state estimate, in the autopilot's local frame)",
        x_label: "east (m)",
        y_label: "north (m)",
        log_y: false,
        series,
    };
    figure(Path::new(out), 900, 900, 1, &[panel]).map_err(|e| e.to_string())?;
    println!("{out}");
    Ok(())
}
