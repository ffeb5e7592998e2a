//! The pilot's sticks: one reading, checked, and the speeds full deflection stands for.

use crate::traits::DiscreteModel;
use crate::types::{Input, State};
use serde::{Deserialize, Serialize};

/// One reading of the pilot's four sticks, each in `[-1, 1]`, in the body frame
/// forward-right-down: `surge` forward, `sway` to starboard, `heave` down, `yaw` a turn to
/// starboard (clockwise seen from above).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Sticks {
    /// Forward (+) or back.
    pub surge: f64,
    /// Starboard (+) or port.
    pub sway: f64,
    /// Down (+) or up.
    pub heave: f64,
    /// Turn to starboard (+) or port.
    pub yaw: f64,
}

/// A stick reading refused, with what was wrong; the vehicle holds meanwhile.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StickError {
    /// The reading is not a JSON object with the four axes as numbers.
    #[error("stick reading {0}")]
    Malformed(String),
    /// An axis is not a finite number (JSON's `null`, what a browser sends for NaN).
    #[error("stick {axis} is not a number")]
    NotFinite {
        /// The axis.
        axis: &'static str,
    },
    /// An axis past full deflection.
    #[error("stick {axis} is {value}: outside -1..1")]
    OutOfRange {
        /// The axis.
        axis: &'static str,
        /// What came.
        value: f64,
    },
    /// The source of the readings failed (a joystick's address that does not answer).
    #[error("{0}")]
    Source(String),
}

/// The axes' names, in [`Sticks::axes`]'s order.
pub const AXES: [&str; 4] = ["surge", "sway", "heave", "yaw"];

impl Sticks {
    /// All four centred.
    pub const CENTRED: Sticks = Sticks { surge: 0.0, sway: 0.0, heave: 0.0, yaw: 0.0 };

    /// `[surge, sway, heave, yaw]`.
    pub fn axes(&self) -> [f64; 4] {
        [self.surge, self.sway, self.heave, self.yaw]
    }

    /// A reading from its four axes, checked.
    ///
    /// # Errors
    /// An axis not finite or outside `[-1, 1]`.
    pub fn new([surge, sway, heave, yaw]: [f64; 4]) -> Result<Self, StickError> {
        let s = Sticks { surge, sway, heave, yaw };
        for (axis, value) in AXES.into_iter().zip(s.axes()) {
            if !value.is_finite() {
                return Err(StickError::NotFinite { axis });
            }
            if value.abs() > 1.0 {
                return Err(StickError::OutOfRange { axis, value });
            }
        }
        Ok(s)
    }

    /// A reading from one JSON object `{"surge": .., "sway": .., "heave": .., "yaw": ..}`
    /// (other keys, such as a token or a time, are the sender's and ignored here).
    ///
    /// # Errors
    /// Not such an object, an axis missing, `null` or not a number, or outside `[-1, 1]`.
    pub fn from_json(line: &str) -> Result<Self, StickError> {
        let value: serde_json::Value =
            serde_json::from_str(line).map_err(|e| StickError::Malformed(format!("is not JSON: {e}")))?;
        Self::from_value(&value)
    }

    /// [`Sticks::from_json`] on a parsed value.
    ///
    /// # Errors
    /// As [`Sticks::from_json`].
    pub fn from_value(value: &serde_json::Value) -> Result<Self, StickError> {
        let object = value.as_object().ok_or_else(|| StickError::Malformed("is not a JSON object".into()))?;
        let mut axes = [0.0; 4];
        for (slot, axis) in axes.iter_mut().zip(AXES) {
            *slot = match object.get(axis) {
                None => return Err(StickError::Malformed(format!("has no {axis}"))),
                Some(serde_json::Value::Null) => return Err(StickError::NotFinite { axis }),
                Some(v) => v.as_f64().ok_or_else(|| StickError::Malformed(format!("{axis} is not a number: {v}")))?,
            };
        }
        Self::new(axes)
    }

    /// The reading as `MANUAL_CONTROL`'s pilot axes `(x, y, z, r)`, ArduSub's convention: `x`
    /// forward, `y` right, `r` a turn to the right in -1000..=1000, `z` 0..=1000 with 500
    /// neutral and above 500 up (full deflection is 1000 either way, 500 for `z`).
    pub fn to_manual_control(&self) -> (i16, i16, i16, i16) {
        let axis = |a: f64, full: f64| (a.clamp(-1.0, 1.0) * full).round() as i16;
        (axis(self.surge, 1000.0), axis(self.sway, 1000.0), 500 - axis(self.heave, 500.0), axis(self.yaw, 1000.0))
    }

