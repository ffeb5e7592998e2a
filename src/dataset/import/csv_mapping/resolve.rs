//! A mapping's columns found in one file's header before any row is read: each section
//! becomes its part of the [`Plan`] and a note saying how it is converted. Apart because
//! this is where a mapping meets a file, and where a missing column is reported.

use super::mapping::{
    AngleUnit, CsvMapping, HeadingFrame, HeadingMapping, InputMapping, PositionMapping, QuaternionOrder, TimeMapping,
    TimeUnit, VelocityAxes, VelocityMapping, YawRateMapping,
};
use super::plan::{Columns, Heading, InputPlan, Plan, TimePlan, VectorPlan, YawRatePlan};
use crate::dataset::import::{BodyFrame, WorldFrame};

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
    pub(super) fn new(mapping: &CsvMapping, header: &[String], has_thrusters: bool) -> Result<Self, String> {
        let mut r = Resolver { header, cols: Columns::default(), notes: Vec::new() };
        let time = r.time(&mapping.time)?;
        let position = mapping.position.as_ref().map(|p| r.position(p)).transpose()?;
        let heading = mapping.heading.as_ref().map(|h| r.heading(h)).transpose()?;
        let velocity = mapping.velocity.as_ref().map(|v| r.velocity(v)).transpose()?;
        let yaw_rate = mapping.yaw_rate.as_ref().map(|y| r.yaw_rate(y)).transpose()?;
        let input = mapping.input.as_ref().map(|i| r.input(i, mapping, has_thrusters)).transpose()?;
        Ok(Self { cols: r.cols, time, position, heading, velocity, yaw_rate, input, notes: r.notes })
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
