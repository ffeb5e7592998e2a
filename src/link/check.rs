//! What an ArduSub autopilot must be set to before pinc dives with it (`pinc vehicle check`):
//! its firmware version, and the parameters that pinc itself and the position sensors fitted
//! (a DVL, a USBL, a GPS, or none) need, each with the value wanted and why. Setting them saves
//! the old values first, as an ArduPilot parameter file (`NAME,VALUE` lines), which sets them
//! back. Every name and value is ArduPilot's (docs/VEHICLE.md, "Checking the autopilot before
//! the first dive", gives the sources); the firmware answers only the names it has.

use super::link::{Autopilot, LinkError, Received, VehicleLink};
use super::params::Params;
use mavlink::dialects::ardupilotmega::{
    AUTOPILOT_VERSION_DATA, HEARTBEAT_DATA, MavAutopilot, MavMessage, MavParamType, MavType, PARAM_SET_DATA,
};
use std::fmt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The firmware pinc was tried with: ArduSub's simulator (`../shared/ardusub_sitl`, ArduPilot's
/// master at git 64a9c787, March 2026).
pub const TRIED_WITH: Firmware = Firmware { major: 4, minor: 8, patch: 0, release: Release::Dev };
/// The git hash of [`TRIED_WITH`].
pub const TRIED_WITH_GIT: &str = "64a9c787";

/// The autopilot's ground-station id under its names, newest first: ArduPilot moved
/// `SYSID_MYGCS` into the MAVLink group as `MAV_GCS_SYSID` (ArduSub 4.8's master answers only
/// the new name; older firmware only the old one).
pub const GCS_ID_NAMES: [&str; 2] = ["MAV_GCS_SYSID", "SYSID_MYGCS"];

/// How often a `PARAM_SET` still unconfirmed is sent again.
const RETRY: Duration = Duration::from_millis(500);

/// What can go wrong checking or setting the autopilot, besides the checks failing.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    /// `--sensors` names something unknown, or a combination that cannot be.
    #[error("--sensors: {0}")]
    Sensors(String),
    /// The link broke.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// A parameter file could not be read or written.
    #[error("{}: {source}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A line of a parameter file is not `NAME,VALUE` (or `NAME VALUE`).
    #[error("{}:{line}: {what}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// The line (from 1).
        line: usize,
        /// What is wrong with it.
        what: String,
    },
    /// The autopilot did not confirm a value set (no `PARAM_VALUE` reporting it in time).
    #[error("the autopilot did not confirm {name} = {wanted} within {timeout_s} s ({})",
        reported.map_or("no answer: not a parameter of this firmware?".to_string(), |v| format!("it reports {v}")))]
    NotConfirmed {
        /// The parameter.
        name: String,
        /// The value sent.
        wanted: f32,
        /// The value it last reported.
        reported: Option<f32>,
        /// The time waited (s).
        timeout_s: f64,
    },
}

/// The position sensors fitted, as `--sensors` names them (none of them: a stock BlueROV2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Sensors {
    /// A DVL on MAVLink (Water Linked's integration: `VISION_POSITION_DELTA`).
    pub dvl: bool,
    /// A USBL whose fixes reach the autopilot as a MAVLink GPS (Water Linked's Underwater GPS:
    /// `GPS_INPUT`).
    pub usbl: bool,
    /// A GPS (at the surface, or the simulator's, which works under water).
    pub gps: bool,
}

impl Sensors {
    /// The sensors of `--sensors` (`dvl`, `usbl`, `gps`, or `none` alone).
    ///
    /// # Errors
    /// An unknown name, `none` beside another, or a USBL beside a GPS (both are the
    /// autopilot's GPS 1).
    pub fn parse<S: AsRef<str>>(names: &[S]) -> Result<Self, CheckError> {
        let mut s = Self::default();
        let mut none = false;
        for name in names {
            match name.as_ref().trim().to_ascii_lowercase().as_str() {
                "dvl" => s.dvl = true,
                "usbl" => s.usbl = true,
                "gps" => s.gps = true,
                "none" => none = true,
                other => {
                    return Err(CheckError::Sensors(format!(
                        "unknown sensor {other:?}: give dvl, usbl, gps (comma-separated) or none"
                    )));
                }
            }
        }
        if none && s != Self::default() {
            return Err(CheckError::Sensors("none names no sensor: give it alone".into()));
        }
        if s.usbl && s.gps {
            return Err(CheckError::Sensors(
                "a USBL and a GPS would both be the autopilot's GPS 1 (GPS1_TYPE): give one".into(),
            ));
        }
        Ok(s)
    }

    /// Whether one of them gives the autopilot an absolute position (a USBL's or a GPS's fixes).
    pub fn absolute_position(&self) -> bool {
        self.usbl || self.gps
    }