    /// A ground station's joystick (`MANUAL_CONTROL`'s `x, y, z, r`, as
    /// [`Sticks::to_manual_control`] writes them) as a reading, checked. An axis at `i16::MAX`
    /// is one the sender does not use (MAVLink's mark): centred.
    ///
    /// # Errors
    /// An axis outside its range (past full deflection).
    pub fn from_manual_control(x: i16, y: i16, z: i16, r: i16) -> Result<Self, StickError> {
        let axis = |v: i16, centre: f64, full: f64| if v == i16::MAX { 0.0 } else { (f64::from(v) - centre) / full };
        Self::new([axis(x, 0.0, 1000.0), axis(y, 0.0, 1000.0), -axis(z, 500.0, 500.0), axis(r, 0.0, 1000.0)])
    }

    /// Whether every axis lies within `deadband` of the centre.
    pub fn centred(&self, deadband: f64) -> bool {
        self.axes().iter().all(|a| a.abs() <= deadband)
    }
}

/// What full deflection of each stick asks for: surge, sway and heave speeds over the ground
/// (m/s) and the yaw rate (rad/s).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StickLimits {
    /// Surge (m/s).
    pub surge: f64,
    /// Sway (m/s).
    pub sway: f64,
    /// Heave (m/s).
    pub heave: f64,
    /// Yaw rate (rad/s).
    pub yaw_rate: f64,
}

/// The share of the model's steady speed at full thrust that full deflection asks for: the
/// rest is what the controller has left to hold depth, heading and a current.
pub const STEADY_SPEED_SHARE: f64 = 0.8;
/// How long the model is run at full thrust to find its steady speeds (s).
const STEADY_RUN_S: f64 = 15.0;

impl StickLimits {
    /// What full deflection asks for on `model` within the input bounds `(lo, hi)`: on each
    /// axis [`STEADY_SPEED_SHARE`] of the slower of its two steady speeds (the model run from
    /// rest at full thrust one way and the other), or `wanted` where given (surge, sway, heave
    /// m/s, yaw rate rad/s) up to that steady speed.
    ///
    /// An axis the model cannot move (its bounds zero there) gets 0: its stick does nothing.
    ///
    /// # Errors
    /// The model fails on the run.
    pub fn of_model<M: DiscreteModel>(
        model: &M,
        (lo, hi): (Input, Input),
        wanted: [Option<f64>; 4],
    ) -> Result<Self, String> {
        let mut ws = model.workspace();
        let steps = (STEADY_RUN_S / model.dt()).ceil() as usize;
        let mut steady = [f64::INFINITY; 4];
        for (axis, speed) in steady.iter_mut().enumerate() {
            for bound in [lo[axis], hi[axis]] {
                let mut u = Input::zeros();
                u[axis] = bound;
                let mut x = State::zeros();
                x[3] = 1.0;
                let mut next = State::zeros();
                for _ in 0..steps {
                    model
                        .step(&mut ws, &x, &u, &mut next)
                        .map_err(|e| format!("the model at full {}: {e}", AXES[axis]))?;
                    std::mem::swap(&mut x, &mut next);
                    // Depth and heading as they were: only the velocity is sought.
                    (x[2], x[3], x[4]) = (0.0, 1.0, 0.0);
                }
                *speed = speed.min(x[5 + axis].abs());
            }
            // An axis the model never learned (a fit of heave and yaw alone: its bounds are
            // zero there) does not move: its stick asks for nothing.
            if !(speed.is_finite() && *speed > 1e-3) {
                *speed = 0.0;
            }
        }
        // An owner's cap may ask for up to the steady speed itself (a current along helps; one
        // against leaves the vehicle short, going as fast as it can).
        let limit = |axis: usize| wanted[axis].map_or(STEADY_SPEED_SHARE * steady[axis], |w| w.min(steady[axis]));
        Ok(Self { surge: limit(0), sway: limit(1), heave: limit(2), yaw_rate: limit(3) })
    }

