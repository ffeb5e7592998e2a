//! What the filter's innovations say of its model: per sensor, how far the measurements fall
//! from what the model predicted in units of the spread it predicted (the normalised
//! innovation squared, NIS, 1 on average for a filter whose model and noise are right) and how
//! many were gated out. From these the filter adapts (the process noise of the motion a sensor
//! observes grows while its NIS stays high, and shrinks back), and a live session stops when
//! the estimate has lost the vehicle.

use std::fmt;

/// The sensors the filter fuses, as the health figures name them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sensor {
    /// The depth sensor.
    Depth,
    /// The autopilot's heading.
    Heading,
    /// The gyro's yaw rate.
    YawRate,
    /// A position source.
    Position,
    /// A velocity (the autopilot's NED velocity, a DVL).
    Velocity,
}

/// Number of [`Sensor`]s.
pub const SENSORS: usize = 5;

impl Sensor {
    /// Every sensor, in index order.
    pub const ALL: [Sensor; SENSORS] =
        [Sensor::Depth, Sensor::Heading, Sensor::YawRate, Sensor::Position, Sensor::Velocity];

    /// Its index in the health arrays.
    pub fn index(self) -> usize {
        self as usize
    }

    /// `depth`, `heading`, `yaw_rate`, `position`, `velocity`.
    pub fn name(self) -> &'static str {
        match self {
            Sensor::Depth => "depth",
            Sensor::Heading => "heading",
            Sensor::YawRate => "yaw_rate",
            Sensor::Position => "position",
            Sensor::Velocity => "velocity",
        }
    }

    /// The motion the model gets wrong when this sensor's innovations stay large, in words.
    pub fn motion(self) -> &'static str {
        match self {
            Sensor::Depth => "heave (depth and its rate)",
            Sensor::Heading | Sensor::YawRate => "yaw (heading and turn rate)",
            Sensor::Position | Sensor::Velocity => "surge and sway",
        }
    }
}

/// Weight of the newest measurement in the fast averages (about two seconds of a 12.5 Hz
/// stream): what the live stop looks at.
const FAST: f64 = 1.0 / 25.0;
/// In the slow averages (about twenty seconds): what the adaptation and the summary look at.
const SLOW: f64 = 1.0 / 250.0;
/// Measurements of a sensor before its averages are taken as meaningful.
const WARM_UP: u64 = 25;

/// The running figures of one sensor.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SensorHealth {
    /// Measurements seen.
    pub count: u64,
    /// Of them, gated out.
    pub rejected: u64,
    /// Exponentially weighted mean NIS, about the last two seconds.
    pub nis_fast: f64,
    /// About the last twenty seconds.
    pub nis_slow: f64,
    /// Fraction gated out, about the last two seconds.
    pub rejected_fast: f64,
    /// The largest slow mean NIS of the run (once the slow mean spans its window).
    pub nis_slow_max: f64,
}

impl SensorHealth {
    fn add(&mut self, nis: f64, rejected: bool) {
        // One wild value must not swamp the averages: a NIS is counted at most as 100 (10 sigma).
        let nis = if nis.is_finite() { nis.min(100.0) } else { 100.0 };
        let r = f64::from(u8::from(rejected));
        if self.count == 0 {
            (self.nis_fast, self.nis_slow, self.rejected_fast) = (nis, nis, r);
        } else {
            // Until the averages have as many samples as their span, they are plain means.
            let n = (self.count + 1) as f64;
            let (fast, slow) = (FAST.max(1.0 / n), SLOW.max(1.0 / n));
            self.nis_fast += fast * (nis - self.nis_fast);
            self.nis_slow += slow * (nis - self.nis_slow);
            self.rejected_fast += fast * (r - self.rejected_fast);
        }
        self.count += 1;
        self.rejected += u64::from(rejected);
        // The slow mean's largest value once it spans its whole window: a start-up transient
        // (the autopilot aligning its heading) is not a model that fits badly.
        if self.count as f64 >= 1.0 / SLOW {
            self.nis_slow_max = self.nis_slow_max.max(self.nis_slow);
        }
    }

    /// Whether enough measurements came for the averages to mean something.
    pub fn warm(&self) -> bool {
        self.count >= WARM_UP
    }
}

/// The health of a filter: every sensor's figures.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Health {
    /// By [`Sensor::index`].
    pub sensors: [SensorHealth; SENSORS],
}

/// Past this slow mean NIS a sensor's motion counts as one the model gets wrong (the errors
/// are twice the spread the filter predicts, on average over twenty seconds).
pub const MISFIT_NIS: f64 = 4.0;