    /// The `--sensors` value that names them.
    pub fn name(&self) -> String {
        let names: Vec<&str> = [(self.dvl, "dvl"), (self.usbl, "usbl"), (self.gps, "gps")]
            .into_iter()
            .filter_map(|(on, n)| on.then_some(n))
            .collect();
        if names.is_empty() { "none".into() } else { names.join(",") }
    }
}

/// The value a parameter must have.
#[derive(Debug, Clone, PartialEq)]
pub enum Want {
    /// This value.
    Equal(f64),
    /// One of these.
    OneOf(Vec<f64>),
    /// This value or more.
    AtLeast(f64),
    /// From the first to the second, both included.
    Between(f64, f64),
    /// Anything but 0.
    NonZero,
    /// Within the second of the first.
    Near(f64, f64),
}

/// Whether `a` and `b` are the same value once sent as a `PARAM_VALUE` (a 32-bit float).
fn same(a: f64, b: f64) -> bool {
    a as f32 == b as f32
}

impl Want {
    /// Whether `value` is wanted.
    pub fn holds(&self, value: f64) -> bool {
        match self {
            Self::Equal(w) => same(value, *w),
            Self::OneOf(ws) => ws.iter().any(|w| same(value, *w)),
            Self::AtLeast(w) => value >= *w,
            Self::Between(lo, hi) => (*lo..=*hi).contains(&value),
            Self::NonZero => value != 0.0,
            Self::Near(w, tol) => (value - w).abs() <= *tol,
        }
    }
}

/// A value as the autopilot holds it (a 32-bit float), in the fewest digits that read back to it.
pub fn show(value: f64) -> String {
    (value as f32).to_string()
}

impl fmt::Display for Want {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Equal(w) => write!(f, "{}", show(*w)),
            Self::OneOf(ws) => {
                let each: Vec<String> = ws.iter().map(|w| show(*w)).collect();
                write!(f, "{}", each.join(" or "))
            }
            Self::AtLeast(w) => write!(f, "{} or more", show(*w)),
            Self::Between(lo, hi) => write!(f, "{} to {}", show(*lo), show(*hi)),
            Self::NonZero => write!(f, "not 0"),
            Self::Near(w, tol) => write!(f, "{} +- {}", show(*w), show(*tol)),
        }
    }
}

/// Whether the autopilot reads `name` only at boot, so that a change takes effect after a
/// reboot: the sensor drivers' types (ArduPilot marks them `@RebootRequired`) and the EKF's
/// sources (`AP_NavEKF_Source::init` takes the active set once, at the EKF's start).
pub fn read_at_boot(name: &str) -> bool {
    name == "VISO_TYPE" || (name.starts_with("GPS") && name.ends_with("_TYPE")) || name.starts_with("EK3_SRC")
}

/// One check of one parameter: what it must be, what `--set` writes, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Requirement {
    /// The parameter's name, as the autopilot answers it.
    pub name: String,
    /// The value wanted.
    pub want: Want,
    /// What `--set` writes where the check fails; `None`: pinc cannot choose it (the owner
    /// must give it).
    pub set_to: Option<f64>,
    /// Why, in one sentence.
    pub why: String,
    /// The autopilot reads it at boot: a change takes effect after a reboot.
    pub at_boot: bool,
}

/// A requirement with the value the autopilot answered.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// What is wanted.
    pub requirement: Requirement,
    /// What the autopilot answered (`None`: it did not answer the name).
    pub found: Option<f64>,
}

impl Row {
    /// Whether the check passes: answered and wanted.
    pub fn passes(&self) -> bool {
        self.found.is_some_and(|v| self.requirement.want.holds(v))
    }

    /// The parameter's name.
    pub fn name(&self) -> &str {
        &self.requirement.name
    }
}

/// What the checks are made against besides the sensors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckSettings {
    /// The system id pinc sends as (`--gcs-sysid`).
    pub gcs_sysid: u8,
    /// The local magnetic declination (degrees east), where the owner gave it.
    pub declination_deg: Option<f64>,
}

/// How far `COMPASS_DEC` may be from the declination given (rad): 0.06 deg, finer than a
/// declination map's own error.
pub const DECLINATION_TOLERANCE_RAD: f64 = 0.001;

/// Every name the checks of `sensors` read (the ground-station id under both its names).
pub fn names_to_read(sensors: Sensors, settings: &CheckSettings) -> Vec<String> {
    let mut names: Vec<String> = GCS_ID_NAMES.iter().map(|n| n.to_string()).collect();
    for r in requirements(sensors, settings, GCS_ID_NAMES[0]) {
        if !names.contains(&r.name) {
            names.push(r.name);
        }
    }
    names
}

/// The name of the ground-station id that the autopilot answered (newest first); the newest
/// where it answered neither.
pub fn gcs_id_name(params: &Params) -> &'static str {
    GCS_ID_NAMES.iter().copied().find(|n| params.get(n).is_some()).unwrap_or(GCS_ID_NAMES[0])
}

