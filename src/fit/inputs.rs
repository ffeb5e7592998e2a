//! What a fit reads: each recording by its extension (MAVLink, or a `.BIN`'s streams) and the
//! starting vehicle file. Apart because it is the only stage that touches the files; the
//! others work on what it read.

use super::FitError;
use super::settings::FitSettings;
use crate::dataset::import::mavlink_log;
use crate::vehicle::{Thrusters, VehicleParams};
use std::path::{Path, PathBuf};

/// One recording as read.
pub(super) struct Log {
    pub(super) path: PathBuf,
    pub(super) sha256: String,
    pub(super) content: Content,
    /// Where it was cut off, if it was.
    pub(super) cut: Option<crate::dataset::import::McapCut>,
}

/// A recording's MAVLink messages (`.tlog`, pinc's MCAP), or the streams of an ArduPilot
/// `.BIN`.
pub(super) enum Content {
    Mavlink(Vec<(u64, u8, mavlink::dialects::ardupilotmega::MavMessage)>),
    Streams(Box<crate::dataset::import::StreamSet>),
}

/// Reads a recording by its extension (through a `.partial`): `.tlog` and `.mcap` as
/// MAVLink, `.bin` as an ArduPilot dataflash log (its thruster outputs through `thrusters`);
/// where a cut-off MCAP ended.
pub(super) fn read_recording(
    path: &Path,
    thrusters: &Thrusters,
    water_density: f64,
) -> Result<(Content, Option<crate::dataset::import::McapCut>), String> {
    use crate::dataset::import::{ArdupilotOptions, InputSource, read_bin};
    match crate::dataset::import::log_extension(path).as_deref() {
        Some("tlog" | "mcap") => {
            mavlink_log(path).map(|l| (Content::Mavlink(l.messages), l.cut)).map_err(|e| e.to_string())
        }
        Some("bin") => {
            let t = thrusters.clone();
            let options = ArdupilotOptions {
                inputs: InputSource::ThrusterOutputs,
                thrusters: Some(Box::new(move |c: &[f64]| t.input_from_commands(c))),
                water_density,
                ..ArdupilotOptions::default()
            };
            read_bin(path, &options).map(|s| (Content::Streams(Box::new(s)), None)).map_err(|e| e.to_string())
        }
        _ => Err("a recording is a .tlog, a pinc MCAP (`pinc vehicle excite` / `record`) or an ArduPilot .BIN".into()),
    }
}

/// The starting vehicle file: its coefficients, its thrusters, and the thrusters' tables as
/// TOML that stands alone.
pub(super) fn starting_vehicle(settings: &FitSettings) -> Result<(VehicleParams, Thrusters, String), FitError> {
    let vehicle_err = |message: String| FitError::Input { path: settings.vehicle.clone(), message };
    let base = VehicleParams::load(&settings.vehicle).map_err(|e| vehicle_err(e.to_string()))?;
    let thrusters = Thrusters::load(&settings.vehicle).map_err(|e| vehicle_err(e.to_string()))?;
    let thrusters_toml =
        crate::vehicle::standalone_thruster_tables(&settings.vehicle).map_err(|e| vehicle_err(e.to_string()))?;
    Ok((base, thrusters, thrusters_toml))
}
