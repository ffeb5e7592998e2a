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
#[derive(Default)]
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

/// How a row's time is found.
#[derive(Clone, Copy)]
enum TimePlan {
    /// A time-stamp column (its slot) and the seconds per unit.
    Column { slot: usize, scale: f64 },
    /// No column: row `i` is at `i / rate` s.
    Rate(f64),
}

impl TimePlan {
    /// The time (s) of data row `row` (from 0) whose parsed fields are `vals`.
    fn at(self, vals: &[f64], row: usize) -> f64 {
        match self {
            Self::Column { slot, scale } => vals[slot] * scale,
            Self::Rate(rate) => row as f64 / rate,
        }
    }
}

/// The axes of a vector the mapping reads, and its conversion to pinc's (NED world, FRD body).
trait Axes: Copy {
    /// `v` in pinc's axes.
    fn to_pinc(self, v: [f64; 3]) -> [f64; 3];
}

impl Axes for WorldFrame {
    fn to_pinc(self, v: [f64; 3]) -> [f64; 3] {
        match self {
            WorldFrame::Ned => v,
            WorldFrame::Enu => [v[1], v[0], -v[2]],
        }
    }
}

impl Axes for VelocityAxes {
    fn to_pinc(self, v: [f64; 3]) -> [f64; 3] {
        match self {
            VelocityAxes::BodyFrd | VelocityAxes::WorldNed => v,
            VelocityAxes::BodyFlu => [v[0], -v[1], -v[2]],
            VelocityAxes::WorldEnu => WorldFrame::Enu.to_pinc(v),
        }
    }
}

/// Three columns read as one vector in `axes` (a position, a velocity), and their names for
/// the report.
struct VectorPlan<A> {
    slots: [usize; 3],
    axes: A,
    source: String,
}

impl<A: Axes> VectorPlan<A> {
    /// The vector of a row, in pinc's axes.
    fn of(&self, vals: &[f64]) -> [f64; 3] {
        self.axes.to_pinc(self.slots.map(|s| vals[s]))
    }
}

/// How the heading columns turn into roll, pitch, yaw.
enum Heading {
    Yaw { slot: usize, scale: f64, enu: bool },
    Quaternion { slots: [usize; 4], columns: String, enu_flu: bool },
}

impl Heading {
    /// Roll, pitch, yaw of a row (NaN for a quaternion with a missing part).
    ///
    /// # Errors
    /// A quaternion off unit length, naming the line of `record` and data row `row` (from 0).
    fn attitude(&self, vals: &[f64], record: &csv::ByteRecord, row: usize) -> Result<[f64; 3], String> {
        Ok(match self {
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
                        return Err(format!(
                            "line {} (data row {}): quaternion {columns} has length {norm:.6}, not 1 (tolerance {QUATERNION_NORM_TOLERANCE})",
                            line_of(record),
                            row + 1
                        ));
                    }
                    let r = rotation(w / norm, x / norm, y / norm, z / norm);
                    euler_zyx(&if *enu_flu { ENU_TO_NED * r * FRD_TO_FLU } else { r })
                }
            }
        })
    }
}

/// The yaw-rate column, its factor to rad/s about the down axis, and its name.
struct YawRatePlan {
    slot: usize,
    scale: f64,
    source: String,
}

/// How the input columns turn into `[X, Y, Z, Mz]`.
enum InputPlan {
    Wrench { slots: [usize; 4], flu: bool },
    Thrusters { slots: Vec<usize>, channels: Vec<usize>, n_channels: usize },
}

impl InputPlan {
    /// The body input of a row; thruster commands go into `commands` (by channel) and through
    /// `commands_to_input`, a missing one makes the whole input NaN.
    fn of(&self, vals: &[f64], commands: &mut [f64], commands_to_input: Option<CommandsToInput<'_>>) -> [f64; 4] {
        match self {
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
                    let f = commands_to_input.expect("checked when planned");
                    let u = f(commands);
                    [u[0], u[1], u[2], u[3]]
                }
            }
        }
    }
}