    /// `[surge, sway, heave, yaw_rate]`.
    pub fn axes(&self) -> [f64; 4] {
        [self.surge, self.sway, self.heave, self.yaw_rate]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reading_is_refused_with_what_is_wrong() {
        assert_eq!(
            Sticks::from_json(r#"{"surge": 0.5, "sway": 0, "heave": -1, "yaw": 0.25, "token": "x"}"#),
            Ok(Sticks { surge: 0.5, sway: 0.0, heave: -1.0, yaw: 0.25 })
        );
        assert_eq!(
            Sticks::from_json(r#"{"surge": null, "sway": 0, "heave": 0, "yaw": 0}"#),
            Err(StickError::NotFinite { axis: "surge" })
        );
        assert_eq!(
            Sticks::from_json(r#"{"surge": 0, "sway": 1.5, "heave": 0, "yaw": 0}"#).unwrap_err().to_string(),
            "stick sway is 1.5: outside -1..1"
        );
        assert_eq!(
            Sticks::from_json(r#"{"surge": 0, "sway": 0, "yaw": 0}"#).unwrap_err().to_string(),
            "stick reading has no heave"
        );
        assert!(matches!(Sticks::from_json("[1, 2]"), Err(StickError::Malformed(_))));
        assert!(matches!(Sticks::from_json(r#"{"surge": "1""#), Err(StickError::Malformed(_))));
        assert_eq!(Sticks::new([0.0, f64::NAN, 0.0, 0.0]), Err(StickError::NotFinite { axis: "sway" }));
    }

    #[test]
    fn a_joystick_reads_back_as_the_sticks_it_was_sent_as() {
        // Up on the left stick is MANUAL_CONTROL's z above 500: the sticks' heave is down +.
        assert_eq!(Sticks::from_manual_control(0, 0, 1000, 0), Ok(Sticks { heave: -1.0, ..Sticks::CENTRED }));
        assert_eq!(Sticks::from_manual_control(0, 0, 500, 0), Ok(Sticks::CENTRED));
        assert_eq!(
            Sticks::from_manual_control(i16::MAX, -1000, i16::MAX, 250).map(|s| s.axes()),
            Ok([0.0, -1.0, 0.0, 0.25])
        );
        for s in [
            Sticks { surge: 0.5, sway: -0.3, heave: 0.25, yaw: -1.0 },
            Sticks { surge: -1.0, sway: 1.0, heave: -1.0, yaw: 0.002 },
        ] {
            let (x, y, z, r) = s.to_manual_control();
            let back = Sticks::from_manual_control(x, y, z, r).unwrap();
            for (a, b) in s.axes().into_iter().zip(back.axes()) {
                approx::assert_abs_diff_eq!(a, b, epsilon = 1e-3);
            }
        }
        assert_eq!(
            Sticks::from_manual_control(1200, 0, 500, 0).unwrap_err().to_string(),
            "stick surge is 1.2: outside -1..1"
        );
        assert_eq!(
            Sticks::from_manual_control(0, 0, -20, 0),
            Err(StickError::OutOfRange { axis: "heave", value: 1.04 })
        );
    }

    #[test]
    fn full_deflection_is_a_share_of_the_models_steady_speed() {
        use crate::vehicle::{Rk4Vehicle, terminal_speed};
        let v = Rk4Vehicle::with_dt(0.08);
        let p = v.params;
        let (lo, hi) = (
            Input::from_column_slice(&[-80.0, -60.0, -70.0, -20.0]),
            Input::from_column_slice(&[85.0, 60.0, 70.0, 20.0]),
        );
        let l = StickLimits::of_model(&v, (lo, hi), [None, Some(0.3), None, Some(100.0)]).unwrap();
        // Surge: the slower way (back, 80 N) against the closed form of the steady speed.
        let back = terminal_speed(80.0, p.x_u, p.x_uu);
        approx::assert_relative_eq!(l.surge, STEADY_SPEED_SHARE * back, max_relative = 1e-3);
        assert_eq!(l.sway, 0.3);
        // Asked for more than it can: the steady speed itself.
        let shared = StickLimits::of_model(&v, (lo, hi), [None; 4]).unwrap();
        approx::assert_relative_eq!(l.yaw_rate * STEADY_SPEED_SHARE, shared.yaw_rate, max_relative = 1e-12);
        // Heave: buoyancy helps one way and hinders the other; the slower is taken.
        let slower = terminal_speed(70.0 - p.net_buoyancy().abs(), p.z_w, p.z_ww);
        approx::assert_relative_eq!(l.heave, STEADY_SPEED_SHARE * slower, max_relative = 1e-3);
        // No surge force in the bounds: the surge stick asks for nothing.
        let none = (Input::from_column_slice(&[0.0, -60.0, -70.0, -20.0]), hi);
        assert_eq!(StickLimits::of_model(&v, none, [Some(0.5), None, None, None]).unwrap().surge, 0.0);
    }
}
