//! What a vehicle measures, each with its autopilot time, and the noise the filter assumes
//! for each.

use crate::types::{NS, NU};
use serde::Serialize;

/// One measurement (autopilot time `t`, s).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Measurement {
    /// Depth `z` (m, down): a pressure sensor, or the position source's `z`.
    Depth {
        /// Time (s).
        t: f64,
        /// Depth (m).
        z: f64,
    },
    /// Heading `psi` (rad, from north, clockwise seen from above).
    Heading {
        /// Time (s).
        t: f64,
        /// Heading (rad; wrapped or not).
        psi: f64,
    },
    /// Yaw rate `r` (rad/s).
    YawRate {
        /// Time (s).
        t: f64,
        /// Yaw rate (rad/s).
        r: f64,
    },
    /// NED position (m): GPS, an underwater positioning system, a DVL's dead reckoning.
    Position {
        /// Time (s).
        t: f64,
        /// North (m).
        x: f64,
        /// East (m).
        y: f64,
        /// Down (m); NaN to leave depth to a depth sensor.
        z: f64,
    },
    /// A position fix of the vehicle's own positioning sensor (a USBL such as Water Linked's
    /// Underwater GPS, a GPS at the surface), turned into the autopilot's local NED frame (m),
    /// at the time it was measured.
    Fix {
        /// Time (s) it was measured.
        t: f64,
        /// North (m).
        x: f64,
        /// East (m).
        y: f64,
        /// Its standard deviation (m) as the sensor states it; NaN where it states none.
        std: f64,
    },
    /// NED velocity (m/s), as the autopilot's EKF reports it.
    VelocityNed {
        /// Time (s).
        t: f64,
        /// North (m/s).
        vn: f64,
        /// East (m/s).
        ve: f64,
        /// Down (m/s).
        vd: f64,
    },
    /// Vertical velocity (m/s, down) as the autopilot's EKF reports it: ArduSub estimates it
    /// from its accelerometers and depth sensor with or without a position source.
    VerticalVelocity {
        /// Time (s).
        t: f64,
        /// Down (m/s).
        vd: f64,
    },
    /// Body velocity (m/s): a DVL.
    VelocityBody {
        /// Time (s).
        t: f64,
        /// Surge (m/s).
        u: f64,
        /// Sway (m/s).
        v: f64,
        /// Heave (m/s).
        w: f64,
    },
}

impl Measurement {
    /// Its time (s).
    pub fn t(&self) -> f64 {
        match *self {
            Measurement::Depth { t, .. }
            | Measurement::Heading { t, .. }
            | Measurement::YawRate { t, .. }
            | Measurement::Position { t, .. }
            | Measurement::Fix { t, .. }
            | Measurement::VelocityNed { t, .. }
            | Measurement::VerticalVelocity { t, .. }
            | Measurement::VelocityBody { t, .. } => t,
        }
    }

    /// Its kind's name (`depth`, `heading`, `yaw_rate`, `position`, `fix`, `velocity_ned`,
    /// `vertical_velocity`, `velocity_body`).
    pub fn kind(&self) -> &'static str {
        match self {
            Measurement::Depth { .. } => "depth",
            Measurement::Heading { .. } => "heading",
            Measurement::YawRate { .. } => "yaw_rate",
            Measurement::Position { .. } => "position",
            Measurement::Fix { .. } => "fix",
            Measurement::VelocityNed { .. } => "velocity_ned",
            Measurement::VerticalVelocity { .. } => "vertical_velocity",
            Measurement::VelocityBody { .. } => "velocity_body",
        }
    }

    /// Whether it observes the horizontal motion (a position or a velocity).
    pub fn observes_horizontal(&self) -> bool {
        matches!(
            self,
            Measurement::Position { .. }
                | Measurement::Fix { .. }
                | Measurement::VelocityNed { .. }
                | Measurement::VelocityBody { .. }
        )
    }
}