/// What a mapping reads from one file, resolved against its header before any row is read:
/// the columns parsed, how each quantity is converted, and the notes saying so.
struct Plan {
    cols: Columns,
    time: TimePlan,
    position: Option<VectorPlan<WorldFrame>>,
    heading: Option<Heading>,
    velocity: Option<VectorPlan<VelocityAxes>>,
    yaw_rate: Option<YawRatePlan>,
    /// The input's conversion and its columns' names.
    input: Option<(InputPlan, String)>,
    notes: Vec<String>,
}

/// Resolves a mapping's sections against a header, one at a time, collecting the columns to
/// parse and a note per section.
struct Resolver<'h> {
    header: &'h [String],
    cols: Columns,
    notes: Vec<String>,
}

impl Plan {
    /// Every section of `mapping` resolved against `header`, in the mapping's order (time,
    /// position, heading, velocity, yaw rate, input), so the first column missing from the
    /// header is the one reported. `has_thrusters`: a conversion of thruster commands is given.
    ///
    /// # Errors
    /// A column not in the header (listing it), or thruster columns without the thrusters.
    fn new(mapping: &CsvMapping, header: &[String], has_thrusters: bool) -> Result<Self, String> {
        let mut r = Resolver { header, cols: Columns::default(), notes: Vec::new() };
        let time = r.time(&mapping.time)?;
        let position = mapping.position.as_ref().map(|p| r.position(p)).transpose()?;
        let heading = mapping.heading.as_ref().map(|h| r.heading(h)).transpose()?;
        let velocity = mapping.velocity.as_ref().map(|v| r.velocity(v)).transpose()?;
        let yaw_rate = mapping.yaw_rate.as_ref().map(|y| r.yaw_rate(y)).transpose()?;
        let input = mapping.input.as_ref().map(|i| r.input(i, mapping, has_thrusters)).transpose()?;
        Ok(Self { cols: r.cols, time, position, heading, velocity, yaw_rate, input, notes: r.notes })
    }

    /// The streams read, the notes with the row count (and a torn last line), as the reader
    /// returns them; velocities go to the body or the world stream by their axes.
    ///
    /// # Errors
    /// No row after the header.
    fn finish(self, streams: Streams, rows: usize, torn: Option<String>) -> Result<StreamSet, String> {
        if rows == 0 {
            return Err("no rows after the header".into());
        }
        let mut notes = self.notes;
        notes.push(format!("{rows} rows"));
        notes.extend(torn);
        let (mut velocity_body, mut velocity_ned) = (None, None);
        match self.velocity.as_ref().map(|v| v.axes) {
            Some(VelocityAxes::BodyFrd | VelocityAxes::BodyFlu) => velocity_body = streams.velocity,
            Some(VelocityAxes::WorldNed | VelocityAxes::WorldEnu) => velocity_ned = streams.velocity,
            None => {}
        }
        Ok(StreamSet {
            position: streams.position,
            depth: None,
            attitude: streams.attitude,
            velocity_ned,
            velocity_body,
            yaw_rate: streams.yaw_rate,
            input: streams.input,
            notes,
        })
    }
}