/// The checks of `sensors` against the autopilot's `params`, in the order they are shown.
pub fn table(sensors: Sensors, settings: &CheckSettings, params: &Params) -> Vec<Row> {
    requirements(sensors, settings, gcs_id_name(params))
        .into_iter()
        .map(|requirement| Row { found: params.get(&requirement.name), requirement })
        .collect()
}

/// The requirements of `sensors`, the ground-station id under `gcs_name`.
pub fn requirements(sensors: Sensors, settings: &CheckSettings, gcs_name: &str) -> Vec<Requirement> {
    let req = |name: &str, want: Want, set_to: Option<f64>, why: String| Requirement {
        name: name.to_string(),
        want,
        set_to,
        why,
        at_boot: read_at_boot(name),
    };
    let gcs = f64::from(settings.gcs_sysid);
    let mut rows = vec![
        req(
            gcs_name,
            Want::Equal(gcs),
            Some(gcs),
            format!(
                "The autopilot takes pilot commands (MANUAL_CONTROL, RC overrides) and watches the heartbeat of \
                 its failsafe from this system id only, and pinc sends as {} (--gcs-sysid).",
                settings.gcs_sysid
            ),
        ),
        req(
            "FS_GCS_ENABLE",
            Want::AtLeast(2.0),
            Some(2.0),
            "With 2 (disarm), 3 (depth hold) or 4 (surface) the autopilot acts when pinc's heartbeat stops for \
             FS_GCS_TIMEOUT s (a cut tether, pinc killed); 0 (off) or 1 (warn only) leaves the thrusters on their \
             last command."
                .into(),
        ),
        req(
            "FS_PILOT_INPUT",
            Want::Equal(2.0),
            Some(2.0),
            "With 2 the autopilot disarms when pinc's commands (MANUAL_CONTROL, RC overrides) stop for \
             FS_PILOT_TIMEOUT s while its heartbeat goes on (a controller stuck); 0 (off) or 1 (warn only) leaves \
             the thrusters on the last command."
                .into(),
        ),
        req(
            "FS_PILOT_TIMEOUT",
            Want::Between(0.5, 3.0),
            Some(3.0),
            "How long without pinc's commands before that disarm (s): pinc commands every 0.08 s, so under 0.5 s \
             one late packet disarms, and ArduSub takes no more than 3."
                .into(),
        ),
        req(
            "EK3_SRC1_POSZ",
            Want::Equal(1.0),
            Some(1.0),
            "The EKF's depth from the pressure sensor (1, Baro), the reading pinc's depth comes from.".into(),
        ),
        req(
            "EK3_SRC1_YAW",
            Want::Equal(1.0),
            Some(1.0),
            "The EKF's heading from the compass (1), the heading pinc steers by and turns the horizontal \
             velocities with."
                .into(),
        ),
    ];
    if sensors.dvl {
        rows.push(req(
            "VISO_TYPE",
            Want::Equal(1.0),
            Some(1.0),
            "1 (MAVLink) makes the autopilot read the DVL's VISION_POSITION_DELTA; with 0 it drops every DVL \
             message."
                .into(),
        ));
        rows.push(req(
            "EK3_SRC1_VELXY",
            Want::Equal(6.0),
            Some(6.0),
            "The EKF's horizontal velocity from the DVL (6, ExternalNav), the velocity pinc's position hold and \
             its dead reckoning rest on."
                .into(),
        ));
        rows.push(req(
            "EK3_SRC1_VELZ",
            Want::OneOf(vec![0.0, 6.0]),
            Some(0.0),
            "No GPS vertical velocity under water: 0 (none; the EKF fuses the DVL's three body axes anyway) or 6 \
             (the DVL), not 3 (GPS)."
                .into(),
        ));
    }
    if sensors.usbl {
        rows.push(req(
            "GPS1_TYPE",
            Want::Equal(14.0),
            Some(14.0),
            "14 (MAVLink) makes the autopilot read the USBL's fixes (GPS_INPUT) as its GPS.".into(),
        ));
    } else if sensors.gps {
        rows.push(req(
            "GPS1_TYPE",
            Want::NonZero,
            Some(1.0),
            "The GPS must be enabled (1: detected at boot, or its type) for the EKF to have a position.".into(),
        ));
    }
    if sensors.absolute_position() {
        rows.push(req(
            "EK3_SRC1_POSXY",
            Want::Equal(3.0),
            Some(3.0),
            format!(
                "The EKF's horizontal position from the GPS driver (3), {}: pinc holds and follows positions on it.",
                if sensors.usbl { "which reads the USBL's fixes" } else { "the GPS's fixes" }
            ),
        ));
    } else if sensors.dvl {
        rows.push(req(
            "EK3_SRC1_POSXY",
            Want::OneOf(vec![0.0, 6.0]),
            Some(0.0),
            "A DVL measures no position: 0 (none) has the EKF integrate its velocity from the origin (6 takes the \
             DVL integration's position resets); with 3 (GPS) the EKF and pinc wait for a GPS fix that never \
             comes under water."
                .into(),
        ));
    }
    if !sensors.dvl {
        if sensors.usbl {
            rows.push(req(
                "EK3_SRC1_VELXY",
                Want::Equal(0.0),
                Some(0.0),
                "The USBL's fixes carry no velocity and no DVL measures one: 0 (none), the EKF's velocity from its \
                 IMU and the fixes."
                    .into(),
            ));
        } else if sensors.gps {
            rows.push(req(
                "EK3_SRC1_VELXY",
                Want::Equal(3.0),
                Some(3.0),
                "The EKF's horizontal velocity from the GPS (3).".into(),
            ));
        }
    }
    if !sensors.absolute_position() {
        rows.push(req(
            "COMPASS_AUTODEC",
            Want::Equal(0.0),
            Some(0.0),
            "The declination is set by hand (COMPASS_DEC): 0 keeps the autopilot from replacing it by a lookup \
             from a position it may get later."
                .into(),
        ));
        let (want, set_to) = match settings.declination_deg {
            Some(d) => (Want::Near(d.to_radians(), DECLINATION_TOLERANCE_RAD), Some(d.to_radians())),
            None => (Want::NonZero, None),
        };
        rows.push(req(
            "COMPASS_DEC",
            want,
            set_to,
            "Without a position the autopilot cannot look the declination up: with COMPASS_DEC (radians) 0 its \
             heading, the one pinc steers by, is magnetic, off true north by the local declination (10.9 deg on \
             the simulator near Los Angeles); give your site's with --declination DEG."
                .into(),
        ));
    }
    rows
}

