//! Any CSV log through a mapping file (TOML, docs/LOGS_CSV.md): which columns hold time,
//! position, heading, velocities, yaw rate and inputs, in which frames and units. The reader
//! converts everything to pinc's conventions (NED world, forward-right-down body, rad, s) and
//! returns the per-quantity streams.

use super::csv_rows::{next_row, parse_field};
use super::{BodyFrame, CommandsToInput, ImportError, Series, StreamSet, WorldFrame};
use crate::vehicle::wrap_angle;
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};
use std::f64::consts::FRAC_PI_2;
use std::path::Path;

/// How far a quaternion's length may be from 1 before the row is refused.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// Which columns of a CSV file hold what, in which frames and units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CsvMapping {
    /// Field separator, one ASCII character [default: `,`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub delimiter: Option<String>,
    /// The time column or the fixed rate.
    pub time: TimeMapping,
    /// Position columns.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<PositionMapping>,
    /// Yaw column or quaternion columns.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heading: Option<HeadingMapping>,
    /// Linear velocity columns.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<VelocityMapping>,
    /// Yaw-rate column.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_rate: Option<YawRateMapping>,
    /// Body wrench columns or thruster command columns.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input: Option<InputMapping>,
}

/// `[time]`: a column with its unit, or a fixed rate for files without time stamps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeMapping {
    /// The time-stamp column.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub column: Option<String>,
    /// Unit of the time-stamp column [default: `s`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unit: Option<TimeUnit>,
    /// Rows per second when there is no time column: row `i` is at `i / rate_hz` s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate_hz: Option<f64>,
}

/// Unit of a time-stamp column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TimeUnit {
    /// Seconds.
    S,
    /// Milliseconds.
    Ms,
    /// Microseconds.
    Us,
    /// Nanoseconds.
    Ns,
}

impl TimeUnit {
    /// Seconds per unit.
    pub fn seconds(self) -> f64 {
        match self {
            Self::S => 1.0,
            Self::Ms => 1e-3,
            Self::Us => 1e-6,
            Self::Ns => 1e-9,
        }
    }
}

/// `[position]`: three columns in a world frame (m).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionMapping {
    /// The x, y, z columns, in the order of `frame`'s axes.
    pub columns: [String; 3],
    /// Their frame.
    pub frame: WorldFrame,
}

/// Unit of an angle (or, for a rate, of the angle per second).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AngleUnit {
    /// Radians.
    Rad,
    /// Degrees.
    Deg,
}

impl AngleUnit {
    /// Radians per unit.
    pub fn radians(self) -> f64 {
        match self {
            Self::Rad => 1.0,
            Self::Deg => std::f64::consts::PI / 180.0,
        }
    }
}

/// Order of the four quaternion columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum QuaternionOrder {
    /// Vector part first, scalar last (ROS, Eigen's storage).
    Xyzw,
    /// Scalar first.
    Wxyz,
}

/// Frame of a heading: for a yaw column the world frame it is measured in, for a quaternion
/// the world frame and body axes it rotates between.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HeadingFrame {
    /// Yaw clockwise from north (pinc's own).
    Ned,
    /// Yaw counter-clockwise from east.
    Enu,
    /// Quaternion from forward-right-down body axes to a north-east-down world.
    NedFrd,
    /// Quaternion from forward-left-up body axes to an east-north-up world (the ROS convention).
    EnuFlu,
}

/// `[heading]`: a yaw column, or four quaternion columns (roll and pitch come with it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadingMapping {
    /// The yaw column.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_column: Option<String>,
    /// Unit of the yaw column [default: `rad`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unit: Option<AngleUnit>,
    /// The four quaternion columns, in the order `order` names.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quaternion_columns: Option<[String; 4]>,
    /// Order of the quaternion columns [default: `xyzw`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub order: Option<QuaternionOrder>,
    /// `ned` or `enu` for a yaw column, `ned_frd` or `enu_flu` for a quaternion.
    pub frame: HeadingFrame,
}