impl Resolver<'_> {
    /// `[time]`: the column and its unit, or the fixed rate.
    fn time(&mut self, t: &TimeMapping) -> Result<TimePlan, String> {
        match (&t.column, t.rate_hz) {
            (Some(c), _) => {
                let unit = t.unit.unwrap_or(TimeUnit::S);
                let name = match unit {
                    TimeUnit::S => "s",
                    TimeUnit::Ms => "ms (converted to s)",
                    TimeUnit::Us => "us (converted to s)",
                    TimeUnit::Ns => "ns (converted to s)",
                };
                self.notes.push(format!("time: column {c} in {name}"));
                Ok(TimePlan::Column { slot: self.cols.slot(self.header, c, "[time] column")?, scale: unit.seconds() })
            }
            (None, Some(rate)) => {
                self.notes.push(format!("time: no column, a fixed rate of {rate} Hz from t = 0"));
                Ok(TimePlan::Rate(rate))
            }
            (None, None) => unreachable!("checked"),
        }
    }

    /// `[position]`: three columns, NED or ENU.
    fn position(&mut self, p: &PositionMapping) -> Result<VectorPlan<WorldFrame>, String> {
        let slots = self.cols.slots(self.header, &p.columns, "[position] columns")?;
        self.notes.push(match p.frame {
            WorldFrame::Ned => format!("position: {} in NED", p.columns.join(",")),
            WorldFrame::Enu => {
                format!("position: {} in ENU (z up), converted to NED: (x, y, z) -> (y, x, -z)", p.columns.join(","))
            }
        });
        Ok(VectorPlan { slots, axes: p.frame, source: p.columns.join(",") })
    }

    /// `[heading]`: a yaw column (roll and pitch 0) or a quaternion.
    fn heading(&mut self, h: &HeadingMapping) -> Result<Heading, String> {
        Ok(match (&h.yaw_column, &h.quaternion_columns) {
            (Some(c), _) => {
                let unit = h.unit.unwrap_or(AngleUnit::Rad);
                let enu = h.frame == HeadingFrame::Enu;
                self.notes.push(format!(
                    "heading: yaw column {c} in {}{}; roll and pitch not in the file, taken as 0",
                    if unit == AngleUnit::Deg { "deg" } else { "rad" },
                    if enu {
                        ", counter-clockwise from east, converted: psi = pi/2 - yaw"
                    } else {
                        ", clockwise from north"
                    }
                ));
                Heading::Yaw {
                    slot: self.cols.slot(self.header, c, "[heading] yaw_column")?,
                    scale: unit.radians(),
                    enu,
                }
            }
            (None, Some(q)) => {
                let order = h.order.unwrap_or(QuaternionOrder::Xyzw);
                let s = self.cols.slots(self.header, q, "[heading] quaternion_columns")?;
                // Slots in the order w, x, y, z.
                let slots = match order {
                    QuaternionOrder::Xyzw => [s[3], s[0], s[1], s[2]],
                    QuaternionOrder::Wxyz => s,
                };
                let enu_flu = h.frame == HeadingFrame::EnuFlu;
                self.notes.push(format!(
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
        })
    }

    /// `[velocity]`: three columns in body or world axes.
    fn velocity(&mut self, v: &VelocityMapping) -> Result<VectorPlan<VelocityAxes>, String> {
        let slots = self.cols.slots(self.header, &v.columns, "[velocity] columns")?;
        let what = match v.axes {
            VelocityAxes::BodyFrd => "body FRD axes",
            VelocityAxes::BodyFlu => "body FLU axes, converted to FRD: (x, y, z) -> (x, -y, -z)",
            VelocityAxes::WorldNed => "world NED axes (rotated into the body by the attitude when resampled)",
            VelocityAxes::WorldEnu => "world ENU axes, converted to NED: (x, y, z) -> (y, x, -z)",
        };
        self.notes.push(format!("velocity: {} in {what}", v.columns.join(",")));
        Ok(VectorPlan { slots, axes: v.axes, source: v.columns.join(",") })
    }

    /// `[yaw_rate]`: one column about the down or the up axis.
    fn yaw_rate(&mut self, y: &YawRateMapping) -> Result<YawRatePlan, String> {
        let slot = self.cols.slot(self.header, &y.column, "[yaw_rate] column")?;
        let unit = y.unit.unwrap_or(AngleUnit::Rad);
        let flu = y.axes == BodyFrame::Flu;
        self.notes.push(format!(
            "yaw rate: {} in {}/s{}",
            y.column,
            if unit == AngleUnit::Deg { "deg" } else { "rad" },
            if flu { " about the up axis (FLU), sign flipped to the down axis" } else { " about the down axis (FRD)" }
        ));
        Ok(YawRatePlan { slot, scale: unit.radians() * if flu { -1.0 } else { 1.0 }, source: y.column.clone() })
    }

    /// `[input]`: the wrench columns, or thruster columns by channel (which need the thrusters).
    fn input(
        &mut self,
        i: &InputMapping,
        mapping: &CsvMapping,
        has_thrusters: bool,
    ) -> Result<(InputPlan, String), String> {
        match (&i.wrench_columns, &i.thruster_columns) {
            (Some(w), _) => {
                let flu = i.axes == Some(BodyFrame::Flu);
                self.notes.push(format!(
                    "input: wrench {}{}",
                    w.join(","),
                    if flu { " in FLU, converted to FRD: (X, Y, Z, Mz) -> (X, -Y, -Z, -Mz)" } else { " in FRD" }
                ));
                let slots = self.cols.slots(self.header, w, "[input] wrench_columns")?;
                Ok((InputPlan::Wrench { slots, flu }, w.join(",")))
            }
            (None, Some(t)) => {
                if !has_thrusters {
                    return Err(
                        "the mapping's [input] thruster_columns need the vehicle's thrusters (a vehicle file with a thruster layout)"
                            .into(),
                    );
                }
                let channels = mapping.channels().expect("thruster input");
                let slots = t
                    .iter()
                    .map(|c| self.cols.slot(self.header, c, "[input] thruster_columns"))
                    .collect::<Result<Vec<_>, _>>()?;
                self.notes.push(format!(
                    "input: thruster commands {} on channels {:?}, converted to a body wrench by the vehicle's thrusters",
                    t.join(","),
                    channels
                ));
                let n_channels = channels.iter().copied().max().unwrap_or(0);
                Ok((InputPlan::Thrusters { slots, channels, n_channels }, t.join(",")))
            }
            (None, None) => unreachable!("checked"),
        }
    }
}

/// The series a file fills, one per section its plan reads.
struct Streams {
    position: Option<Series<3>>,
    attitude: Option<Series<3>>,
    velocity: Option<Series<3>>,
    yaw_rate: Option<Series<1>>,
    input: Option<Series<4>>,
    /// A row's thruster commands by channel (NaN on channels the mapping does not name).
    commands: Vec<f64>,
}

impl Streams {
    /// Empty series named after their columns.
    fn new(plan: &Plan) -> Self {
        Self {
            position: plan.position.as_ref().map(|p| Series::new(p.source.clone())),
            attitude: plan.heading.as_ref().map(|h| {
                Series::new(match h {
                    Heading::Yaw { slot, .. } => plan.cols.name[*slot].clone(),
                    Heading::Quaternion { columns, .. } => columns.clone(),
                })
            }),
            velocity: plan.velocity.as_ref().map(|v| Series::new(v.source.clone())),
            yaw_rate: plan.yaw_rate.as_ref().map(|y| Series::new(y.source.clone())),
            input: plan.input.as_ref().map(|i| Series::new(i.1.clone())),
            commands: vec![
                f64::NAN;
                plan.input.as_ref().map_or(0, |i| match &i.0 {
                    InputPlan::Thrusters { n_channels, .. } => *n_channels,
                    InputPlan::Wrench { .. } => 0,
                })
            ],
        }
    }

    /// Appends one row, each quantity converted as the plan says.
    ///
    /// # Errors
    /// A quaternion off unit length.
    fn push(
        &mut self,
        plan: &Plan,
        vals: &[f64],
        record: &csv::ByteRecord,
        row: usize,
        commands_to_input: Option<CommandsToInput<'_>>,
    ) -> Result<(), String> {
        let t = plan.time.at(vals, row);
        if let (Some(p), Some(series)) = (&plan.position, &mut self.position) {
            series.push(t, p.of(vals));
        }
        if let (Some(h), Some(series)) = (&plan.heading, &mut self.attitude) {
            series.push(t, h.attitude(vals, record, row)?);
        }
        if let (Some(v), Some(series)) = (&plan.velocity, &mut self.velocity) {
            series.push(t, v.of(vals));
        }
        if let (Some(y), Some(series)) = (&plan.yaw_rate, &mut self.yaw_rate) {
            series.push(t, [vals[y.slot] * y.scale]);
        }
        if let (Some((i, _)), Some(series)) = (&plan.input, &mut self.input) {
            series.push(t, i.of(vals, &mut self.commands, commands_to_input));
        }
        Ok(())
    }
}

/// The line of the file a record was read from.
fn line_of(record: &csv::ByteRecord) -> u64 {
    record.position().map_or(0, |p| p.line())
}

/// Opens the file as the mapping's CSV dialect and reads its header.
fn open(path: &Path, mapping: &CsvMapping) -> Result<(csv::Reader<std::fs::File>, Vec<String>), ImportError> {
    let file = std::fs::File::open(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let delimiter = mapping.delimiter.as_deref().map_or(b',', |d| d.as_bytes()[0]);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .delimiter(delimiter)
        .trim(csv::Trim::Headers)
        .buffer_capacity(1 << 16)
        .from_reader(file);
    let header: Vec<String> = reader
        .headers()
        .map_err(|e| ImportError::Malformed { path: path.to_path_buf(), message: format!("line 1: {e}") })?
        .iter()
        .map(str::to_string)
        .collect();
    Ok((reader, header))
}

/// Reads every row into `streams`, parsing only the plan's columns; returns the number of rows
/// and the note of a torn last line.
///
/// # Errors
/// A damaged row before the last line, a field that is not a number, a quaternion off unit
/// length.
fn read_rows(
    reader: &mut csv::Reader<std::fs::File>,
    header: &[String],
    plan: &Plan,
    streams: &mut Streams,
    commands_to_input: Option<CommandsToInput<'_>>,
) -> Result<(usize, Option<String>), String> {
    let mut record = csv::ByteRecord::new();
    let mut vals = vec![0.0; plan.cols.index.len()];
    let mut row = 0usize;
    let mut torn: Option<String> = None;
    while next_row(reader, &mut record, header.len(), &mut torn)? {
        for (v, &idx) in vals.iter_mut().zip(&plan.cols.index) {
            let field = &record[idx];
            *v = parse_field(field).ok_or_else(|| {
                format!(
                    "line {}: column {}: {:?} is not a number",
                    line_of(&record),
                    header[idx],
                    String::from_utf8_lossy(field.trim_ascii())
                )
            })?;
        }
        streams.push(plan, &vals, &record, row, commands_to_input)?;
        row += 1;
    }
    Ok((row, torn))
}

/// Reads one CSV file through `mapping`, converting every quantity to pinc's frames and units.
/// Only the columns the mapping names are parsed; an empty field or `nan` is a missing value
/// (NaN, skipped by the windowing). Thruster command columns go through `commands_to_input`
/// (commands by channel, index `c - 1` for channel `c`; channels the mapping does not name
/// are NaN); a row with a missing command gets a NaN input.
///
/// The stages: the mapping checked, the file opened and its header read, every column the
/// mapping names resolved against the header (`Plan`) before any row is read, the rows read
/// and converted, the streams returned with the notes.
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
    let (mut reader, header) = open(path, mapping)?;
    let plan = Plan::new(mapping, &header, commands_to_input.is_some()).map_err(malformed)?;
    let mut streams = Streams::new(&plan);
    let (rows, torn) = read_rows(&mut reader, &header, &plan, &mut streams, commands_to_input).map_err(malformed)?;
    plan.finish(streams, rows, torn).map_err(malformed)
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
