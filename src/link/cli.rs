//! The command-line options every program that talks to a vehicle shares (`pinc vehicle`,
//! `mpc_track --connect`), and the opening of a link from them.

use super::command::{CommandWay, Commander};
use super::drive::DriveSettings;
use super::link::{Autopilot, LinkConfig, LinkError, Received, VehicleLink};
use super::safety::SafetyLimits;
use super::signing::SigningKey;
use super::state::{StateAssembler, StateConfig};
use super::url::LinkAddress;
use crate::estimation::NoiseSettings;
use crate::vehicle::Thrusters;
use std::path::Path;
use std::time::Duration;

/// Where the autopilot is, and how to talk to it.
#[derive(clap::Args, Debug, Clone)]
pub struct LinkArgs {
    /// Connection: udpin:HOST:PORT (or udp:), udpout:HOST:PORT, tcp:HOST:PORT (or tcpout:),
    /// tcpin:HOST:PORT, serial:DEVICE:BAUD or DEVICE:BAUD.
    #[arg(long)]
    pub connect: String,
    #[command(flatten)]
    /// The rest.
    pub options: LinkOptions,
}

impl std::ops::Deref for LinkArgs {
    type Target = LinkOptions;
    fn deref(&self) -> &LinkOptions {
        &self.options
    }
}

/// How to talk to the autopilot and rebuild its state.
#[derive(clap::Args, Debug, Clone)]
pub struct LinkOptions {
    /// Seconds to wait for the autopilot's heartbeat.
    #[arg(long, default_value_t = 10.0)]
    pub timeout: f64,
    /// Rate (Hz) requested for the state messages (default: pinc's control rate, 1 / 0.08 s).
    #[arg(long, default_value_t = 1.0 / crate::DEFAULT_DT)]
    pub rate: f64,
    /// System id pinc sends from: the autopilot's SYSID_MYGCS.
    #[arg(long, default_value_t = 255)]
    pub gcs_sysid: u8,
    /// A state part older than this (s) is reported missing.
    #[arg(long, default_value_t = 0.5)]
    pub max_age: f64,
    /// Surface pressure (hPa) for depth from pressure.
    #[arg(long, default_value_t = 1013.25)]
    pub surface_pressure: f64,
    /// Water density (kg/m^3) for depth from pressure: 1000 x ArduSub's BARO_SPEC_GRAV.
    #[arg(long, default_value_t = 1000.0)]
    pub water_density: f64,
    /// MAVLink 2 signing key file (64 hex digits, or a passphrase whose SHA-256 is the key):
    /// pinc signs what it sends and drops every frame not signed with it. Give the autopilot
    /// the key first with `pinc vehicle setup-signing`.
    #[arg(long, value_name = "FILE")]
    pub signing_key: Option<std::path::PathBuf>,
}

