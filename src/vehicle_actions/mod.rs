//! `pinc vehicle`'s actions on a live vehicle: `status`, `check`, `record`, `excite` and
//! `setup-signing`: pinc as a MAVLink participant next to an ArduSub autopilot
//! (docs/VEHICLE.md), on the link of [`crate::link`].
//!
//! One module per action; the recording's writer is shared by `record` and `excite`.

mod check;
mod excite;
mod record;
mod signing;
mod status;
mod writer;

use crate::link::Autopilot;
use crate::link::cli::{DriveArgs, LinkArgs};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// `pinc vehicle` actions.
#[derive(clap::Subcommand)]
pub enum VehicleAction {
    /// Wait for the autopilot's heartbeat and print its type, firmware, mode, armed state and
    /// which parts of the state it sends at what rates; exit 1 when nothing answers.
    Status(StatusArgs),
    /// Check the autopilot before a dive: its firmware version, and the parameters pinc and the
    /// position sensors fitted need (each with the value wanted and why); exit 1 naming each
    /// to change. With --set, save the old values to a file and set the failing ones.
    Check(CheckArgs),
    /// Record every MAVLink message, pinc's reconstructed state and the thruster outputs to
    /// an MCAP file that `pinc dataset import` reads.
    Record(RecordArgs),
    /// Play an excitation file (`pinc excitation`) open loop on the vehicle and record it as
    /// `record` does, with every safety stop (docs/VEHICLE.md).
    Excite(Box<ExciteArgs>),
    /// Give the autopilot a MAVLink 2 signing key (SETUP_SIGNING), then check that it answers
    /// signed; from then on connect with --signing-key FILE.
    SetupSigning(SetupSigningArgs),
}

/// Arguments of `pinc vehicle setup-signing`.
#[derive(clap::Args)]
pub struct SetupSigningArgs {
    /// Connection, as for the other actions (the link must not be signed yet, or signed with
    /// --signing-key, the key in force).
    #[command(flatten)]
    link: LinkArgs,
    /// The new key file: 64 hex digits, or a passphrase whose SHA-256 is the key.
    #[arg(long, value_name = "FILE")]
    key: PathBuf,
}