/// An ArduPilot firmware version (`AUTOPILOT_VERSION.flight_sw_version`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Firmware {
    /// Major version.
    pub major: u8,
    /// Minor version.
    pub minor: u8,
    /// Patch version.
    pub patch: u8,
    /// Release type.
    pub release: Release,
}

/// ArduPilot's release types (`FIRMWARE_VERSION_TYPE`, the version's low byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Release {
    /// A development build.
    Dev,
    /// An alpha.
    Alpha,
    /// A beta.
    Beta,
    /// A release candidate.
    Rc,
    /// An official release.
    Official,
    /// A type ArduPilot does not define.
    Unknown(u8),
}

impl Firmware {
    /// The version in `flight_sw_version`: major, minor, patch and release type, from the top byte.
    pub fn from_sw_version(v: u32) -> Self {
        let release = match (v & 0xff) as u8 {
            0 => Release::Dev,
            64 => Release::Alpha,
            128 => Release::Beta,
            192 => Release::Rc,
            255 => Release::Official,
            other => Release::Unknown(other),
        };
        Self { major: (v >> 24) as u8, minor: (v >> 16) as u8, patch: (v >> 8) as u8, release }
    }

    /// The version in a boot banner's `STATUSTEXT` ("ArduSub V4.8.0-dev (64a9c787)"), if it is one.
    pub fn from_banner(text: &str) -> Option<Self> {
        let rest = text.split_once("ArduSub V")?.1;
        let (numbers, tail) = rest.split_once(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or((rest, ""));
        let mut parts = numbers.split('.').map(str::parse::<u8>);
        let (major, minor, patch) = (parts.next()?.ok()?, parts.next()?.ok()?, parts.next()?.ok()?);
        let release = match tail.split_whitespace().next().unwrap_or("") {
            s if s.starts_with("dev") => Release::Dev,
            s if s.starts_with("alpha") => Release::Alpha,
            s if s.starts_with("beta") => Release::Beta,
            s if s.starts_with("rc") => Release::Rc,
            _ => Release::Official,
        };
        Some(Self { major, minor, patch, release })
    }

    /// Whether it is the version pinc was tried with (any release type of it).
    pub fn tried(&self) -> bool {
        (self.major, self.minor, self.patch) == (TRIED_WITH.major, TRIED_WITH.minor, TRIED_WITH.patch)
    }
}

impl fmt::Display for Firmware {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.patch)?;
        match self.release {
            Release::Dev => write!(f, "-dev"),
            Release::Alpha => write!(f, "-alpha"),
            Release::Beta => write!(f, "-beta"),
            Release::Rc => write!(f, "-rc"),
            Release::Official => Ok(()),
            Release::Unknown(t) => write!(f, " (release type {t})"),
        }
    }
}

/// What the autopilot said about itself, judged against what pinc was tried with.
#[derive(Debug, Clone, PartialEq)]
pub struct FirmwareCheck {
    /// Its version, where it said.
    pub version: Option<Firmware>,
    /// Its git hash, where it said.
    pub git: Option<String>,
    /// Whether it is ArduSub at the version pinc was tried with (otherwise a warning, not a
    /// failure).
    pub tried: bool,
    /// What it is, and the warning where it is not what pinc was tried with, in words.
    pub text: String,
}