/// How to command the vehicle, and the safety limits.
#[derive(clap::Args, Debug, Clone)]
pub struct DriveArgs {
    /// manual: MANUAL_CONTROL pilot axes in MANUAL mode, through ArduSub's mixer and pilot
    /// gain (a stock vehicle); thrusters: one PWM per thruster in RC_CHANNELS_OVERRIDE, only
    /// where every thruster's output passes its RC channel through (SERVOn_FUNCTION = RCINn),
    /// which pinc checks before sending anything.
    #[arg(long = "command", value_parser = ["manual", "thrusters"], default_value = "manual")]
    pub command_way: String,
    /// The gain on MANUAL_CONTROL [default: the autopilot's JS_GAIN_DEFAULT, read at connect;
    /// 1 where it does not answer].
    #[arg(long)]
    pub js_gain: Option<f64>,
    /// Arm the vehicle (pinc never arms without it; it disarms on a stop if it armed).
    #[arg(long)]
    pub arm: bool,
    /// Stop when deeper than this (m).
    #[arg(long)]
    pub max_depth: Option<f64>,
    /// Stop when no fresh state came for this long (s).
    #[arg(long, default_value_t = 0.25)]
    pub max_state_age: f64,
    /// Stop when no autopilot heartbeat came for this long (s).
    #[arg(long, default_value_t = 2.5)]
    pub heartbeat_timeout: f64,
    /// Stop when turning faster than this (deg/s).
    #[arg(long, default_value_t = 180.0)]
    pub max_yaw_rate: f64,
    /// Stop when the depth reading has not changed for this long (s): a frozen or lost sensor
    /// (ArduSub repeats the last reading when its depth sensor is gone).
    #[arg(long, default_value_t = 1.0)]
    pub max_frozen: f64,
    /// Stop when no depth or heading measurement came for this long (s).
    #[arg(long, default_value_t = 0.5)]
    pub max_sensor_silence: f64,
    /// Stop after more than this many malformed frames.
    #[arg(long, default_value_t = 0)]
    pub max_malformed: u64,
    /// Seconds to wait (neutral commands) after arming for a position source (GPS, a DVL) to
    /// give the full state; 0: start at once on depth and heading (the state estimate gives
    /// the body velocities), and take a position source whenever it comes.
    #[arg(long, default_value_t = 0.0)]
    pub wait_position: f64,
    /// Seconds to keep asking while the autopilot refuses to arm (ArduSub does for its first
    /// seconds, until its EKF has aligned); each refusal's reason is printed.
    #[arg(long, default_value_t = 30.0)]
    pub arm_timeout: f64,
    /// Rate (Hz) requested for SERVO_OUTPUT_RAW, whose outputs give the recorded input.
    #[arg(long, default_value_t = 50.0)]
    pub outputs_rate: f64,
    /// Take the autopilot's ground-station place from the station with this system id for the
    /// run (Cockpit: 255): pinc's --gcs-sysid becomes the autopilot's ground station, so that
    /// station's joystick moves nothing meanwhile, and the place is given back at every end.
    /// `--pilot` on a ground station's joystick takes it by itself.
    #[arg(long, value_name = "SYSID")]
    pub take_ground_station: Option<u8>,
}

/// A number of seconds that is zero or more, or an error naming `name`.
///
/// # Errors
/// Not finite or negative.
pub fn non_negative(name: &str, v: f64) -> Result<Duration, String> {
    if v.is_finite() && v >= 0.0 {
        Ok(Duration::from_secs_f64(v))
    } else {
        Err(format!("{name} must be a number of seconds, zero or more, got {v}"))
    }
}

/// A distance in metres, zero or more (a flag's value).
fn metres(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!("expected a distance in metres, zero or more, got {s:?}")),
    }
}

/// A number of seconds from 0 to the longest latency a fix may have.
fn seconds_or_zero(s: &str) -> Result<f64, String> {
    let most = crate::estimation::MAX_FIX_LATENCY_S;
    match s.parse::<f64>() {
        Ok(v) if (0.0..=most).contains(&v) => Ok(v),
        _ => Err(format!("expected a latency in seconds from 0 to {most}, got {s:?}")),
    }
}

/// A positive number of seconds, or an error naming `name`.
///
/// # Errors
/// Not finite or not positive.
pub fn positive(name: &str, v: f64) -> Result<Duration, String> {
    if v.is_finite() && v > 0.0 {
        Ok(Duration::from_secs_f64(v))
    } else {
        Err(format!("{name} must be a positive number of seconds, got {v}"))
    }
}

impl DriveArgs {
    /// The way commands go.
    pub fn way(&self) -> CommandWay {
        if self.command_way == "manual" { CommandWay::Manual } else { CommandWay::Thrusters }
    }

    /// The commander of `vehicle_file`'s thrusters.
    ///
    /// # Errors
    /// The file cannot be read or cannot command this way.
    pub fn commander(&self, vehicle_file: &Path) -> Result<Commander, String> {
        let thrusters = Thrusters::load(vehicle_file).map_err(|e| e.to_string())?;
        self.commander_of(thrusters, &vehicle_file.display().to_string())
    }

    /// The commander over `thrusters` (from `source`, named in errors).
    ///
    /// # Errors
    /// Thrusters that cannot take the command way.
    pub fn commander_of(&self, thrusters: Thrusters, source: &str) -> Result<Commander, String> {
        Commander::new(thrusters, self.way(), self.js_gain.unwrap_or(1.0)).map_err(|e| format!("{source}: {e}"))
    }

    /// The session's settings: limits, arming, notes echoed on stderr.
    ///
    /// # Errors
    /// A limit or the arm timeout that is not positive.
    pub fn settings(&self) -> Result<DriveSettings, String> {
        Ok(DriveSettings {
            limits: self.limits()?,
            arm: self.arm,
            arm_timeout: positive("--arm-timeout", self.arm_timeout)?,
            echo_notes: true,
            js_gain_from_autopilot: self.js_gain.is_none(),
            sensor_silence: positive("--max-sensor-silence", self.max_sensor_silence)?.as_secs_f64(),
            frozen_depth: positive("--max-frozen", self.max_frozen)?.as_secs_f64(),
            replaces_ground_station: self.take_ground_station,
        })
    }

