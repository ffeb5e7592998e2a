//! Stage 3, the sensor model: each reading's noise from the first pass's readings, then the
//! depth lag and what it was measured against ([`LagMethod`]); with [`Sensors`], what the
//! replays are told of the sensors. Apart from [`super::sensors`], which holds the
//! measurements' arithmetic, because this is the stage that chooses among them.

use super::sensors::{self, HorizontalNoise};
use super::{Pipeline, Stage};
use crate::estimation::NoiseSettings;
use crate::estimation::replay::Replay;
use crate::model::SensorModel;

/// What the depth sensor's lag is measured against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LagMethod {
    /// The integral of the autopilot's vertical velocity
    /// ([`sensors::depth_lag_from_vertical_velocity`]).
    VerticalVelocity,
    /// The heave equation with the applied heave force ([`sensors::depth_lag_scan`]).
    HeaveEquation,
}

impl LagMethod {
    /// Its name in the report (`vertical_velocity`, `heave_equation`).
    pub fn key(self) -> &'static str {
        match self {
            LagMethod::VerticalVelocity => "vertical_velocity",
            LagMethod::HeaveEquation => "heave_equation",
        }
    }

    /// In words, for the report.
    pub fn describe(self) -> &'static str {
        match self {
            LagMethod::VerticalVelocity => "the integral of the autopilot's vertical velocity",
            LagMethod::HeaveEquation => "the heave equation",
        }
    }
}

/// What a fit's replays tell the estimator of the sensors: the sensor model the model file
/// carries, and the horizontal readings' noise where there is a position source.
#[derive(Debug, Clone, Copy)]
pub(super) struct Sensors {
    pub(super) model: SensorModel,
    pub(super) horizontal: Option<HorizontalNoise>,
}

impl Default for Sensors {
    /// The estimator's defaults (a fit's first pass).
    fn default() -> Self {
        Self { model: default_sensors(), horizontal: None }
    }
}

/// The default sensor model before a fit: the estimator's defaults.
fn default_sensors() -> SensorModel {
    let n = NoiseSettings::default();
    SensorModel {
        depth_std: n.depth_std,
        depth_delay: n.depth_delay,
        heading_std: n.heading_std,
        yaw_rate_std: n.yaw_rate_std,
    }
}

impl Pipeline<'_> {
    /// The sensors' noise from the readings, then the depth lag, from the first pass.
    pub(super) fn sensors(
        &self,
        first: &[Replay],
        on_stage: &mut impl FnMut(Stage),
    ) -> (SensorModel, Vec<&'static str>, Vec<(f64, f64)>, LagMethod) {
        let measurements: Vec<_> = first.iter().flat_map(|r| r.measurements.iter().copied()).collect();
        let (mut sensors, mut sensors_defaulted) = sensors::noise_model(&measurements, &default_sensors());
        let lags = sensors::lag_candidates();
        on_stage(Stage::SensorLag(lags.len()));
        let mut lag_scan = vec![(0.0, 0.0); lags.len()];
        let mut scanned = 0;
        // Against the autopilot's vertical velocity where the recordings have it (its integral
        // has the depth's shape without a lag), else against the heave equation.
        let velocities: Vec<_> = first.iter().map(|r| sensors::vertical_velocities(&r.measurements)).collect();
        let lag_method = if velocities.iter().any(|v| v.len() >= 100) {
            LagMethod::VerticalVelocity
        } else {
            LagMethod::HeaveEquation
        };
        for (run, velocity) in first.iter().zip(&velocities) {
            let depth = sensors::readings(&run.measurements)[0].clone();
            let scan = match lag_method {
                LagMethod::VerticalVelocity => sensors::depth_lag_from_vertical_velocity(&depth, velocity, &lags),
                LagMethod::HeaveEquation => {
                    let heave: Vec<(f64, f64)> = run.applied.iter().map(|(t, u)| (*t, u[2])).collect();
                    sensors::depth_lag_scan(&depth, &heave, &lags)
                }
            };
            if let Some(scan) = scan {
                for (sum, (lag, rss)) in lag_scan.iter_mut().zip(scan) {
                    *sum = (lag, sum.1 + rss);
                }
                scanned += 1;
            }
        }
        // A minimum inside the range is a lag; one at its far end says the readings are not
        // explained (a feedback or a sensor's sample-and-hold can do that to the heave
        // equation). At zero, against the vertical velocity's integral (which has no lag of its
        // own), the reading lags by less than a step of the scan: zero is the answer (with a
        // GPS the autopilot's vertical velocity gave this on ArduSub's simulator); against the
        // heave equation it stays unexplained.
        let best =
            lag_scan.iter().enumerate().filter(|(_, (_, v))| v.is_finite()).min_by(|a, b| a.1.1.total_cmp(&b.1.1));
        let inside = |k: usize| k + 1 < lag_scan.len() && (k > 0 || lag_method == LagMethod::VerticalVelocity);
        match best {
            Some((k, &(lag, _))) if scanned > 0 && inside(k) => sensors.depth_delay = lag,
            _ => sensors_defaulted.push("depth lag"),
        }
        (sensors, sensors_defaulted, lag_scan, lag_method)
    }
}
