//! What every log reader yields before resampling: each quantity the state and the input are
//! made of, as a time series at its own rate, already in pinc's conventions (world frame
//! NED with z down, body frame forward-right-down, rad, m/s, N, N m, seconds on one time base
//! per file). Converting frames and units is the reader's job; merging the streams onto one
//! sample period is shared (`resample`).

use crate::types::Input;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// One quantity sampled at its own times.
#[derive(Debug, Clone, PartialEq)]
pub struct Series<const N: usize> {
    /// Where it came from, as the user would name it: `ATT.Yaw`, `LOCAL_POSITION_NED`,
    /// `/mavros/local_position/odom`, a CSV column list. Printed in the import report.
    pub source: String,
    /// Time stamps (s), non-decreasing.
    pub t: Vec<f64>,
    /// One value per time stamp.
    pub v: Vec<[f64; N]>,
}

impl<const N: usize> Series<N> {
    /// An empty series named `source`.
    pub fn new(source: impl Into<String>) -> Self {
        Self { source: source.into(), t: Vec::new(), v: Vec::new() }
    }

    /// Appends one sample.
    pub fn push(&mut self, t: f64, v: [f64; N]) {
        self.t.push(t);
        self.v.push(v);
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// True when there is no sample.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }
}

/// Everything a reader found in one file, each part optional where logs may lack it.
///
/// The state `[x, y, z, psi, u, v, w, r]` is assembled from: `position` (or `depth` for z
/// alone), `attitude` (roll, pitch, yaw), body velocities either given (`velocity_body`) or
/// rotated from `velocity_ned` by the attitude, and the yaw rate `r` (given, or else the
/// derivative of the yaw). Inputs are body forces `[X, Y, Z, Mz]` held from each sample to
/// the next (a reader that has thruster commands converts them through the vehicle file's
/// thrusters first).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StreamSet {
    /// NED position (m).
    pub position: Option<Series<3>>,
    /// Depth (m, positive down) where no position exists or as a better z.
    pub depth: Option<Series<1>>,
    /// Roll, pitch, yaw (rad; yaw clockwise from north, as NED / forward-right-down implies).
    pub attitude: Option<Series<3>>,
    /// World-frame velocity, NED (m/s).
    pub velocity_ned: Option<Series<3>>,
    /// Body-frame velocity, forward-right-down (m/s).
    pub velocity_body: Option<Series<3>>,
    /// Yaw rate about the body's down axis (rad/s).
    pub yaw_rate: Option<Series<1>>,
    /// Body input `[X, Y, Z, Mz]`, each value held until the next sample.
    pub input: Option<Series<4>>,
    /// What the reader assumed and what it found (frames, units, messages skipped), one line
    /// each, printed with the import report.
    pub notes: Vec<String>,
}

/// The axes of a world frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WorldFrame {
    /// North-east-down (pinc's).
    Ned,
    /// East-north-up (REP 103).
    Enu,
}

/// The axes of a body frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BodyFrame {
    /// Forward-right-down (pinc's).
    Frd,
    /// Forward-left-up (REP 103).
    Flu,
}

impl FromStr for WorldFrame {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "ned" => Ok(Self::Ned),
            "enu" => Ok(Self::Enu),
            _ => Err(format!("world frame {s:?}: expected ned or enu")),
        }
    }
}

impl FromStr for BodyFrame {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "frd" => Ok(Self::Frd),
            "flu" => Ok(Self::Flu),
            _ => Err(format!("body frame {s:?}: expected frd or flu")),
        }
    }
}

impl fmt::Display for WorldFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Ned => "NED",
            Self::Enu => "ENU",
        })
    }
}

impl fmt::Display for BodyFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Frd => "FRD",
            Self::Flu => "FLU",
        })
    }
}

/// A vehicle's thrusters as a reader needs them: commands by output channel (index `c - 1`
/// for channel `c`) to the body input `[X, Y, Z, Mz]` (`Thrusters::input_from_commands`).
pub type CommandsToInput<'a> = &'a dyn Fn(&[f64]) -> Input;