/// Axes of a velocity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VelocityAxes {
    /// Body, forward-right-down (pinc's own).
    BodyFrd,
    /// Body, forward-left-up (ROS).
    BodyFlu,
    /// World, north-east-down.
    WorldNed,
    /// World, east-north-up.
    WorldEnu,
}

/// `[velocity]`: three linear-velocity columns (m/s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VelocityMapping {
    /// The three columns, in the order of `axes`.
    pub columns: [String; 3],
    /// Their axes.
    pub axes: VelocityAxes,
}

/// `[yaw_rate]`: the angular rate about the body's vertical axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct YawRateMapping {
    /// The column.
    pub column: String,
    /// `frd`: about the down axis; `flu`: about the up axis (the sign flips).
    pub axes: BodyFrame,
    /// Angle unit per second [default: `rad`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unit: Option<AngleUnit>,
}

/// `[input]`: the body wrench, or thruster commands that the vehicle's thrusters turn into one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputMapping {
    /// Columns of the force along x, y, z (N) and the moment about z (N m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wrench_columns: Option<[String; 4]>,
    /// Axes of the wrench columns.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axes: Option<BodyFrame>,
    /// Thruster command columns (as the vehicle file's thrusters take them, e.g. PWM in us).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thruster_columns: Option<Vec<String>>,
    /// The channel (1-based) of each thruster column [default: 1, 2, ...].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channels: Option<Vec<usize>>,
}