    /// The safety limits.
    ///
    /// # Errors
    /// A limit that is not positive.
    pub fn limits(&self) -> Result<SafetyLimits, String> {
        if !(self.max_yaw_rate.is_finite() && self.max_yaw_rate > 0.0) {
            return Err(format!("--max-yaw-rate must be positive, got {}", self.max_yaw_rate));
        }
        if let Some(d) = self.max_depth
            && !d.is_finite()
        {
            return Err(format!("--max-depth must be a number of metres, got {d}"));
        }
        Ok(SafetyLimits {
            max_state_age: positive("--max-state-age", self.max_state_age)?,
            heartbeat_timeout: positive("--heartbeat-timeout", self.heartbeat_timeout)?,
            max_depth: self.max_depth,
            max_yaw_rate: self.max_yaw_rate.to_radians(),
            max_malformed: self.max_malformed,
        })
    }
}

/// Opens the link, waits for the autopilot (every message meanwhile goes to `seen`) and asks
/// for the state streams at `--rate`.
///
/// # Errors
/// A bad option, the link cannot be opened, or no autopilot answers.
pub fn open(
    connect: &str,
    a: &LinkOptions,
    seen: impl FnMut(&Received),
) -> Result<(VehicleLink, Autopilot, StateAssembler), String> {
    let address: LinkAddress = connect.parse().map_err(|e| format!("--connect: {e}"))?;
    let timeout = positive("--timeout", a.timeout)?;
    if !(a.rate.is_finite() && a.rate > 0.0) {
        return Err(format!("--rate must be a positive number of Hz, got {}", a.rate));
    }
    positive("--max-age", a.max_age)?;
    let signing = a.signing_key.as_deref().map(SigningKey::load).transpose().map_err(|e| e.to_string())?;
    let config = LinkConfig { gcs_system_id: a.gcs_sysid, signing, ..LinkConfig::default() };
    // A TCP autopilot that is still starting refuses the connection: ask again until the
    // timeout, as ground stations do.
    let started = std::time::Instant::now();
    let mut link = loop {
        match VehicleLink::connect(&address, config.clone()) {
            Err(LinkError::Open { source, .. })
                if source.kind() == std::io::ErrorKind::ConnectionRefused && started.elapsed() < timeout =>
            {
                std::thread::sleep(Duration::from_millis(200));
            }
            other => break other.map_err(|e| e.to_string())?,
        }
    };
    let autopilot = link.wait_for_autopilot(timeout, seen).map_err(|e| e.to_string())?;
    link.request_state_streams(a.rate).map_err(|e| e.to_string())?;
    let estimator = StateAssembler::new(StateConfig {
        max_age: a.max_age,
        surface_pressure_hpa: a.surface_pressure,
        water_density: a.water_density,
    });
    Ok((link, autopilot, estimator))
}

