//! The mapping file's types (the TOML side): which columns hold what, in which frames and
//! units, and the check that each section names one consistent choice. Apart from the reading
//! because it is the format a user writes (docs/LOGS_CSV.md), the same whatever file it reads.

use crate::dataset::import::{BodyFrame, WorldFrame};
use serde::{Deserialize, Serialize};

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
    pub(super) fn channels(&self) -> Option<Vec<usize>> {
        let i = self.input.as_ref()?;
        let cols = i.thruster_columns.as_ref()?;
        Some(i.channels.clone().unwrap_or_else(|| (1..=cols.len()).collect()))
    }
}