/// Standard deviations the filter assumes: of each sensor, of the model's error per step,
/// and of the disturbance.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NoiseSettings {
    /// Depth sensor (m). A Bar30 resolves 2 mm but waves, a tether's pull and the sensor's
    /// offset from the centre of the vehicle add more; ArduSub's simulator has 0.12 m.
    pub depth_std: f64,
    /// How long the depth sensor lags (s): its reading at `t` is taken as the depth at
    /// `t - depth_delay` (to first order, `z - depth_delay w`). ArduSub's simulator lags
    /// 0.02-0.04 s (its readings at their own stamps against its truth; `pinc fit` finds 0.04
    /// against the autopilot's vertical velocity); a Bar30 behind ArduSub lags by its
    /// conversion and the autopilot's averaging between reads. The default, 0.04 s (0.1 while
    /// each sample's depth was fused a sample late: that delay is gone, docs/MODEL.md 12).
    pub depth_delay: f64,
    /// Heading (rad): the autopilot's attitude estimate.
    pub heading_std: f64,
    /// Yaw rate (rad/s): the gyro (ArduSub's simulator matches its truth within 0.01 rad/s).
    pub yaw_rate_std: f64,
    /// Position (m): GPS at the surface, an underwater positioning system.
    pub position_std: f64,
    /// NED velocity (m/s) from the autopilot's EKF.
    pub velocity_ned_std: f64,
    /// Vertical velocity (m/s) from the autopilot's EKF (accelerometers and depth sensor):
    /// ArduSub's simulator without a position source reports its truth within 0.018 m/s RMS
    /// (measured, `GLOBAL_POSITION_INT.vz` against `SIM_STATE`); a real vehicle's vibration
    /// and accelerometer bias add more.
    pub vertical_velocity_std: f64,
    /// Body velocity (m/s) of a DVL.
    pub velocity_body_std: f64,
    /// The model's error per sample period on `x y z psi u v w r`.
    pub process_std: [f64; NS],
    /// Spread of the disturbance `X Y Z Mz` (N, N m) over time.
    pub disturbance_std: [f64; NU],
    /// How long the disturbance stays correlated (s).
    pub disturbance_time_constant: f64,
    /// Innovations beyond this many standard deviations are left out.
    pub gate: f64,
}

impl Default for NoiseSettings {
    fn default() -> Self {
        Self {
            depth_std: 0.1,
            depth_delay: 0.04,
            heading_std: 0.02,
            yaw_rate_std: 0.005,
            position_std: 0.3,
            velocity_ned_std: 0.1,
            vertical_velocity_std: 0.05,
            velocity_body_std: 0.03,
            process_std: [0.005, 0.005, 0.01, 0.002, 0.02, 0.02, 0.05, 0.02],
            disturbance_std: [5.0, 5.0, 5.0, 1.0],
            disturbance_time_constant: 60.0,
            gate: 5.0,
        }
    }
}

impl NoiseSettings {
    /// The model's error per step on the whole filter state (the disturbance's is set by
    /// the filter from its spread and time constant).
    pub fn process_std(&self) -> [f64; NS] {
        self.process_std
    }

    /// Checks that every value is finite and positive.
    ///
    /// # Errors
    /// The first that is not, by name.
    pub fn validate(&self) -> Result<(), String> {
        let named = [
            ("depth_std", self.depth_std),
            ("heading_std", self.heading_std),
            ("yaw_rate_std", self.yaw_rate_std),
            ("position_std", self.position_std),
            ("velocity_ned_std", self.velocity_ned_std),
            ("vertical_velocity_std", self.vertical_velocity_std),
            ("velocity_body_std", self.velocity_body_std),
            ("disturbance_time_constant", self.disturbance_time_constant),
            ("gate", self.gate),
        ];
        let lists = self
            .process_std
            .iter()
            .map(|v| ("process_std", *v))
            .chain(self.disturbance_std.iter().map(|v| ("disturbance_std", *v)));
        if !(self.depth_delay.is_finite() && self.depth_delay >= 0.0) {
            return Err(format!(
                "estimator depth_delay must be a number of seconds, zero or more, got {}",
                self.depth_delay
            ));
        }
        for (name, v) in named.into_iter().chain(lists) {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("estimator noise {name} must be a positive number, got {v}"));
            }
        }
        Ok(())
    }
}

/// The white noise of a sampled signal: each sample against the straight line through its
/// two neighbours (in time), scaled to one sample's deviation, as a robust spread (1.4826
/// times the median absolute value: a few jumps or manoeuvres do not inflate it). The
/// signal's own curvature over two sample periods is left in; at 10 Hz and more it is far
/// below the noise of a depth sensor. `wrap` treats the values as angles. `None` for fewer
/// than 10 usable samples.
pub fn white_noise_std(samples: &[(f64, f64)], wrap: bool) -> Option<f64> {
    let diff = |a: f64, b: f64| if wrap { crate::vehicle::wrap_angle(a - b) } else { a - b };
    let mut d: Vec<f64> = samples
        .windows(3)
        .filter_map(|w| {
            let ((t0, y0), (t1, y1), (t2, y2)) = (w[0], w[1], w[2]);
            let (h0, h1) = (t1 - t0, t2 - t1);
            if !(h0 > 0.0 && h1 > 0.0) {
                return None;
            }
            // y1 against the line through its neighbours: y0 + (y2 - y0) h0 / (h0 + h1).
            let (a, b) = (h1 / (h0 + h1), h0 / (h0 + h1));
            let line = y0 + b * diff(y2, y0);
            let r = diff(y1, line);
            Some((r / (1.0 + a * a + b * b).sqrt()).abs())
        })
        .filter(|r| r.is_finite())
        .collect();
    if d.len() < 10 {
        return None;
    }
    let mid = d.len() / 2;
    let (_, median, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
    Some(1.4826 * *median)
}
