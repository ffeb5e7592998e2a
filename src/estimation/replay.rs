//! A recorded log's MAVLink messages replayed through the [`Estimator`]: what `pinc estimate`
//! writes and what `pinc fit` estimates a stock vehicle's body velocities with. The live
//! session feeds the same filter from the same [`MavlinkMeasurements`], message by message.

use super::Estimator;
use super::health::Health;
use super::mavlink::{MavlinkMeasurements, Observation, change_time};
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
    /// Every depth, heading, yaw-rate, vertical-velocity, position and NED-velocity
    /// measurement, in log order.
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
        "the estimator never started (it needs a heading, a yaw rate and a depth: ATTITUDE and SCALED_PRESSURE2, \
         SCALED_PRESSURE or LOCAL_POSITION_NED; in a .BIN, ATT, IMU and BARO)"
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
    let mut feeder = Feeder::new(model, settings);
    let mut observed = Vec::new();
    for (_, sys, message) in messages {
        if *sys != autopilot || (settings.ignore_position && matches!(message, MavMessage::LOCAL_POSITION_NED(_))) {
            continue;
        }
        reader.observe(feeder.now, message, |o| observed.push(o));
        // ArduSub sends a sample's messages in one burst, ATTITUDE first and the depth and
        // vertical velocity of the same stamp after it: the burst ends where the next
        // ATTITUDE begins, and the filter steps to the last heading's time only then (as the
        // live session reads a burst whole before the sample).
        if observed.iter().any(is_heading) {
            feeder.tick()?;
        }
        for o in observed.drain(..) {
            feeder.feed(o);
        }
    }
    feeder.tick()?;
    feeder.finish()
}

fn is_heading(o: &Observation) -> bool {
    matches!(o, Observation::Measured(Measurement::Heading { .. }))
}

/// Replays the streams a log reader gave (an ArduPilot `.BIN` through
/// [`read_bin`](crate::dataset::import::read_bin)), in time order, through an estimator on
/// `model`: the attitude's yaw as heading (and the clock), the yaw rate, the depth, the
/// position (its depth left to the depth stream where there is one) and the velocities as
/// measurements, the input as applied.
///
/// # Errors
/// [`ReplayError`]: no attitude, a filter that never started (no yaw rate or depth), a model
/// failure.
pub fn replay_streams<M: DiscreteModel>(
    streams: &crate::dataset::import::StreamSet,
    model: M,
    settings: &ReplaySettings,
) -> Result<Replay, ReplayError> {
    let attitude = streams.attitude.as_ref().filter(|a| !a.is_empty()).ok_or(ReplayError::NoAttitude)?;
    let measured = Observation::Measured;
    let mut events: Vec<Observation> =
        attitude.t.iter().zip(&attitude.v).map(|(&t, a)| measured(Measurement::Heading { t, psi: a[2] })).collect();
    if let Some(s) = &streams.yaw_rate {
        events.extend(s.t.iter().zip(&s.v).map(|(&t, r)| measured(Measurement::YawRate { t, r: r[0] })));
    }
    if let Some(s) = &streams.depth {
        events.extend(s.t.iter().zip(&s.v).map(|(&t, z)| measured(Measurement::Depth { t, z: z[0] })));
    }
    if !settings.ignore_position {
        let depth_sensor = streams.depth.is_some();
        if let Some(s) = &streams.position {
            events.extend(s.t.iter().zip(&s.v).map(|(&t, p)| {
                let z = if depth_sensor { f64::NAN } else { p[2] };
                measured(Measurement::Position { t, x: p[0], y: p[1], z })
            }));
        }
        if let Some(s) = &streams.velocity_ned {
            events.extend(
                s.t.iter()
                    .zip(&s.v)
                    .map(|(&t, v)| measured(Measurement::VelocityNed { t, vn: v[0], ve: v[1], vd: v[2] })),
            );
        }
    }
    if let Some(s) = &streams.velocity_body {
        events.extend(
            s.t.iter().zip(&s.v).map(|(&t, v)| measured(Measurement::VelocityBody { t, u: v[0], v: v[1], w: v[2] })),
        );
    }
    if let Some(s) = &streams.input {
        // Each change dated between the sample that first shows it and the one before, as the
        // live outputs are ([`change_time`]).
        let mut last = None;
        for (&t, u) in s.t.iter().zip(&s.v) {
            let since = change_time(last.as_ref(), t, u);
            last = Some((t, *u));
            events.push(Observation::Applied(since, crate::types::Input::from_row_slice(u)));
        }
    }
    let time = |o: &Observation| match o {
        Observation::Measured(m) | Observation::Unfused(m) => m.t(),
        Observation::Applied(t, _) => *t,
    };
    // In time order; at one time, the heading (which steps the filter) after the rest.
    events.retain(|o| time(o).is_finite());
    events.sort_by(|a, b| time(a).total_cmp(&time(b)).then(is_heading(a).cmp(&is_heading(b))));
    let mut feeder = Feeder::new(model, settings);
    for o in events {
        feeder.feed(o);
        feeder.tick()?;
    }
    feeder.finish()
}

/// The estimator fed observations in log order: the heading's time is the clock, and the
/// filter steps every `dt` of it.
struct Feeder<'a, M: DiscreteModel> {
    estimator: Estimator<M>,
    settings: &'a ReplaySettings,
    now: f64,
    next_sample: f64,
    /// A heading queued since the last tick: its time steps the filter.
    clock: Option<f64>,
    horizontal: bool,
    measurements: Vec<Measurement>,
    applied: Vec<(f64, crate::types::Input)>,
}