/// The state estimator of a live session.
#[derive(clap::Args, Debug, Clone)]
pub struct EstimatorArgs {
    /// Control on the raw state instead of the estimate (needs a position source: the body
    /// velocities then come from the autopilot's EKF).
    #[arg(long)]
    pub no_estimator: bool,
    /// The estimator's process model: the controller's own model, or the analytic vehicle of
    /// --vehicle.
    #[arg(long, value_parser = ["controller", "vehicle"], default_value = "controller")]
    pub estimator_model: String,
    /// Standard deviation of the depth sensor (m) the estimator assumes [default: the fitted
    /// model's sensor model, else 0.1].
    #[arg(long)]
    pub depth_std: Option<f64>,
    /// How long the depth sensor lags (s): its reading is taken as the depth that long ago
    /// [default: the fitted model's, else 0.04].
    #[arg(long)]
    pub depth_delay: Option<f64>,
    /// Standard deviation of the heading (rad) the estimator assumes [default: the fitted
    /// model's, else 0.02].
    #[arg(long)]
    pub heading_std: Option<f64>,
    /// Standard deviation of the yaw rate (rad/s) the estimator assumes [default: the fitted
    /// model's, else 0.005].
    #[arg(long)]
    pub yaw_rate_std: Option<f64>,
    /// Standard deviation of the autopilot's vertical velocity (m/s, `GLOBAL_POSITION_INT.vz`,
    /// from its accelerometers and depth sensor) the estimator assumes [default: 0.05].
    #[arg(long)]
    pub vertical_velocity_std: Option<f64>,
    /// Standard deviation of the autopilot's position (m, `LOCAL_POSITION_NED`: its EKF's
    /// estimate from GPS, a DVL or acoustic positioning) the estimator assumes [default: 0.3].
    #[arg(long)]
    pub position_std: Option<f64>,
    /// Standard deviation of the autopilot's NED velocity (m/s) the estimator assumes
    /// [default: 0.1].
    #[arg(long)]
    pub velocity_ned_std: Option<f64>,
    /// How far the current's horizontal force may wander (N, one standard deviation over its
    /// 60 s correlation time): smaller steadies a noisy position sensor where no DVL measures
    /// the velocity (a USBL alone), larger follows a current that changes [default: 5].
    #[arg(long)]
    pub current_std: Option<f64>,
    /// How much dead reckoning may add to the horizontal uncertainty (m, one standard
    /// deviation) while no position or velocity is measured (a DVL that lost the bottom, a GPS
    /// without its fix) before the horizontal goal is dropped; 0 drops it at once.
    #[arg(long, default_value_t = crate::estimation::DEFAULT_DEAD_RECKONING_BOUND_M, value_parser = metres)]
    pub dead_reckoning_bound: f64,
    /// How late (s) the positioning sensor's fixes (`GPS_INPUT`, `GLOBAL_VISION_POSITION_ESTIMATE`
    /// from its own link: a USBL, a GPS on MAVLink) arrive after they were measured; each is
    /// fused against the estimate of that time (at most 2 s). Water Linked's Underwater GPS:
    /// about 0.5.
    #[arg(long, default_value_t = 0.0, value_parser = seconds_or_zero)]
    pub fix_latency: f64,
    /// The DVL's yaw misalignment as measured on the vehicle (deg, its forward axis turned to
    /// starboard of the hull's): taken as known. Without it the estimator estimates it from
    /// the positioning sensor's fixes while the vehicle moves (a prior of 3 deg).
    #[arg(long, value_name = "DEG", allow_negative_numbers = true)]
    pub dvl_yaw_deg: Option<f64>,
    /// The DVL's scale as measured (it reads FACTOR times the velocity, e.g. 1.01): taken as
    /// known. Without it, estimated as the misalignment is (a prior of 3 %).
    #[arg(long, value_name = "FACTOR")]
    pub dvl_scale: Option<f64>,
    /// Ask the autopilot for the simulator's truth (SIM_STATE, ArduPilot's SITL only) and
    /// report the estimate's errors against it.
    #[arg(long)]
    pub sim_truth: bool,
}

impl EstimatorArgs {
    /// The noise settings: each flag given, else the fitted model's sensor model, else the
    /// estimator's default.
    ///
    /// # Errors
    /// A value that is not a positive number.
    pub fn noise(&self, fitted: Option<&crate::model::SensorModel>) -> Result<NoiseSettings, String> {
        let d = NoiseSettings::default();
        let pick = |flag: Option<f64>, fit: Option<f64>, default: f64| flag.or(fit).unwrap_or(default);
        let noise = NoiseSettings {
            depth_std: pick(self.depth_std, fitted.map(|f| f.depth_std), d.depth_std),
            depth_delay: pick(self.depth_delay, fitted.map(|f| f.depth_delay), d.depth_delay),
            heading_std: pick(self.heading_std, fitted.map(|f| f.heading_std), d.heading_std),
            yaw_rate_std: pick(self.yaw_rate_std, fitted.map(|f| f.yaw_rate_std), d.yaw_rate_std),
            vertical_velocity_std: self.vertical_velocity_std.unwrap_or(d.vertical_velocity_std),
            position_std: self.position_std.unwrap_or(d.position_std),
            velocity_ned_std: self.velocity_ned_std.unwrap_or(d.velocity_ned_std),
            ..d
        };
        let mut noise = noise;
        if let Some(v) = self.current_std {
            noise.disturbance_std[0] = v;
            noise.disturbance_std[1] = v;
        }
        noise.validate()?;
        Ok(noise)
    }
}