impl CsvMapping {
    /// Checks that each section names one consistent choice.
    ///
    /// # Errors
    /// One line naming the section and key: both or neither of a pair of alternatives, a key
    /// that belongs to the other alternative, a frame that does not fit, a rate that is not
    /// positive, a delimiter that is not one ASCII character, channels that do not match.
    pub fn check(&self) -> Result<(), String> {
        if let Some(d) = &self.delimiter
            && !(d.len() == 1 && d.is_ascii())
        {
            return Err(format!("delimiter: one ASCII character, got {d:?}"));
        }
        let t = &self.time;
        match (&t.column, t.rate_hz) {
            (Some(_), Some(_)) => return Err("[time]: give column or rate_hz, not both".into()),
            (None, None) => return Err("[time]: give column (and unit) or rate_hz".into()),
            (None, Some(r)) if !(r.is_finite() && r > 0.0) => {
                return Err(format!("[time] rate_hz: a positive number, got {r}"));
            }
            (None, Some(_)) if t.unit.is_some() => return Err("[time] unit: only with column".into()),
            _ => {}
        }
        if let Some(h) = &self.heading {
            match (&h.yaw_column, &h.quaternion_columns) {
                (Some(_), Some(_)) => return Err("[heading]: give yaw_column or quaternion_columns, not both".into()),
                (None, None) => return Err("[heading]: give yaw_column or quaternion_columns".into()),
                (Some(_), None) => {
                    if h.order.is_some() {
                        return Err("[heading] order: only with quaternion_columns".into());
                    }
                    if !matches!(h.frame, HeadingFrame::Ned | HeadingFrame::Enu) {
                        return Err("[heading] frame: a yaw column is in `ned` or `enu`".into());
                    }
                }
                (None, Some(_)) => {
                    if h.unit.is_some() {
                        return Err("[heading] unit: only with yaw_column".into());
                    }
                    if !matches!(h.frame, HeadingFrame::NedFrd | HeadingFrame::EnuFlu) {
                        return Err("[heading] frame: a quaternion is in `ned_frd` or `enu_flu`".into());
                    }
                }
            }
        }
        if let Some(i) = &self.input {
            match (&i.wrench_columns, &i.thruster_columns) {
                (Some(_), Some(_)) => {
                    return Err("[input]: give wrench_columns or thruster_columns, not both".into());
                }
                (None, None) => return Err("[input]: give wrench_columns or thruster_columns".into()),
                (Some(_), None) => {
                    if i.axes.is_none() {
                        return Err("[input] axes: `frd` or `flu` is required with wrench_columns".into());
                    }
                    if i.channels.is_some() {
                        return Err("[input] channels: only with thruster_columns".into());
                    }
                }
                (None, Some(cols)) => {
                    if i.axes.is_some() {
                        return Err("[input] axes: only with wrench_columns".into());
                    }
                    if cols.is_empty() {
                        return Err("[input] thruster_columns: at least one column".into());
                    }
                    if let Some(ch) = &i.channels {
                        if ch.len() != cols.len() {
                            return Err(format!(
                                "[input] channels: {} channels for {} thruster columns",
                                ch.len(),
                                cols.len()
                            ));
                        }
                        if ch.contains(&0) {
                            return Err("[input] channels: channels count from 1".into());
                        }
                        let mut sorted = ch.clone();
                        sorted.sort_unstable();
                        if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
                            return Err(format!("[input] channels: channel {} given twice", w[0]));
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// The thruster channel of each thruster column (1-based), when the input is thrusters.
    fn channels(&self) -> Option<Vec<usize>> {
        let i = self.input.as_ref()?;
        let cols = i.thruster_columns.as_ref()?;
        Some(i.channels.clone().unwrap_or_else(|| (1..=cols.len()).collect()))
    }
}

/// Reads and checks a mapping file.
///
/// # Errors
/// The file cannot be read, is not TOML, has a key the format does not know (named), a value
/// of the wrong kind, or an inconsistent section (see [`CsvMapping::check`]); one line, with
/// the line of the file where the TOML parser found the fault.
pub fn load_mapping(path: &Path) -> Result<CsvMapping, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    let text = std::fs::read_to_string(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let mapping: CsvMapping = toml::from_str(&text).map_err(|e: toml::de::Error| {
        let message = e.message().trim().replace('\n', " ");
        match e.span() {
            Some(span) => malformed(format!("line {}: {message}", text[..span.start].matches('\n').count() + 1)),
            None => malformed(message),
        }
    })?;
    mapping.check().map_err(malformed)?;
    Ok(mapping)
}

/// The columns a mapping reads, resolved against one file's header.
struct Columns {
    /// Header index of each column read, in slot order.
    index: Vec<usize>,
    /// Header name of each slot.
    name: Vec<String>,
}

impl Columns {
    /// The slot of `column` (named by `role` of the mapping), adding it when new.
    fn slot(&mut self, header: &[String], column: &str, role: &str) -> Result<usize, String> {
        let Some(idx) = header.iter().position(|h| h == column) else {
            return Err(format!(
                "column {column:?} ({role} in the mapping) is not in the header; the file has: {}",
                header.join(", ")
            ));
        };
        if let Some(s) = self.index.iter().position(|&i| i == idx) {
            return Ok(s);
        }
        self.index.push(idx);
        self.name.push(column.to_string());
        Ok(self.index.len() - 1)
    }

    fn slots<const N: usize>(
        &mut self,
        header: &[String],
        columns: &[String; N],
        role: &str,
    ) -> Result<[usize; N], String> {
        let mut out = [0; N];
        for (o, c) in out.iter_mut().zip(columns) {
            *o = self.slot(header, c, role)?;
        }
        Ok(out)
    }
}

/// The rotation (body to world) of a unit quaternion `w, x, y, z`.
fn rotation(w: f64, x: f64, y: f64, z: f64) -> Matrix3<f64> {
    Matrix3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )
}

/// Roll, pitch, yaw (Z-Y-X) of a body-to-world rotation.
fn euler_zyx(r: &Matrix3<f64>) -> [f64; 3] {
    [r[(2, 1)].atan2(r[(2, 2)]), -r[(2, 0)].clamp(-1.0, 1.0).asin(), r[(1, 0)].atan2(r[(0, 0)])]
}

/// ENU world axes to NED: swap east and north, flip up.
const ENU_TO_NED: Matrix3<f64> = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
/// FRD body axes to FLU (its own inverse): flip y and z.
const FRD_TO_FLU: Matrix3<f64> = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);

/// How the heading columns turn into roll, pitch, yaw.
enum Heading {
    Yaw { slot: usize, scale: f64, enu: bool },
    Quaternion { slots: [usize; 4], columns: String, enu_flu: bool },
}

/// How the input columns turn into `[X, Y, Z, Mz]`.
enum InputPlan {
    Wrench { slots: [usize; 4], flu: bool },
    Thrusters { slots: Vec<usize>, channels: Vec<usize>, n_channels: usize },
}

/// Reads one CSV file through `mapping`, converting every quantity to pinc's frames and units.
/// Only the columns the mapping names are parsed; an empty field or `nan` is a missing value
/// (NaN, skipped by the windowing). Thruster command columns go through `commands_to_input`
/// (commands by channel, index `c - 1` for channel `c`; channels the mapping does not name
/// are NaN); a row with a missing command gets a NaN input.
///
/// # Errors
/// One line naming the file: the file cannot be read, a column the mapping names is not in
/// the header (the error lists the header), a row has the wrong number of fields, a field is
/// not a number (line and column), a quaternion is not of unit length within
/// [`QUATERNION_NORM_TOLERANCE`] (line and columns), thruster columns without a
/// `commands_to_input`, or no row after the header.
pub fn read_mapped_csv(
    path: &Path,
    mapping: &CsvMapping,
    commands_to_input: Option<CommandsToInput<'_>>,
) -> Result<StreamSet, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    mapping.check().map_err(|m| malformed(format!("mapping: {m}")))?;
    let file = std::fs::File::open(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let delimiter = mapping.delimiter.as_deref().map_or(b',', |d| d.as_bytes()[0]);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .delimiter(delimiter)
        .trim(csv::Trim::Headers)
        .buffer_capacity(1 << 16)
        .from_reader(file);
    let header: Vec<String> =
        reader.headers().map_err(|e| malformed(format!("line 1: {e}")))?.iter().map(str::to_string).collect();
    let width = header.len();

    // Resolve every named column to a slot before reading any row.
    let mut cols = Columns { index: Vec::new(), name: Vec::new() };
    let mut notes = Vec::new();
    let time = match (&mapping.time.column, mapping.time.rate_hz) {
        (Some(c), _) => {
            let unit = mapping.time.unit.unwrap_or(TimeUnit::S);
            let name = match unit {
                TimeUnit::S => "s",
                TimeUnit::Ms => "ms (converted to s)",
                TimeUnit::Us => "us (converted to s)",
                TimeUnit::Ns => "ns (converted to s)",
            };
            notes.push(format!("time: column {c} in {name}"));
            Ok((cols.slot(&header, c, "[time] column").map_err(&malformed)?, unit.seconds()))
        }
        (None, Some(rate)) => {
            notes.push(format!("time: no column, a fixed rate of {rate} Hz from t = 0"));
            Err(rate)
        }
        (None, None) => unreachable!("checked"),
    };
    let position = match &mapping.position {
        Some(p) => {
            let slots = cols.slots(&header, &p.columns, "[position] columns").map_err(&malformed)?;
            notes.push(match p.frame {
                WorldFrame::Ned => format!("position: {} in NED", p.columns.join(",")),
                WorldFrame::Enu => {
                    format!(
                        "position: {} in ENU (z up), converted to NED: (x, y, z) -> (y, x, -z)",
                        p.columns.join(",")
                    )
                }
            });
            Some((slots, p.frame == WorldFrame::Enu, p.columns.join(",")))
        }
        None => None,
    };
    let heading = match &mapping.heading {
        Some(h) => Some(match (&h.yaw_column, &h.quaternion_columns) {
            (Some(c), _) => {
                let unit = h.unit.unwrap_or(AngleUnit::Rad);
                let enu = h.frame == HeadingFrame::Enu;
                notes.push(format!(
                    "heading: yaw column {c} in {}{}; roll and pitch not in the file, taken as 0",
                    if unit == AngleUnit::Deg { "deg" } else { "rad" },
                    if enu {
                        ", counter-clockwise from east, converted: psi = pi/2 - yaw"
                    } else {
                        ", clockwise from north"
                    }
                ));
                Heading::Yaw {
                    slot: cols.slot(&header, c, "[heading] yaw_column").map_err(&malformed)?,
                    scale: unit.radians(),
                    enu,
                }
            }
            (None, Some(q)) => {
                let order = h.order.unwrap_or(QuaternionOrder::Xyzw);
                let s = cols.slots(&header, q, "[heading] quaternion_columns").map_err(&malformed)?;
                // Slots in the order w, x, y, z.
                let slots = match order {
                    QuaternionOrder::Xyzw => [s[3], s[0], s[1], s[2]],
                    QuaternionOrder::Wxyz => s,
                };
                let enu_flu = h.frame == HeadingFrame::EnuFlu;
                notes.push(format!(
                    "heading: quaternion {} ({order:?} order){}; roll, pitch, yaw (Z-Y-X) taken from it",
                    q.join(","),
                    if enu_flu {
                        ", FLU body to ENU world, converted to FRD body to NED world (psi = pi/2 - yaw_enu)"
                    } else {
                        ", FRD body to NED world"
                    }
                ));
                Heading::Quaternion { slots, columns: q.join(","), enu_flu }
            }
            (None, None) => unreachable!("checked"),
        }),
        None => None,
    };
    let velocity = match &mapping.velocity {
        Some(v) => {
            let slots = cols.slots(&header, &v.columns, "[velocity] columns").map_err(&malformed)?;
            let what = match v.axes {
                VelocityAxes::BodyFrd => "body FRD axes",
                VelocityAxes::BodyFlu => "body FLU axes, converted to FRD: (x, y, z) -> (x, -y, -z)",
                VelocityAxes::WorldNed => "world NED axes (rotated into the body by the attitude when resampled)",
                VelocityAxes::WorldEnu => "world ENU axes, converted to NED: (x, y, z) -> (y, x, -z)",
            };
            notes.push(format!("velocity: {} in {what}", v.columns.join(",")));
            Some((slots, v.axes, v.columns.join(",")))
        }
        None => None,
    };
    let yaw_rate = match &mapping.yaw_rate {
        Some(y) => {
            let slot = cols.slot(&header, &y.column, "[yaw_rate] column").map_err(&malformed)?;
            let unit = y.unit.unwrap_or(AngleUnit::Rad);
            let flu = y.axes == BodyFrame::Flu;
            notes.push(format!(
                "yaw rate: {} in {}/s{}",
                y.column,
                if unit == AngleUnit::Deg { "deg" } else { "rad" },
                if flu {
                    " about the up axis (FLU), sign flipped to the down axis"
                } else {
                    " about the down axis (FRD)"
                }
            ));
            Some((slot, unit.radians() * if flu { -1.0 } else { 1.0 }, y.column.clone()))
        }
        None => None,
    };
    let input = match &mapping.input {
        Some(i) => Some(match (&i.wrench_columns, &i.thruster_columns) {
            (Some(w), _) => {
                let flu = i.axes == Some(BodyFrame::Flu);
                notes.push(format!(
                    "input: wrench {}{}",
                    w.join(","),
                    if flu { " in FLU, converted to FRD: (X, Y, Z, Mz) -> (X, -Y, -Z, -Mz)" } else { " in FRD" }
                ));
                (
                    InputPlan::Wrench {
                        slots: cols.slots(&header, w, "[input] wrench_columns").map_err(&malformed)?,
                        flu,
                    },
                    w.join(","),
                )
            }
            (None, Some(t)) => {
                if commands_to_input.is_none() {
                    return Err(malformed(
                        "the mapping's [input] thruster_columns need the vehicle's thrusters (a vehicle file with a thruster layout)"
                            .into(),
                    ));
                }
                let channels = mapping.channels().expect("thruster input");
                let slots = t
                    .iter()
                    .map(|c| cols.slot(&header, c, "[input] thruster_columns"))
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(&malformed)?;
                notes.push(format!(
                    "input: thruster commands {} on channels {:?}, converted to a body wrench by the vehicle's thrusters",
                    t.join(","),
                    channels
                ));
                let n_channels = channels.iter().copied().max().unwrap_or(0);
                (InputPlan::Thrusters { slots, channels, n_channels }, t.join(","))
            }
            (None, None) => unreachable!("checked"),
        }),
        None => None,
    };

    let mut out = StreamSet::default();
    let mut pos_s = position.as_ref().map(|p| Series::<3>::new(p.2.clone()));
    let mut att_s = heading.as_ref().map(|h| {
        Series::<3>::new(match h {
            Heading::Yaw { slot, .. } => cols.name[*slot].clone(),
            Heading::Quaternion { columns, .. } => columns.clone(),
        })
    });
    let mut vel_s = velocity.as_ref().map(|v| Series::<3>::new(v.2.clone()));
    let mut rate_s = yaw_rate.as_ref().map(|y| Series::<1>::new(y.2.clone()));
    let mut input_s = input.as_ref().map(|i| Series::<4>::new(i.1.clone()));

    let mut record = csv::ByteRecord::new();
    let mut vals = vec![0.0; cols.index.len()];
    let mut commands = vec![
        f64::NAN;
        input.as_ref().map_or(0, |i| match &i.0 {
            InputPlan::Thrusters { n_channels, .. } => *n_channels,
            InputPlan::Wrench { .. } => 0,
        })
    ];
    let mut row = 0usize;
    let mut torn: Option<String> = None;
    loop {
        if !next_row(&mut reader, &mut record, width, &mut torn).map_err(malformed)? {
            break;
        }
        for (v, &idx) in vals.iter_mut().zip(&cols.index) {
            let field = &record[idx];
            *v = match parse_field(field) {
                Some(x) => x,
                None => {
                    let line = record.position().map_or(0, |p| p.line());
                    return Err(malformed(format!(
                        "line {line}: column {}: {:?} is not a number",
                        header[idx],
                        String::from_utf8_lossy(field.trim_ascii())
                    )));
                }
            };
        }
        let t = match time {
            Ok((slot, scale)) => vals[slot] * scale,
            Err(rate) => row as f64 / rate,
        };
        if let (Some((s, enu, _)), Some(series)) = (&position, &mut pos_s) {
            let p = [vals[s[0]], vals[s[1]], vals[s[2]]];
            series.push(t, if *enu { [p[1], p[0], -p[2]] } else { p });
        }
        if let (Some(h), Some(series)) = (&heading, &mut att_s) {
            let att = match h {
                Heading::Yaw { slot, scale, enu } => {
                    let yaw = vals[*slot] * scale;
                    [0.0, 0.0, if *enu { wrap_angle(FRAC_PI_2 - yaw) } else { wrap_angle(yaw) }]
                }
                Heading::Quaternion { slots, columns, enu_flu } => {
                    let [w, x, y, z] = slots.map(|s| vals[s]);
                    let norm = (w * w + x * x + y * y + z * z).sqrt();
                    if norm.is_nan() {
                        [f64::NAN; 3]
                    } else {
                        if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
                            let line = record.position().map_or(0, |p| p.line());
                            return Err(malformed(format!(
                                "line {line} (data row {}): quaternion {columns} has length {norm:.6}, not 1 (tolerance {QUATERNION_NORM_TOLERANCE})",
                                row + 1
                            )));
                        }
                        let r = rotation(w / norm, x / norm, y / norm, z / norm);
                        euler_zyx(&if *enu_flu { ENU_TO_NED * r * FRD_TO_FLU } else { r })
                    }
                }
            };
            series.push(t, att);
        }
        if let (Some((s, axes, _)), Some(series)) = (&velocity, &mut vel_s) {
            let v = [vals[s[0]], vals[s[1]], vals[s[2]]];
            series.push(
                t,
                match axes {
                    VelocityAxes::BodyFrd | VelocityAxes::WorldNed => v,
                    VelocityAxes::BodyFlu => [v[0], -v[1], -v[2]],
                    VelocityAxes::WorldEnu => [v[1], v[0], -v[2]],
                },
            );
        }
        if let (Some((slot, scale, _)), Some(series)) = (&yaw_rate, &mut rate_s) {
            series.push(t, [vals[*slot] * scale]);
        }
        if let (Some((plan, _)), Some(series)) = (&input, &mut input_s) {
            let u = match plan {
                InputPlan::Wrench { slots, flu } => {
                    let w = slots.map(|s| vals[s]);
                    if *flu { [w[0], -w[1], -w[2], -w[3]] } else { w }
                }
                InputPlan::Thrusters { slots, channels, .. } => {
                    let mut missing = false;
                    for (&s, &c) in slots.iter().zip(channels) {
                        commands[c - 1] = vals[s];
                        missing |= vals[s].is_nan();
                    }
                    if missing {
                        [f64::NAN; 4]
                    } else {
                        let f = commands_to_input.expect("checked above");
                        let u = f(&commands);
                        [u[0], u[1], u[2], u[3]]
                    }
                }
            };
            series.push(t, u);
        }
        row += 1;
    }
    if row == 0 {
        return Err(malformed("no rows after the header".into()));
    }
    notes.push(format!("{row} rows"));
    notes.extend(torn);
    out.position = pos_s;
    out.attitude = att_s;
    match velocity.as_ref().map(|v| v.1) {
        Some(VelocityAxes::BodyFrd | VelocityAxes::BodyFlu) => out.velocity_body = vel_s,
        Some(VelocityAxes::WorldNed | VelocityAxes::WorldEnu) => out.velocity_ned = vel_s,
        None => {}
    }
    out.yaw_rate = rate_s;
    out.input = input_s;
    out.notes = notes;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quaternion_of_a_pure_enu_yaw_gives_the_ned_yaw_pi_over_2_minus_it() {
        let a: f64 = 0.4;
        let r = rotation((a / 2.0).cos(), 0.0, 0.0, (a / 2.0).sin());
        let [roll, pitch, yaw] = euler_zyx(&(ENU_TO_NED * r * FRD_TO_FLU));
        assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12);
        assert!((yaw - (FRAC_PI_2 - a)).abs() < 1e-12);
    }

    #[test]
    fn nose_up_in_flu_is_nose_up_in_frd() {
        // Pitch about FLU's y (left) by -b lifts the nose; in FRD that is a positive pitch.
        let b: f64 = 0.2;
        let r = rotation((-b / 2.0).cos(), 0.0, (-b / 2.0).sin(), 0.0);
        let [roll, pitch, _] = euler_zyx(&(ENU_TO_NED * r * FRD_TO_FLU));
        assert!(roll.abs() < 1e-12);
        assert!((pitch - b).abs() < 1e-12, "{pitch}");
    }

    #[test]
    fn starboard_down_in_flu_is_a_positive_roll_in_frd() {
        // About FLU's x (forward) by +a the left side rises: starboard down, positive in FRD too.
        let a: f64 = 0.15;
        let r = rotation((a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0);
        let [roll, pitch, _] = euler_zyx(&(ENU_TO_NED * r * FRD_TO_FLU));
        assert!(pitch.abs() < 1e-12);
        assert!((roll - a).abs() < 1e-12, "{roll}");
    }
}