impl<'a, M: DiscreteModel> Feeder<'a, M> {
    fn new(model: M, settings: &'a ReplaySettings) -> Self {
        Self {
            estimator: Estimator::new(model, settings.noise.clone()).keep_history(),
            settings,
            now: 0.0,
            next_sample: f64::NEG_INFINITY,
            clock: None,
            horizontal: false,
            measurements: Vec::new(),
            applied: Vec::new(),
        }
    }

    /// Queues an observation (a heading also sets the clock for the next [`Feeder::tick`]).
    fn feed(&mut self, o: Observation) {
        let m = match o {
            Observation::Applied(t, u) => {
                self.applied.push((t, u));
                self.estimator.applied(t, u);
                return;
            }
            Observation::Measured(m) => m,
            Observation::Unfused(_) => return,
        };
        self.horizontal |= m.observes_horizontal();
        if matches!(
            m,
            Measurement::Depth { .. }
                | Measurement::Heading { .. }
                | Measurement::YawRate { .. }
                | Measurement::VerticalVelocity { .. }
                | Measurement::Position { .. }
                | Measurement::VelocityNed { .. }
        ) {
            self.measurements.push(m);
        }
        if let Measurement::Heading { t, .. } = m {
            self.clock = Some(t);
        }
        self.estimator.measure(m);
    }

    /// Steps the filter to the last heading's time when a sample is due there.
    fn tick(&mut self) -> Result<(), ReplayError> {
        let Some(t) = self.clock.take() else { return Ok(()) };
        self.now = t;
        if t >= self.next_sample - 1e-9 {
            self.estimator.advance(t).map_err(|e| ReplayError::Model { t, message: e.to_string() })?;
            let started = self.estimator.started();
            self.next_sample = if started { self.estimator.ekf().t() + self.settings.dt } else { t };
        }
        Ok(())
    }

    fn finish(self) -> Result<Replay, ReplayError> {
        let estimator = self.estimator;
        let smoothed = estimator.smoothed();
        if smoothed.is_empty() {
            return Err(ReplayError::NeverStarted);
        }
        Ok(Replay {
            filtered: estimator.filtered(),
            smoothed,
            horizontal: self.horizontal,
            restarts: estimator.restarts(),
            late: estimator.late(),
            health: *estimator.ekf().health(),
            measurements: self.measurements,
            applied: self.applied,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::import::{Series, StreamSet};
    use crate::types::{Input, SimState};
    use crate::vehicle::Rk4Vehicle;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A log reader's streams of a simulated dive (heading and yaw rate at 12.5 Hz, depth at
    /// 10 Hz with 5 cm of noise, the held input at 25 Hz, no velocity): the smoothed heave and
    /// yaw rate come back within 0.06 m/s and 0.01 rad/s RMS of the simulator's truth (measured
    /// 0.042 and 0.005), where the heave itself swings at over 0.15 m/s RMS.
    #[test]
    fn streams_replayed_estimate_the_velocities_no_stream_holds() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let noise = Normal::new(0.0, 1.0).expect("finite");
        let fine = Rk4Vehicle::with_dt(0.01);
        let (mut s, mut u) = (SimState::from([0.0, 0.0, 1.0, 0.2, 0.0, 0.0, 0.0, 0.0]), Input::zeros());
        let mut truth = Vec::new();
        let mut set = StreamSet {
            attitude: Some(Series::new("att")),
            yaw_rate: Some(Series::new("r")),
            depth: Some(Series::new("z")),
            input: Some(Series::new("u")),
            ..StreamSet::default()
        };
        for k in 0..9000u32 {
            let t = f64::from(k) * 0.01;
            if k % 100 == 0 {
                // A new heave and yaw push every second, pulled back toward 2 m.
                u = Input::new(
                    0.0,
                    0.0,
                    30.0 * (noise.sample(&mut rng) * 0.5) - 20.0 * (s[2] - 2.0),
                    3.0 * noise.sample(&mut rng),
                );
            }
            if k % 8 == 0 {
                set.attitude.as_mut().unwrap().push(t, [0.0, 0.0, crate::vehicle::wrap_angle(s[3])]);
                set.yaw_rate.as_mut().unwrap().push(t, [s[7] + 0.005 * noise.sample(&mut rng)]);
                truth.push((t, s));
            }
            if k % 10 == 0 {
                set.depth.as_mut().unwrap().push(t, [s[2] + 0.05 * noise.sample(&mut rng)]);
            }
            if k % 4 == 0 {
                set.input.as_mut().unwrap().push(t, [u[0], u[1], u[2], u[3]]);
            }
            s = fine.simulate(&s, &[u])[1];
        }
        let settings = ReplaySettings {
            dt: 0.08,
            surface_pressure: 1013.25,
            water_density: 1000.0,
            noise: NoiseSettings { depth_std: 0.05, depth_delay: 0.0, ..NoiseSettings::default() },
            ignore_position: false,
        };
        let run = replay_streams(&set, Rk4Vehicle::with_dt(0.08), &settings).unwrap();
        assert!(!run.horizontal && run.smoothed.len() > 1000);
        let (mut ew, mut er, mut w2, mut n) = (0.0, 0.0, 0.0, 0);
        for step in run.smoothed.iter().filter(|s| s.t > 5.0) {
            let Some(&(_, x)) = truth.iter().find(|(t, _)| (t - step.t).abs() < 1e-6) else { continue };
            ew += (step.state[6] - x[6]).powi(2);
            er += (step.state[7] - x[7]).powi(2);
            w2 += x[6] * x[6];
            n += 1;
        }
        let rms = |v: f64| (v / n as f64).sqrt();
        let (ew, er, w) = (rms(ew), rms(er), rms(w2));
        assert!(n > 1000 && ew < 0.06 && er < 0.01 && w > 0.15, "{n} steps: w {ew} (truth {w}), r {er}");
    }
}