/// When the estimate counts as having lost the vehicle: over the last two seconds, more than
/// this fraction of a sensor's measurements gated out...
pub const LOST_REJECTED: f64 = 0.5;
/// ...or its mean NIS beyond this (errors eight times the predicted spread).
pub const LOST_NIS: f64 = 64.0;

/// Why the estimate is taken as lost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lost {
    /// The sensor whose measurements the estimate no longer follows.
    pub sensor: Sensor,
    /// Its fraction gated out over the last two seconds.
    pub rejected: f64,
    /// Its mean NIS over the last two seconds.
    pub nis: f64,
}

impl fmt::Display for Lost {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "the state estimate no longer follows the {} sensor: over the last 2 s {:.0} % of its measurements were \
             gated out and the rest fell {:.1} standard deviations from the model's prediction on average; the \
             model does not describe the {} of this vehicle: fit a model to it (pinc identify, then a hybrid)",
            self.sensor.name(),
            100.0 * self.rejected,
            self.nis.sqrt(),
            self.sensor.motion()
        )
    }
}

impl Health {
    /// Adds one measurement's NIS (before any reacquisition) and whether it was gated out.
    pub fn add(&mut self, sensor: Sensor, nis: f64, rejected: bool) {
        self.sensors[sensor.index()].add(nis, rejected);
    }

    /// One sensor's figures.
    pub fn sensor(&self, s: Sensor) -> &SensorHealth {
        &self.sensors[s.index()]
    }

    /// The first sensor (depth, heading, yaw rate) whose measurements the estimate no longer
    /// follows, if any.
    pub fn lost(&self) -> Option<Lost> {
        [Sensor::Depth, Sensor::Heading, Sensor::YawRate].into_iter().find_map(|sensor| {
            let h = self.sensor(sensor);
            (h.warm() && (h.rejected_fast > LOST_REJECTED || h.nis_fast > LOST_NIS)).then_some(Lost {
                sensor,
                rejected: h.rejected_fast,
                nis: h.nis_fast,
            })
        })
    }

    /// The motions the model got wrong over the run, in words an owner acts on (empty where
    /// it fitted): one line per sensor whose slow mean NIS passed [`MISFIT_NIS`].
    pub fn misfits(&self) -> Vec<String> {
        let mut seen_motion: Vec<&str> = Vec::new();
        Sensor::ALL
            .iter()
            .filter_map(|&s| {
                let h = self.sensor(s);
                if h.nis_slow_max <= MISFIT_NIS || seen_motion.contains(&s.motion()) {
                    return None;
                }
                seen_motion.push(s.motion());
                Some(format!(
                    "the model gets the vehicle's {} wrong: {} measurements fell up to {:.1} standard deviations from \
                     its predictions (20 s mean); fit a model to this vehicle (pinc identify on its recordings, then \
                     a hybrid) to cure it",
                    s.motion(),
                    s.name(),
                    h.nis_slow_max.sqrt()
                ))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_filter_whose_innovations_match_their_spread_is_healthy() {
        let mut h = Health::default();
        for k in 0..500 {
            // NIS of a chi-square with one degree of freedom averages 1.
            let nis = [0.1, 0.5, 1.0, 2.4][k % 4];
            h.add(Sensor::Heading, nis, false);
            h.add(Sensor::YawRate, nis, false);
            h.add(Sensor::Depth, nis, false);
        }
        assert!(h.lost().is_none());
        assert!(h.misfits().is_empty(), "{:?}", h.misfits());
        assert!((h.sensor(Sensor::Depth).nis_slow - 1.0).abs() < 0.1);
    }

    #[test]
    fn gated_out_measurements_over_two_seconds_mean_the_vehicle_is_lost() {
        let mut h = Health::default();
        for _ in 0..100 {
            h.add(Sensor::Heading, 1.0, false);
        }
        let mut lost_after = None;
        for k in 0..50 {
            h.add(Sensor::Heading, 60.0, true);
            if lost_after.is_none() && h.lost().is_some() {
                lost_after = Some(k + 1);
            }
        }
        // Half of a two-second window: about 17 samples of a 12.5 Hz stream (1.4 s).
        let n = lost_after.expect("lost");
        assert!((10..=25).contains(&n), "lost after {n} rejections");
        let text = h.lost().unwrap().to_string();
        assert!(text.contains("heading") && text.contains("yaw"), "{text}");
    }

    #[test]
    fn a_motion_the_model_gets_wrong_is_named_once() {
        let mut h = Health::default();
        for _ in 0..400 {
            h.add(Sensor::Depth, 9.0, false);
            h.add(Sensor::Heading, 1.0, false);
        }
        let m = h.misfits();
        assert_eq!(m.len(), 1, "{m:?}");
        assert!(m[0].contains("heave") && m[0].contains("3.0 standard deviations"), "{m:?}");
    }
}
