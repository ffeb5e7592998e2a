//! A recorded log's MAVLink messages replayed through the [`Estimator`]: what `pinc estimate`
//! writes and what `pinc fit` estimates a stock vehicle's body velocities with. The live
//! session feeds the same filter from the same [`MavlinkMeasurements`], message by message.

use super::Estimator;
use super::health::Health;
use super::mavlink::{MavlinkMeasurements, Observation};
use super::measurement::{Measurement, NoiseSettings};
use super::smoother::Smoothed;
use crate::traits::DiscreteModel;
use crate::vehicle::Thrusters;
use mavlink::dialects::ardupilotmega::MavMessage;

/// How a log is replayed.
#[derive(Debug, Clone)]
pub struct ReplaySettings {
    /// Sample period of the estimate (s): a step every `dt` of the autopilot's ATTITUDE time.
    pub dt: f64,
    /// Surface pressure (hPa) for depth from pressure.
    pub surface_pressure: f64,
    /// Water density (kg/m^3) for depth from pressure.
    pub water_density: f64,
    /// The filter's sensor and process noise.
    pub noise: NoiseSettings,
    /// Leave LOCAL_POSITION_NED out (what a vehicle without a position source knew).
    pub ignore_position: bool,
}

/// One replay's result.
#[derive(Debug, Clone)]
pub struct Replay {
    /// The filter's estimate at every step, as it was then.
    pub filtered: Vec<Smoothed>,
    /// The same steps smoothed backward (each unbroken run on its own).
    pub smoothed: Vec<Smoothed>,
    /// Whether a measurement of the horizontal motion (position, velocity) was fused.
    pub horizontal: bool,
    /// Times the filter restarted after a gap.
    pub restarts: u64,
    /// Measurements that came too late for their step.
    pub late: u64,
    /// The filter's innovations per sensor (since its last restart).
    pub health: Health,
    /// Every depth, heading and yaw-rate measurement, in log order.
    pub measurements: Vec<Measurement>,
    /// Every input the vehicle reported applying (its thruster outputs), with its time.
    pub applied: Vec<(f64, crate::types::Input)>,
}

/// Why a log cannot be replayed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReplayError {
    /// No ATTITUDE: neither heading nor a clock.
    #[error("no ATTITUDE message: no heading, no clock to estimate on")]
    NoAttitude,
    /// The filter never had a depth and a heading at once.
    #[error(
        "the estimator never started (it needs ATTITUDE and a depth: SCALED_PRESSURE2, SCALED_PRESSURE or LOCAL_POSITION_NED)"
    )]
    NeverStarted,
    /// The model failed at a step.
    #[error("the estimator at {t:.3} s: {message}")]
    Model {
        /// Autopilot time (s).
        t: f64,
        /// The model's error.
        message: String,
    },
}

/// Replays `messages` (time stamp, sender, message; in log order) of the system that sends
/// ATTITUDE through an estimator on `model`; `thrusters` turn SERVO_OUTPUT_RAW into the
/// applied input.
///
/// # Errors
/// [`ReplayError`].
pub fn replay<M: DiscreteModel>(
    messages: &[(u64, u8, MavMessage)],
    model: M,
    thrusters: Option<Thrusters>,
    settings: &ReplaySettings,
) -> Result<Replay, ReplayError> {
    let autopilot = messages
        .iter()
        .find_map(|(_, sys, m)| matches!(m, MavMessage::ATTITUDE(_)).then_some(*sys))
        .ok_or(ReplayError::NoAttitude)?;
    let mut reader = MavlinkMeasurements::new(settings.surface_pressure, settings.water_density, thrusters);
    let mut estimator = Estimator::new(model, settings.noise.clone()).keep_history();
    let (mut now, mut next_sample, mut horizontal) = (0.0f64, f64::NEG_INFINITY, false);
    let (mut measurements, mut applied) = (Vec::new(), Vec::new());
    for (_, sys, message) in messages {
        if *sys != autopilot || (settings.ignore_position && matches!(message, MavMessage::LOCAL_POSITION_NED(_))) {
            continue;
        }
        let mut attitude_t = None;
        reader.observe(now, message, |o| match o {
            Observation::Measured(m) => {
                horizontal |= m.observes_horizontal();
                match m {
                    Measurement::Heading { t, .. } => {
                        attitude_t = Some(t);
                        measurements.push(m);
                    }
                    Measurement::Depth { .. } | Measurement::YawRate { .. } => measurements.push(m),
                    _ => {}
                }
                estimator.measure(m);
            }
            Observation::Applied(t, u) => {
                applied.push((t, u));
                estimator.applied(t, u);
            }
        });
        // ATTITUDE is the clock: a sample every dt of its time.
        if let Some(t) = attitude_t {
            now = t;
            if t >= next_sample - 1e-9 {
                estimator.advance(t).map_err(|e| ReplayError::Model { t, message: e.to_string() })?;
                next_sample = if estimator.started() { estimator.ekf().t() + settings.dt } else { t };
            }
        }
    }
    let smoothed = estimator.smoothed();
    if smoothed.is_empty() {
        return Err(ReplayError::NeverStarted);
    }
    Ok(Replay {
        filtered: estimator.filtered(),
        smoothed,
        horizontal,
        restarts: estimator.restarts(),
        late: estimator.late(),
        health: *estimator.ekf().health(),
        measurements,
        applied,
    })
}
