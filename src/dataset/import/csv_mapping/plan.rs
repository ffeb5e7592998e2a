//! What a mapping reads from one file once resolved against its header ([`Plan`]), and how
//! each quantity of a row becomes pinc's (NED world, FRD body, rad, s). Apart from the
//! resolving because these are the per-row conversions, run once per row.

use super::line_of;
use super::mapping::VelocityAxes;
use super::rotation::{ENU_TO_NED, FRD_TO_FLU, euler_zyx, rotation};
use crate::dataset::import::{CommandsToInput, WorldFrame};
use crate::vehicle::wrap_angle;
use std::f64::consts::FRAC_PI_2;

/// How far a quaternion's length may be from 1 before the row is refused.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// The columns a mapping reads, resolved against one file's header.
#[derive(Default)]
pub(super) struct Columns {
    /// Header index of each column read, in slot order.
    pub(super) index: Vec<usize>,
    /// Header name of each slot.
    pub(super) name: Vec<String>,
}

/// How a row's time is found.
#[derive(Clone, Copy)]
pub(super) enum TimePlan {
    /// A time-stamp column (its slot) and the seconds per unit.
    Column { slot: usize, scale: f64 },
    /// No column: row `i` is at `i / rate` s.
    Rate(f64),
}

impl TimePlan {
    /// The time (s) of data row `row` (from 0) whose parsed fields are `vals`.
    pub(super) fn at(self, vals: &[f64], row: usize) -> f64 {
        match self {
            Self::Column { slot, scale } => vals[slot] * scale,
            Self::Rate(rate) => row as f64 / rate,
        }
    }
}

/// The axes of a vector the mapping reads, and its conversion to pinc's (NED world, FRD body).
pub(super) trait Axes: Copy {
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
pub(super) struct VectorPlan<A> {
    pub(super) slots: [usize; 3],
    pub(super) axes: A,
    pub(super) source: String,
}

impl<A: Axes> VectorPlan<A> {
    /// The vector of a row, in pinc's axes.
    pub(super) fn of(&self, vals: &[f64]) -> [f64; 3] {
        self.axes.to_pinc(self.slots.map(|s| vals[s]))
    }
}

/// How the heading columns turn into roll, pitch, yaw.
pub(super) enum Heading {
    Yaw { slot: usize, scale: f64, enu: bool },
    Quaternion { slots: [usize; 4], columns: String, enu_flu: bool },
}

impl Heading {
    /// Roll, pitch, yaw of a row (NaN for a quaternion with a missing part).
    ///
    /// # Errors
    /// A quaternion off unit length, naming the line of `record` and data row `row` (from 0).
    pub(super) fn attitude(&self, vals: &[f64], record: &csv::ByteRecord, row: usize) -> Result<[f64; 3], String> {
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
pub(super) struct YawRatePlan {
    pub(super) slot: usize,
    pub(super) scale: f64,
    pub(super) source: String,
}

/// How the input columns turn into `[X, Y, Z, Mz]`.
pub(super) enum InputPlan {
    Wrench { slots: [usize; 4], flu: bool },
    Thrusters { slots: Vec<usize>, channels: Vec<usize>, n_channels: usize },
}

impl InputPlan {
    /// The body input of a row; thruster commands go into `commands` (by channel) and through
    /// `commands_to_input`, a missing one makes the whole input NaN.
    pub(super) fn of(
        &self,
        vals: &[f64],
        commands: &mut [f64],
        commands_to_input: Option<CommandsToInput<'_>>,
    ) -> [f64; 4] {
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
pub(super) struct Plan {
    pub(super) cols: Columns,
    pub(super) time: TimePlan,
    pub(super) position: Option<VectorPlan<WorldFrame>>,
    pub(super) heading: Option<Heading>,
    pub(super) velocity: Option<VectorPlan<VelocityAxes>>,
    pub(super) yaw_rate: Option<YawRatePlan>,
    /// The input's conversion and its columns' names.
    pub(super) input: Option<(InputPlan, String)>,
    pub(super) notes: Vec<String>,
}