/// The git hash of an `AUTOPILOT_VERSION` (its `flight_custom_version`), if it has one.
pub fn git_hash(v: &AUTOPILOT_VERSION_DATA) -> Option<String> {
    let hash: String = v.flight_custom_version.iter().take_while(|b| **b != 0).map(|b| *b as char).collect();
    (!hash.is_empty()).then_some(hash)
}

/// Judges the autopilot of `heartbeat` at `version` (from `AUTOPILOT_VERSION`, or a boot banner).
pub fn judge_firmware(heartbeat: &HEARTBEAT_DATA, version: Option<Firmware>, git: Option<String>) -> FirmwareCheck {
    let tried_with = format!("ArduSub {TRIED_WITH} (git {TRIED_WITH_GIT}, ArduPilot's simulator)");
    let sub = heartbeat.autopilot == MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA
        && heartbeat.mavtype == MavType::MAV_TYPE_SUBMARINE;
    let what = match (version, &git) {
        (Some(v), Some(g)) => format!("ArduSub {v} (git {g})"),
        (Some(v), None) => format!("ArduSub {v}"),
        (None, _) => "version unknown (no AUTOPILOT_VERSION answered)".into(),
    };
    let (tried, text) = if !sub {
        (
            false,
            format!(
                "warning: not ArduSub (its heartbeat says {:?}, {:?}): pinc was tried with {tried_with} only",
                heartbeat.mavtype, heartbeat.autopilot
            ),
        )
    } else {
        match version {
            Some(v) if v.tried() => (true, format!("{what}: the version pinc was tried with")),
            Some(_) => (
                false,
                format!(
                    "{what}; warning: pinc was tried with {tried_with}: other versions may name or treat these \
                     parameters otherwise"
                ),
            ),
            None => (false, format!("{what}; warning: pinc was tried with {tried_with}")),
        }
    };
    FirmwareCheck { version, git, tried, text }
}

/// A parameter file's text: a comment line per item of `header`, then `NAME,VALUE` per value
/// (ArduPilot's `.parm` format; each value as the 32-bit float the autopilot holds, in the
/// fewest digits that read back to it).
pub fn parm_text(header: &[String], values: &[(String, f32)]) -> String {
    let mut text: String = header.iter().map(|h| format!("# {h}\n")).collect();
    for (name, value) in values {
        text.push_str(&format!("{name},{value}\n"));
    }
    text
}

/// The values of a parameter file (ArduPilot's `.parm`: `NAME,VALUE` or `NAME VALUE` per line,
/// `#` comments), `path` named in errors.
///
/// # Errors
/// A line that is not a name and a finite number.
pub fn parse_parm(text: &str, path: &Path) -> Result<Vec<(String, f32)>, CheckError> {
    let mut values = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let bad = |what: String| CheckError::Parse { path: path.to_path_buf(), line: i + 1, what };
        let mut fields = line.split(|c: char| c == ',' || c.is_whitespace()).filter(|f| !f.is_empty());
        let (Some(name), Some(value), None) = (fields.next(), fields.next(), fields.next()) else {
            return Err(bad(format!("expected NAME,VALUE, got {line:?}")));
        };
        if name.len() > 16 || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(bad(format!("{name:?} is not a parameter name (up to 16 letters, digits and _)")));
        }
        match value.parse::<f32>() {
            Ok(v) if v.is_finite() => values.push((name.to_string(), v)),
            _ => return Err(bad(format!("{name}: {value:?} is not a number"))),
        }
    }
    Ok(values)
}