/// Arguments of `pinc vehicle status`.
#[derive(clap::Args)]
pub struct StatusArgs {
    #[command(flatten)]
    link: LinkArgs,
    /// Seconds over which the message rates are measured.
    #[arg(long, default_value_t = 3.0)]
    window: f64,
    /// Vehicle file: which ways of commanding reach its thrusters' outputs [default: a
    /// BlueROV2's six thrusters on outputs 1-6].
    #[arg(long)]
    vehicle: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// Arguments of `pinc vehicle check`.
#[derive(clap::Args)]
pub struct CheckArgs {
    #[command(flatten)]
    link: LinkArgs,
    /// The position sensors fitted: dvl (on MAVLink, VISION_POSITION_DELTA), usbl (fixes as a
    /// MAVLink GPS, GPS_INPUT), gps, comma-separated; or none (a stock BlueROV2).
    #[arg(long, value_delimiter = ',', default_value = "none")]
    sensors: Vec<String>,
    /// The local magnetic declination (degrees east, from a declination calculator): without
    /// an absolute position (no USBL, no GPS) COMPASS_DEC is checked against it, and --set
    /// sets it.
    #[arg(long, value_name = "DEG", allow_hyphen_values = true)]
    declination: Option<f64>,
    /// Set every failing parameter to its wanted value (each confirmed by the autopilot), after
    /// saving their old values to --backup; nothing is changed where one cannot be set.
    #[arg(long)]
    set: bool,
    /// Where --set saves the old values (ArduPilot's .parm format) [default:
    /// `pinc-params-before-<UTC time>.parm`]; an existing file is never overwritten.
    #[arg(long, value_name = "FILE", requires = "set")]
    backup: Option<PathBuf>,
    /// Set the values of a .parm file (NAME,VALUE lines, as --set saves) back, each confirmed;
    /// no check is made.
    #[arg(long, value_name = "FILE", conflicts_with = "set")]
    restore: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// Arguments of `pinc vehicle record`.
#[derive(clap::Args)]
pub struct RecordArgs {
    #[command(flatten)]
    link: LinkArgs,
    /// Output MCAP file (written as OUT.partial and renamed when complete).
    #[arg(long)]
    out: PathBuf,
    /// Seconds to record [default: until Ctrl-C].
    #[arg(long)]
    duration: Option<f64>,
    /// Vehicle file with [[thruster]] tables: the body input X,Y,Z,Mz of each state sample is
    /// rebuilt from SERVO_OUTPUT_RAW through its thrusters (for `pinc dataset import`), and the
    /// state estimate on its analytic vehicle is recorded on /estimate beside the raw state.
    #[arg(long)]
    vehicle: Option<PathBuf>,
    /// Rate (Hz) requested for SERVO_OUTPUT_RAW with --vehicle.
    #[arg(long, default_value_t = 50.0)]
    outputs_rate: f64,
}

/// Arguments of `pinc vehicle excite`.
#[derive(clap::Args)]
pub struct ExciteArgs {
    #[command(flatten)]
    link: LinkArgs,
    #[command(flatten)]
    drive: DriveArgs,
    /// Vehicle file with the thrusters' [[thruster]] tables (and their ArduSub `mix` factors
    /// for --command manual).
    #[arg(long)]
    vehicle: PathBuf,
    /// Excitation inputs: CSV with header X,Y,Z,Mz, one row per --dt (`pinc excitation`).
    #[arg(long)]
    inputs: PathBuf,
    /// Sample period of the inputs file (s).
    #[arg(long, default_value_t = crate::DEFAULT_DT)]
    dt: f64,
    /// Output MCAP file (written as OUT.partial and renamed when complete).
    #[arg(long)]
    out: PathBuf,
    /// Keep the depth inside TOP,BOTTOM (m): where the vehicle leaves the band less its outer
    /// eighths, a depth feedback sets the heave force (surge, sway and yaw go on exciting)
    /// until it is back in the middle half; `/excite/heave` says which samples it set.
    #[arg(long, value_name = "TOP,BOTTOM", value_delimiter = ',')]
    depth_band: Option<Vec<f64>>,
    /// The band feedback's gain on the depth error (N/m).
    #[arg(long, default_value_t = 60.0)]
    band_kp: f64,
    /// The band feedback's gain on the heave rate (N per m/s).
    #[arg(long, default_value_t = 40.0)]
    band_kd: f64,
    /// Play the whole file: do not stop once the watch finds every coefficient the fit needs
    /// determined.
    #[arg(long)]
    keep_going: bool,
    /// Seconds of recording between two looks of the watch (the fit's identification on the
    /// recording so far; the first look at twice this); 0 turns the watch off.
    #[arg(long, default_value_t = 30.0)]
    watch_every: f64,
}

/// Id of `SERVO_OUTPUT_RAW`.
const SERVO_OUTPUT_RAW_ID: u32 = 36;

/// Runs one `pinc vehicle` action.
pub fn run_vehicle(action: VehicleAction) -> Result<(), String> {
    match action {
        VehicleAction::Status(a) => status::run_status(a),
        VehicleAction::Check(a) => check::run_check(a),
        VehicleAction::Record(a) => record::run_record(a),
        VehicleAction::Excite(a) => excite::run_excite(*a),
        VehicleAction::SetupSigning(a) => signing::run_setup_signing(a),
    }
}

/// The session metadata every recording starts with.
fn session_metadata(a: &LinkArgs, autopilot: &Autopilot) -> BTreeMap<String, String> {
    let mut session = BTreeMap::new();
    session.insert("pinc_version".to_string(), env!("CARGO_PKG_VERSION").to_string());
    session.insert("connect".to_string(), a.connect.clone());
    session.insert("autopilot_system_id".to_string(), autopilot.system_id.to_string());
    session.insert("gcs_system_id".to_string(), a.gcs_sysid.to_string());
    session.insert("requested_rate_hz".to_string(), a.rate.to_string());
    session.insert("max_age_s".to_string(), a.max_age.to_string());
    session.insert("surface_pressure_hpa".to_string(), a.surface_pressure.to_string());
    session.insert("water_density".to_string(), a.water_density.to_string());
    session.insert("time_base".to_string(), "autopilot time_boot_ms".to_string());
    session
}

fn ctrl_c_flag() -> Result<Arc<AtomicBool>, String> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed)).map_err(|e| format!("cannot catch Ctrl-C: {e}"))?;
    Ok(stop)
}