/// Writes `text` to `path` whole or not at all: to a temporary file beside it, then renamed.
/// A file already at `path` is left alone (an earlier save is never overwritten).
///
/// # Errors
/// `path` exists, or the file cannot be written.
pub fn write_new_file_atomically(path: &Path, text: &str) -> Result<(), CheckError> {
    let err = |source| CheckError::File { path: path.to_path_buf(), source };
    if path.exists() {
        return Err(err(std::io::Error::new(std::io::ErrorKind::AlreadyExists, "exists: name another file")));
    }
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
    let written = (|| {
        use std::io::Write;
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(text.as_bytes())?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written.map_err(err)
}

/// The file `--set` saves the old values to when not told: `pinc-params-before-<UTC time>.parm`
/// in the working folder.
pub fn default_backup_path(utc: &chrono::DateTime<chrono::Utc>) -> PathBuf {
    PathBuf::from(format!("pinc-params-before-{}.parm", utc.format("%Y%m%dT%H%M%SZ")))
}

/// Sets `name` to `value` on the autopilot and waits until it says so: the `PARAM_SET` is sent
/// again every half second until a `PARAM_VALUE` of `name` reports `value` or `timeout`
/// passes. ArduPilot stores the value in the parameter's own type (the message's type is not
/// consulted) and answers with what it then holds. Unlike [`super::params::write_param`] (whole
/// numbers), any value: a declination in radians, a timeout in seconds, a saved value set back.
/// Every message received meanwhile goes to `seen`.
///
/// # Errors
/// The link breaks, or the value is not confirmed in time ([`CheckError::NotConfirmed`]).
pub fn set_param(
    link: &mut VehicleLink,
    autopilot: &Autopilot,
    name: &str,
    value: f32,
    timeout: Duration,
    mut seen: impl FnMut(&Received),
) -> Result<(), CheckError> {
    let start = Instant::now();
    let mut next_ask = start;
    let mut reported = None;
    while reported != Some(value) && start.elapsed() < timeout {
        if Instant::now() >= next_ask {
            link.send(&MavMessage::PARAM_SET(PARAM_SET_DATA {
                param_value: value,
                target_system: autopilot.system_id,
                target_component: autopilot.component_id,
                param_id: name.into(),
                param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
            }))?;
            next_ask = Instant::now() + RETRY;
        }
        let Some(r) = link.recv_timeout(Duration::from_millis(20))? else { continue };
        if let MavMessage::PARAM_VALUE(p) = &r.message
            && autopilot.sent(&r)
        {
            let id: String = p.param_id.as_slice().iter().take_while(|b| **b != 0).map(|b| *b as char).collect();
            if id == name {
                reported = Some(p.param_value);
            }
        }
        seen(&r);
    }
    if reported == Some(value) {
        Ok(())
    } else {
        Err(CheckError::NotConfirmed { name: name.into(), wanted: value, reported, timeout_s: timeout.as_secs_f64() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> CheckSettings {
        CheckSettings { gcs_sysid: 255, declination_deg: None }
    }

    /// The values ArduSub 4.8.0-dev's simulator answered on `sub.parm`'s defaults (read from it).
    fn simulator_defaults() -> Params {
        Params::from_pairs([
            ("MAV_GCS_SYSID", 255.0),
            ("FS_GCS_ENABLE", 2.0),
            ("FS_PILOT_INPUT", 2.0),
            ("FS_PILOT_TIMEOUT", 3.0),
            ("EK3_SRC1_POSXY", 3.0),
            ("EK3_SRC1_VELXY", 3.0),
            ("EK3_SRC1_POSZ", 1.0),
            ("EK3_SRC1_VELZ", 0.0),
            ("EK3_SRC1_YAW", 1.0),
            ("VISO_TYPE", 0.0),
            ("GPS1_TYPE", 1.0),
            ("COMPASS_AUTODEC", 1.0),
            ("COMPASS_DEC", 0.0),
        ])
    }

    fn failing(rows: &[Row]) -> Vec<&str> {
        rows.iter().filter(|r| !r.passes()).map(Row::name).collect()
    }

    fn with(params: &Params, changes: &[(&str, f64)]) -> Params {
        let mut all: Vec<(&str, f64)> = params.all().iter().map(|(k, v)| (k.as_str(), *v)).collect();
        for (name, value) in changes {
            all.retain(|(k, _)| k != name);
            all.push((name, *value));
        }
        Params::from_pairs(all)
    }

    #[test]
    fn sensors_are_parsed_from_their_names_and_impossible_sets_refused() {
        let s = Sensors::parse(&["dvl", "USBL"]).unwrap();
        assert!(s.dvl && s.usbl && !s.gps && s.absolute_position());
        assert_eq!(s.name(), "dvl,usbl");
        assert_eq!(Sensors::parse(&["none"]).unwrap(), Sensors::default());
        assert_eq!(Sensors::default().name(), "none");
        for bad in [&["dvl", "none"][..], &["usbl", "gps"], &["sonar"]] {
            assert!(matches!(Sensors::parse(bad), Err(CheckError::Sensors(_))), "{bad:?}");
        }
    }

    #[test]
    fn the_simulator_defaults_miss_what_a_dvl_and_a_usbl_need_and_nothing_else() {
        let s = Sensors::parse(&["dvl", "usbl"]).unwrap();
        let rows = table(s, &settings(), &simulator_defaults());
        assert_eq!(failing(&rows), ["VISO_TYPE", "EK3_SRC1_VELXY", "GPS1_TYPE"]);
        // What --set writes makes every check pass.
        let fixed: Vec<(&str, f64)> =
            rows.iter().filter(|r| !r.passes()).map(|r| (r.name(), r.requirement.set_to.unwrap())).collect();
        assert_eq!(fixed, [("VISO_TYPE", 1.0), ("EK3_SRC1_VELXY", 6.0), ("GPS1_TYPE", 14.0)]);
        let after = table(s, &settings(), &with(&simulator_defaults(), &fixed));
        assert!(after.iter().all(Row::passes), "{:?}", failing(&after));
        // Nothing about the declination: the USBL gives a position to look it up from.
        assert!(rows.iter().all(|r| !r.name().starts_with("COMPASS")));
    }

    #[test]
    fn the_project_s_measured_dvl_and_usbl_configurations_pass() {
        // tests/fixtures/ardusub/dvl_stand_in.parm, then with usbl.parm, then usbl_alone.parm.
        let dvl = with(
            &simulator_defaults(),
            &[
                ("GPS1_TYPE", 0.0),
                ("VISO_TYPE", 1.0),
                ("EK3_SRC1_POSXY", 0.0),
                ("EK3_SRC1_VELXY", 6.0),
                ("EK3_SRC1_VELZ", 0.0),
                ("COMPASS_DEC", 0.2007),
            ],
        );
        let dvl_only = table(Sensors::parse(&["dvl"]).unwrap(), &settings(), &dvl);
        // The stand-in's file leaves COMPASS_AUTODEC on: the only check it fails.
        assert_eq!(failing(&dvl_only), ["COMPASS_AUTODEC"]);
        let usbl = with(&dvl, &[("GPS1_TYPE", 14.0), ("EK3_SRC1_POSXY", 3.0)]);
        let both = table(Sensors::parse(&["dvl", "usbl"]).unwrap(), &settings(), &usbl);
        assert!(both.iter().all(Row::passes), "{:?}", failing(&both));
        let alone = with(&usbl, &[("VISO_TYPE", 0.0), ("EK3_SRC1_VELXY", 0.0)]);
        let usbl_only = table(Sensors::parse(&["usbl"]).unwrap(), &settings(), &alone);
        assert!(usbl_only.iter().all(Row::passes), "{:?}", failing(&usbl_only));
        // A DVL taken for a GPS position (the default 3) fails.
        let wrong = table(Sensors::parse(&["dvl"]).unwrap(), &settings(), &with(&dvl, &[("EK3_SRC1_POSXY", 3.0)]));
        assert!(failing(&wrong).contains(&"EK3_SRC1_POSXY"));
    }

    #[test]
    fn without_a_position_the_declination_is_wanted_by_hand_and_set_only_when_given() {
        let none = Sensors::default();
        let rows = table(none, &settings(), &simulator_defaults());
        assert_eq!(failing(&rows), ["COMPASS_AUTODEC", "COMPASS_DEC"]);
        let dec = rows.iter().find(|r| r.name() == "COMPASS_DEC").unwrap();
        assert_eq!(dec.requirement.set_to, None, "pinc cannot know the site's declination");
        let given = CheckSettings { declination_deg: Some(11.5), ..settings() };
        let rows = table(none, &given, &simulator_defaults());
        let dec = rows.iter().find(|r| r.name() == "COMPASS_DEC").unwrap();
        assert!((dec.requirement.set_to.unwrap() - 0.2007).abs() < 1e-4);
        let set = with(&simulator_defaults(), &[("COMPASS_AUTODEC", 0.0), ("COMPASS_DEC", 0.2007)]);
        assert!(table(none, &given, &set).iter().all(Row::passes));
        // 10 deg set where 11.5 is given: wrong by 1.5 deg.
        let off = with(&set, &[("COMPASS_DEC", 10f64.to_radians())]);
        assert_eq!(failing(&table(none, &given, &off)), ["COMPASS_DEC"]);
    }

    #[test]
    fn the_ground_station_id_is_checked_under_the_name_the_autopilot_answers() {
        let old = with(&simulator_defaults(), &[("COMPASS_AUTODEC", 0.0), ("COMPASS_DEC", 0.2)]);
        let old = Params::from_pairs(
            old.all()
                .iter()
                .filter(|(k, _)| *k != "MAV_GCS_SYSID")
                .map(|(k, v)| (k.as_str(), *v))
                .chain([("SYSID_MYGCS", 255.0)]),
        );
        let rows = table(Sensors::default(), &settings(), &old);
        assert_eq!(rows[0].name(), "SYSID_MYGCS");
        assert!(rows.iter().all(Row::passes));
        // pinc sending as 200: the autopilot's 255 fails, and --set writes 200.
        let other = CheckSettings { gcs_sysid: 200, ..settings() };
        let rows = table(Sensors::default(), &other, &old);
        assert_eq!(failing(&rows), ["SYSID_MYGCS"]);
        assert_eq!(rows[0].requirement.set_to, Some(200.0));
        // Neither name answered: the newest is shown, failing.
        let rows = table(Sensors::default(), &settings(), &Params::default());
        assert_eq!(rows[0].name(), "MAV_GCS_SYSID");
        assert!(rows.iter().all(|r| !r.passes()));
    }

    #[test]
    fn failsafes_that_only_warn_fail_and_a_timeout_outside_its_range_fails() {
        let none = CheckSettings { declination_deg: Some(0.0), ..settings() };
        let base = with(&simulator_defaults(), &[("COMPASS_AUTODEC", 0.0)]);
        assert!(table(Sensors::default(), &none, &base).iter().all(Row::passes));
        for (name, value) in
            [("FS_GCS_ENABLE", 0.0), ("FS_GCS_ENABLE", 1.0), ("FS_PILOT_INPUT", 1.0), ("FS_PILOT_TIMEOUT", 0.1)]
        {
            let rows = table(Sensors::default(), &none, &with(&base, &[(name, value)]));
            assert_eq!(failing(&rows), [name], "{name} = {value}");
        }
        for value in [3.0, 4.0] {
            assert!(
                table(Sensors::default(), &none, &with(&base, &[("FS_GCS_ENABLE", value)])).iter().all(Row::passes)
            );
        }
    }

    #[test]
    fn every_name_checked_is_read() {
        let s = Sensors::parse(&["dvl"]).unwrap();
        let names = names_to_read(s, &settings());
        assert!(names.starts_with(&["MAV_GCS_SYSID".to_string(), "SYSID_MYGCS".to_string()]));
        for r in requirements(s, &settings(), "SYSID_MYGCS") {
            assert!(names.contains(&r.name), "{}", r.name);
        }
    }

    #[test]
    fn firmware_versions_read_from_autopilot_version_and_from_the_banner() {
        // What the simulator answers: 0x04080000, 4.8.0 dev.
        let v = Firmware::from_sw_version(0x0408_0000);
        assert_eq!(v, TRIED_WITH);
        assert_eq!(v.to_string(), "4.8.0-dev");
        assert_eq!(Firmware::from_sw_version(0x0405_07ff).to_string(), "4.5.7");
        assert_eq!(Firmware::from_banner("ArduSub V4.8.0-dev (64a9c787)"), Some(TRIED_WITH));
        assert_eq!(
            Firmware::from_banner("ArduSub V4.1.2 (a1b2c3d4)"),
            Some(Firmware { major: 4, minor: 1, patch: 2, release: Release::Official })
        );
        assert_eq!(Firmware::from_banner("ArduCopter V4.8.0"), None);
    }

    #[test]
    fn another_version_or_vehicle_is_a_warning() {
        let mut hb = HEARTBEAT_DATA {
            mavtype: MavType::MAV_TYPE_SUBMARINE,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            ..HEARTBEAT_DATA::DEFAULT
        };
        let ok = judge_firmware(&hb, Some(TRIED_WITH), Some("64a9c787".into()));
        assert!(ok.tried && ok.text.contains("the version pinc was tried with"), "{}", ok.text);
        let older = judge_firmware(&hb, Some(Firmware::from_sw_version(0x0405_07ff)), None);
        assert!(!older.tried && older.text.contains("warning") && older.text.contains("4.5.7"), "{}", older.text);
        assert!(!judge_firmware(&hb, None, None).tried);
        hb.mavtype = MavType::MAV_TYPE_QUADROTOR;
        assert!(judge_firmware(&hb, Some(TRIED_WITH), None).text.contains("not ArduSub"));
    }

    #[test]
    fn a_parameter_file_reads_back_what_was_written() {
        let values = vec![("COMPASS_DEC".to_string(), 0.2007f32), ("GPS1_TYPE".into(), 1.0), ("X_Y".into(), -3.25)];
        let text = parm_text(&["saved by a test".into()], &values);
        assert!(text.starts_with("# saved by a test\nCOMPASS_DEC,0.2007\nGPS1_TYPE,1\n"), "{text}");
        let path = Path::new("t.parm");
        assert_eq!(parse_parm(&text, path).unwrap(), values);
        // ArduPilot's own files separate by blanks.
        assert_eq!(parse_parm("VISO_TYPE   1 # comment\n\n", path).unwrap(), [("VISO_TYPE".to_string(), 1.0)]);
        for bad in ["VISO_TYPE", "VISO_TYPE,one", "VISO_TYPE,1,2", "BAD-NAME,1", "VISO_TYPE,NaN"] {
            assert!(matches!(parse_parm(bad, path), Err(CheckError::Parse { line: 1, .. })), "{bad}");
        }
    }

    #[test]
    fn the_saved_file_is_written_whole_and_never_over_an_earlier_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("before.parm");
        write_new_file_atomically(&path, "A,1\n").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "A,1\n");
        assert!(matches!(write_new_file_atomically(&path, "A,2\n"), Err(CheckError::File { .. })));
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "A,1\n");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "no temporary file left");
        let t = chrono::TimeZone::with_ymd_and_hms(&chrono::Utc, 2026, 3, 21, 10, 15, 0).unwrap();
        assert_eq!(default_backup_path(&t), PathBuf::from("pinc-params-before-20260321T101500Z.parm"));
    }
}
