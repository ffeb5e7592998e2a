//! The vehicle's state `x y z psi u v w r` rebuilt from ArduSub's standard messages, on the
//! autopilot's own time base (`time_boot_ms`). Each message is read once, by
//! [`MavlinkMeasurements`] (the reading the state estimator takes too): the assembler keeps
//! the newest of each part and hands the same observations on.
//!
//! - heading `psi` (unwrapped across +-pi) and yaw rate `r`: `ATTITUDE` (`yaw`, `yawspeed`);
//! - position `x y z` and the NED velocity: `LOCAL_POSITION_NED`, which ArduSub sends only
//!   once its EKF has a position source (GPS at the surface, a DVL, an underwater GPS);
//! - body velocities `u v w`: the NED velocity turned by the heading of the `ATTITUDE`
//!   nearest in time (pinc's 4-DOF kinematics: roll and pitch taken as zero);
//! - depth `z` without a position: `SCALED_PRESSURE2` (ArduSub's external depth sensor) or
//!   `SCALED_PRESSURE`, as `(p - p_surface) / (rho g)`.
//!
//! Every part keeps its time stamp; a part older than [`StateConfig::max_age`] (autopilot
//! time) is stale and reported as missing (`NaN`), never held.

use super::link::Received;
use crate::estimation::Measurement;
use crate::estimation::mavlink::{MavlinkMeasurements, Observation};
use crate::types::{NS, SIM_STATE_NAMES};
use crate::vehicle::Thrusters;
use mavlink::dialects::ardupilotmega::MavMessage;
use std::collections::VecDeque;
use std::fmt;
use std::time::Instant;

/// The parts of the state, each from its own message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// `psi` from `ATTITUDE.yaw`.
    Heading,
    /// `r` from `ATTITUDE.yawspeed`.
    YawRate,
    /// `x y z` from `LOCAL_POSITION_NED`.
    Position,
    /// `u v w` from `LOCAL_POSITION_NED`'s velocity turned by the heading.
    Velocity,
    /// `z` from the position, or from the pressure without one.
    Depth,
}

impl Part {
    /// Every part, in the order of [`RawState::parts`].
    pub const ALL: [Part; 5] = [Part::Heading, Part::YawRate, Part::Position, Part::Velocity, Part::Depth];

    /// Its name in output (`heading`, `yaw_rate`, `position`, `velocity`, `depth`).
    pub fn name(self) -> &'static str {
        match self {
            Part::Heading => "heading",
            Part::YawRate => "yaw_rate",
            Part::Position => "position",
            Part::Velocity => "velocity",
            Part::Depth => "depth",
        }
    }
}

/// Settings of the reconstruction.
#[derive(Debug, Clone, PartialEq)]
pub struct StateConfig {
    /// A part older than this (s, autopilot time) is stale.
    pub max_age: f64,
    /// Absolute pressure at the surface (hPa), for depth from pressure.
    pub surface_pressure_hpa: f64,
    /// Water density (kg/m^3): ArduSub's `BARO_SPEC_GRAV` times 1000.
    pub water_density: f64,
}

impl Default for StateConfig {
    fn default() -> Self {
        // 0.5 s: five samples at the 10 Hz the SITL logs show for LOCAL_POSITION_NED.
        Self { max_age: 0.5, surface_pressure_hpa: 1013.25, water_density: 1000.0 }
    }
}

/// One part's time stamp and age.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PartStatus {
    /// The part.
    pub part: Part,
    /// Autopilot time of its newest sample (s), if any arrived.
    pub stamp: Option<f64>,
    /// Age at the estimate's time (s).
    pub age: Option<f64>,
    /// Seen and not older than the limit.
    pub fresh: bool,
}

/// Which controller the fresh parts allow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Capability {
    /// Every part: the full-state MPC.
    Full,
    /// Heading, yaw rate and depth but no body velocities (no position source such as a
    /// DVL): the MPC runs on the model-based state estimate (`crate::estimation`).
    DepthHeading,
    /// Heading or depth missing: no controller.
    None,
}

impl fmt::Display for Capability {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Capability::Full => {
                "full state (a position source gives the body velocities): the MPC runs on the state \
                 estimate with position and velocity fused"
            }
            Capability::DepthHeading => {
                "depth and heading only (no position source such as a DVL or GPS, so no measured body \
                 velocities u v w): the MPC runs on the state estimate, its body velocities from the model \
                 and the applied thrust, with a position-free model"
            }
            Capability::None => "no controller: heading or depth missing",
        })
    }
}

/// Where the depth came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthSource {
    /// `LOCAL_POSITION_NED.z`.
    Position,
    /// A pressure message.
    Pressure,
}

/// The state at one autopilot time.
#[derive(Debug, Clone, PartialEq)]
pub struct RawState {
    /// Autopilot time (s since its boot).
    pub t: f64,
    /// `x y z psi u v w r` (m, rad, m/s, rad/s), `NaN` where a part is stale or missing.
    pub sim: [f64; NS],
    /// Each part's stamp and age, in [`Part::ALL`] order.
    pub parts: [PartStatus; 5],
    /// Where `z` came from, when fresh.
    pub depth_source: Option<DepthSource>,
    /// What the fresh parts allow.
    pub capability: Capability,
}

impl RawState {
    /// The status of one part.
    pub fn part(&self, part: Part) -> &PartStatus {
        &self.parts[Part::ALL.iter().position(|p| *p == part).expect("every part is listed")]
    }

    /// `(name, value)` pairs of `sim`, `None` for a missing value.
    pub fn named(&self) -> impl Iterator<Item = (&'static str, Option<f64>)> + '_ {
        SIM_STATE_NAMES.into_iter().zip(self.sim.iter().map(|v| v.is_finite().then_some(*v)))
    }
}

#[derive(Debug, Clone, Copy)]
struct Attitude {
    t: f64,
    yaw: f64,
    yaw_rate: f64,
}

#[derive(Debug, Clone, Copy)]
struct Local {
    t: f64,
    position: [f64; 3],
    velocity_ned: [f64; 3],
}

/// How many `ATTITUDE`s are kept to find the one nearest a position's time (1.3 s at 25 Hz).
const ATTITUDE_HISTORY: usize = 32;
/// A time stamp this far before the newest is a reboot of the autopilot (s).
const REBOOT_STEP: f64 = 5.0;

/// Builds [`RawState`]s from the messages of one autopilot.
#[derive(Debug, Clone)]
pub struct StateAssembler {
    config: StateConfig,
    /// Reads every message (the one place messages become measurements).
    reader: MavlinkMeasurements,
    attitudes: VecDeque<Attitude>,
    local: Option<Local>,
    /// (autopilot time, depth m) of the newest pressure reading.
    depth: Option<(f64, f64)>,
    /// The newest autopilot time seen and when it was received.
    clock: Option<(f64, Instant)>,
    /// Time of the last sample returned by [`StateAssembler::update`]: samples never go back.
    last_sample: Option<f64>,
    /// When the newest position arrived (host clock).
    local_arrival: Option<Instant>,
}

impl Default for StateAssembler {
    fn default() -> Self {
        Self::new(StateConfig::default())
    }
}

fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(std::f64::consts::TAU);
    if w > std::f64::consts::PI { w - std::f64::consts::TAU } else { w }
}

/// The autopilot time stamp (s) of a message that has one.
pub fn message_time(message: &MavMessage) -> Option<f64> {
    let ms = match message {
        MavMessage::ATTITUDE(m) => m.time_boot_ms,
        MavMessage::LOCAL_POSITION_NED(m) => m.time_boot_ms,
        MavMessage::SCALED_PRESSURE(m) => m.time_boot_ms,
        MavMessage::SCALED_PRESSURE2(m) => m.time_boot_ms,
        MavMessage::SCALED_PRESSURE3(m) => m.time_boot_ms,
        MavMessage::GLOBAL_POSITION_INT(m) => m.time_boot_ms,
        MavMessage::SYSTEM_TIME(m) => m.time_boot_ms,
        _ => return None,
    };
    Some(f64::from(ms) * 1e-3)
}

impl StateAssembler {
    /// An assembler with `config`; the applied input is not read until
    /// [`StateAssembler::set_thrusters`].
    pub fn new(config: StateConfig) -> Self {
        let reader = MavlinkMeasurements::new(config.surface_pressure_hpa, config.water_density, None);
        Self {
            config,
            reader,
            attitudes: VecDeque::new(),
            local: None,
            depth: None,
            clock: None,
            last_sample: None,
            local_arrival: None,
        }
    }

    /// Reads the thruster outputs (`SERVO_OUTPUT_RAW`) through `thrusters`: each becomes an
    /// [`Observation::Applied`].
    pub fn set_thrusters(&mut self, thrusters: Thrusters) {
        self.reader.set_thrusters(Some(thrusters));
    }

    /// Position fixes from the vehicle's own positioning sensor are stamped `latency` s before
    /// they arrive.
    pub fn set_fix_latency(&mut self, latency: f64) {
        self.reader.set_fix_latency(latency);
    }

    /// The reader of the messages (what it dropped and left out).
    pub fn reader(&self) -> &MavlinkMeasurements {
        &self.reader
    }

    /// Whether the vehicle has an external depth sensor (`SCALED_PRESSURE2` seen).
    pub fn external_pressure(&self) -> bool {
        self.reader.external_pressure()
    }

    /// The settings.
    pub fn config(&self) -> &StateConfig {
        &self.config
    }

    /// The autopilot time (s) at host instant `at`: the newest stamp plus the host time since
    /// it arrived; `None` before any stamped message.
    pub fn autopilot_time(&self, at: Instant) -> Option<f64> {
        self.clock.map(|(t, host)| {
            let dt = if at >= host { (at - host).as_secs_f64() } else { -(host - at).as_secs_f64() };
            (t + dt).max(0.0)
        })
    }

    /// Feeds one message: what it measures (and the input it says was applied) goes to
    /// `observed`, in the message's order. Returns a new state sample when the message is
    /// the state's clock: `LOCAL_POSITION_NED` while positions keep coming (so position and
    /// velocity are those of the sample's own time), `ATTITUDE` otherwise, from one and a half
    /// attitude periods after the last position on (a position source lost mid-run leaves no
    /// gap in the samples).
    pub fn update(&mut self, r: &Received, observed: impl FnMut(Observation)) -> Option<RawState> {
        let sample = self.take(r, observed)?;
        // The autopilot produces ATTITUDE and LOCAL_POSITION_NED at different instants, and a
        // position can carry a stamp older than the newest attitude: when the clock passes from
        // one to the other, a sample older than the last makes none. Samples never go back.
        if self.last_sample.is_some_and(|last| sample.t <= last) {
            return None;
        }
        self.last_sample = Some(sample.t);
        Some(sample)
    }

    fn take(&mut self, r: &Received, mut observed: impl FnMut(Observation)) -> Option<RawState> {
        if let Some(t) = message_time(&r.message) {
            match self.clock {
                Some((newest, _)) if t < newest - REBOOT_STEP => {
                    // The autopilot rebooted: nothing before belongs to the new time base.
                    let mut fresh = Self::new(self.config.clone());
                    fresh.reader = self.reader.clone();
                    fresh.reader.restart();
                    *self = fresh;
                    self.clock = Some((t, r.at));
                }
                Some((newest, _)) if t <= newest => {}
                _ => self.clock = Some((t, r.at)),
            }
        }
        // At most three observations per message (ATTITUDE: heading and yaw rate; a position:
        // position, velocity and, beside a depth sensor, its own depth).
        let mut got = [None; 3];
        let now = self.autopilot_time(r.at).unwrap_or(0.0);
        self.reader.observe(now, &r.message, |o| {
            if let Some(slot) = got.iter_mut().find(|g| g.is_none()) {
                *slot = Some(o);
            }
            observed(o);
        });
        let (mut heading, mut rate, mut position, mut velocity, mut position_depth) = (None, None, None, None, None);
        for o in got.into_iter().flatten() {
            match o {
                Observation::Measured(Measurement::Heading { t, psi }) => heading = Some((t, psi)),
                Observation::Measured(Measurement::YawRate { r, .. }) => rate = Some(r),
                Observation::Measured(Measurement::Position { t, x, y, z }) => position = Some((t, [x, y, z])),
                Observation::Unfused(Measurement::Depth { z, .. }) => position_depth = Some(z),
                Observation::Measured(Measurement::VelocityNed { vn, ve, vd, .. }) => velocity = Some([vn, ve, vd]),
                Observation::Measured(Measurement::Depth { t, z }) => self.depth = Some((t, z)),
                _ => {}
            }
        }
        if let (Some((t, psi)), Some(yaw_rate)) = (heading, rate) {
            let last = self.attitudes.back().copied();
            let yaw = match last {
                Some(a) => a.yaw + wrap(psi - a.yaw),
                None => psi,
            };
            self.attitudes.push_back(Attitude { t, yaw, yaw_rate });
            if self.attitudes.len() > ATTITUDE_HISTORY {
                self.attitudes.pop_front();
            }
            // The attitude's own period: the shortest of its last intervals (a gap is not a
            // period), at most 0.1 s.
            let newer = self.attitudes.iter().rev();
            let older = self.attitudes.iter().rev().skip(1);
            let period = newer.zip(older).take(8).map(|(a, b)| a.t - b.t).fold(0.1, f64::min);
            // Positions arrive in the same bursts as attitudes but stamped up to a period
            // earlier: whether they are still coming is judged by their arrival.
            let since = self.local_arrival.map(|a| r.at.saturating_duration_since(a).as_secs_f64());
            let position_clock = since.is_some_and(|s| s <= 1.5 * period);
            // A sample the attitude makes holds a position only from its own moment (within
            // the same window): an older one would put the vehicle where it was.
            return (!position_clock).then(|| self.estimate_with(t, (1.5 * period).min(self.config.max_age)));
        }
        if let (Some((t, mut position)), Some(velocity_ned)) = (position, velocity) {
            position[2] = position_depth.unwrap_or(position[2]);
            self.local = Some(Local { t, position, velocity_ned });
            self.local_arrival = Some(r.at);
            return Some(self.estimate_at(t));
        }
        None
    }

    /// The attitude nearest to `t` (the newest one on a tie).
    fn attitude_near(&self, t: f64) -> Option<Attitude> {
        self.attitudes.iter().rev().min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs())).copied()
    }

    /// The state now, by the host clock (for a controller's cycle).
    pub fn estimate_now(&self, now: Instant) -> RawState {
        self.estimate_at(self.autopilot_time(now).unwrap_or(0.0))
    }

    /// The state at autopilot time `t` (s) from the newest sample of each part.
    pub fn estimate_at(&self, t: f64) -> RawState {
        self.estimate_with(t, self.config.max_age)
    }

    /// The state at `t`, a position counting as fresh up to `position_max_age` (s).
    fn estimate_with(&self, t: f64, position_max_age: f64) -> RawState {
        let max_age = self.config.max_age;
        let status_within = |part, stamp: Option<f64>, limit: f64| {
            let age = stamp.map(|s| (t - s).max(0.0));
            PartStatus { part, stamp, age, fresh: age.is_some_and(|a| a <= limit) }
        };
        let status = |part, stamp: Option<f64>| status_within(part, stamp, max_age);
        let mut sim = [f64::NAN; NS];
        // The attitude of the estimate's time: the nearest one to `t`, if it is fresh.
        let attitude = self.attitude_near(t);
        let heading = status(Part::Heading, attitude.map(|a| a.t));
        let yaw_rate = status(Part::YawRate, attitude.map(|a| a.t));
        if let (Some(a), true) = (attitude, heading.fresh) {
            sim[3] = a.yaw;
            sim[7] = a.yaw_rate;
        }
        let position = status_within(Part::Position, self.local.map(|l| l.t), position_max_age);
        let mut velocity = status_within(Part::Velocity, self.local.map(|l| l.t), position_max_age);
        if let (Some(l), true) = (self.local, position.fresh) {
            sim[..3].copy_from_slice(&l.position);
            // Body velocities need the heading at the position's own time.
            match self.attitude_near(l.t).filter(|a| (a.t - l.t).abs() <= max_age) {
                Some(a) => {
                    let (s, c) = a.yaw.sin_cos();
                    let [vn, ve, vd] = l.velocity_ned;
                    sim[4] = c * vn + s * ve;
                    sim[5] = -s * vn + c * ve;
                    sim[6] = vd;
                }
                None => velocity.fresh = false,
            }
        }
        let (depth, depth_source) = if position.fresh {
            (status(Part::Depth, position.stamp), Some(DepthSource::Position))
        } else {
            let d = status(Part::Depth, self.depth.map(|(s, _)| s));
            if let (Some((_, z)), true) = (self.depth, d.fresh) {
                sim[2] = z;
            }
            let source = d.fresh.then_some(DepthSource::Pressure);
            (d, source)
        };
        let parts = [heading, yaw_rate, position, velocity, depth];
        let capability = if parts.iter().all(|p| p.fresh) {
            Capability::Full
        } else if heading.fresh && yaw_rate.fresh && depth.fresh {
            Capability::DepthHeading
        } else {
            Capability::None
        };
        RawState { t, sim, parts, depth_source, capability }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::MavHeader;
    use mavlink::dialects::ardupilotmega::{ATTITUDE_DATA, LOCAL_POSITION_NED_DATA, SCALED_PRESSURE2_DATA};

    fn rx(message: MavMessage) -> Received {
        Received { at: Instant::now(), header: MavHeader::default(), message }
    }

    fn attitude(ms: u32, yaw: f32, yawspeed: f32) -> Received {
        rx(MavMessage::ATTITUDE(ATTITUDE_DATA { time_boot_ms: ms, yaw, yawspeed, ..Default::default() }))
    }

    fn local(ms: u32, p: [f32; 3], v: [f32; 3]) -> Received {
        rx(MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: ms,
            x: p[0],
            y: p[1],
            z: p[2],
            vx: v[0],
            vy: v[1],
            vz: v[2],
        }))
    }

    fn pressure(ms: u32, hpa: f32) -> Received {
        rx(MavMessage::SCALED_PRESSURE2(SCALED_PRESSURE2_DATA {
            time_boot_ms: ms,
            press_abs: hpa,
            ..Default::default()
        }))
    }

    #[test]
    fn surge_while_heading_east_is_an_east_velocity_turned_into_u() {
        // Heading 90 deg (east), moving east at 1 m/s and sinking at 0.2 m/s: u = 1, v = 0, w = 0.2.
        let mut e = StateAssembler::default();
        assert!(e.update(&attitude(960, std::f32::consts::FRAC_PI_2, 0.1), |_| {}).is_some());
        let s = e.update(&local(1000, [1.0, 2.0, 3.0], [0.0, 1.0, 0.2]), |_| {}).expect("position is the clock");
        assert_eq!(s.capability, Capability::Full);
        let want = [1.0, 2.0, 3.0, std::f64::consts::FRAC_PI_2, 1.0, 0.0, 0.2, 0.1];
        for (i, (got, want)) in s.sim.iter().zip(want).enumerate() {
            assert!((got - want).abs() < 1e-6, "{}: {got} vs {want}", SIM_STATE_NAMES[i]);
        }
        // Moving north while heading east is a sway to port: v = -1.
        let s = e.update(&local(1080, [1.0, 2.0, 3.0], [1.0, 0.0, 0.0]), |_| {}).unwrap();
        assert!((s.sim[4]).abs() < 1e-6 && (s.sim[5] + 1.0).abs() < 1e-6, "{:?}", s.sim);
        // With positions coming, attitudes do not make samples of their own.
        assert!(e.update(&attitude(1100, std::f32::consts::FRAC_PI_2, 0.0), |_| {}).is_none());
    }

    /// The firmware's interleaving: a position stamped before the last attitude sample (the
    /// clock passing from ATTITUDE to LOCAL_POSITION_NED) makes no sample, and the samples'
    /// times only ever grow.
    #[test]
    fn samples_never_go_back_in_time_when_the_clock_changes_message() {
        // Each message arrives at its host time (ms after `t0`) in bursts 80 ms apart, the
        // position stamped 68 ms before the attitude of its burst, as the firmware sends them.
        let t0 = Instant::now();
        let at = |r: Received, ms: u64| Received { at: t0 + std::time::Duration::from_millis(ms), ..r };
        let mut e = StateAssembler::default();
        let mut times = Vec::new();
        let mut feed = |e: &mut StateAssembler, r: Received| {
            times.extend(e.update(&r, |_| {}).map(|s| (s.t * 1e3).round() as i64));
            times.clone()
        };
        feed(&mut e, at(attitude(41_080, 0.0, 0.0), 0));
        feed(&mut e, at(attitude(41_160, 0.0, 0.0), 80));
        // The first position, older than the newest attitude: kept, no sample.
        let so_far = feed(&mut e, at(local(41_092, [0.0; 3], [0.0; 3]), 81));
        assert_eq!(so_far, [41_080, 41_160]);
        // Positions keep coming: they are the clock, attitudes make no samples.
        for k in 1..=3u32 {
            feed(&mut e, at(attitude(41_160 + 80 * k, 0.0, 0.0), 80 + 80 * u64::from(k)));
            feed(&mut e, at(local(41_092 + 80 * k, [0.0; 3], [0.0; 3]), 81 + 80 * u64::from(k)));
        }
        let so_far = feed(&mut e, at(attitude(41_480, 0.0, 0.0), 400));
        assert_eq!(so_far, [41_080, 41_160, 41_172, 41_252, 41_332]);
        assert_eq!(e.estimate_at(41.332).capability, Capability::Full);
        // The position source stops (its last arrived at 321 ms): from 1.5 attitude periods on,
        // the attitude is the clock again: 159 ms of host time without a sample, 228 ms between
        // the stamps (the position's lag included), then one every 80 ms.
        for k in 1..=10u32 {
            feed(&mut e, at(attitude(41_480 + 80 * k, 0.0, 0.0), 400 + 80 * u64::from(k)));
        }
        let all = feed(&mut e, at(attitude(42_400, 0.0, 0.0), 1320));
        assert_eq!(all[5], 41_560, "{all:?}");
        assert!(all.windows(2).all(|w| w[1] > w[0] && w[1] - w[0] <= 240), "{all:?}");
        assert!(all[5..].windows(2).all(|w| w[1] - w[0] <= 120), "{all:?}");
        assert!(!e.estimate_at(42.4).part(Part::Position).fresh);
    }

    #[test]
    fn heading_is_unwrapped_across_pi() {
        let mut e = StateAssembler::default();
        e.update(&attitude(0, 3.1, 0.0), |_| {});
        let s = e.update(&attitude(40, -3.1, 0.0), |_| {}).unwrap();
        assert!((s.sim[3] - (3.1 + (std::f64::consts::TAU - 6.2))).abs() < 1e-5, "{}", s.sim[3]);
    }

    #[test]
    fn without_a_position_depth_comes_from_pressure_and_velocities_are_missing() {
        let mut e = StateAssembler::default();
        // 2 m of fresh water: 2 * 1000 * 9.80665 Pa = 196.133 hPa above the surface.
        e.update(&pressure(900, 1013.25 + 196.133), |_| {});
        let s = e.update(&attitude(1000, 0.5, 0.0), |_| {}).unwrap();
        assert_eq!(s.capability, Capability::DepthHeading);
        assert_eq!(s.depth_source, Some(DepthSource::Pressure));
        assert!((s.sim[2] - 2.0).abs() < 1e-4, "{}", s.sim[2]);
        for i in [0, 1, 4, 5, 6] {
            assert!(s.sim[i].is_nan(), "{} should be missing", SIM_STATE_NAMES[i]);
        }
        assert!(!s.part(Part::Velocity).fresh && s.part(Part::Velocity).stamp.is_none());
    }

    #[test]
    fn stale_parts_are_missing_not_held() {
        let mut e = StateAssembler::default();
        e.update(&attitude(1000, 0.0, 0.0), |_| {});
        e.update(&local(1000, [1.0, 1.0, 1.0], [0.0; 3]), |_| {});
        // 0.6 s later only attitudes arrive: the position is stale and the attitude is the clock.
        let later = Received { at: Instant::now() + std::time::Duration::from_millis(600), ..attitude(1600, 0.0, 0.0) };
        let s = e.update(&later, |_| {}).expect("attitude is the clock again");
        let p = s.part(Part::Position);
        assert!(!p.fresh && (p.age.unwrap() - 0.6).abs() < 1e-9, "{p:?}");
        assert!(s.sim[0].is_nan() && s.sim[2].is_nan() && s.sim[4].is_nan());
        assert_eq!(s.capability, Capability::None);
        // And a frozen attitude is stale too, when asked later.
        let later = e.estimate_at(2.2);
        assert!(later.sim[3].is_nan() && !later.part(Part::Heading).fresh);
    }

    #[test]
    fn a_reboot_clears_the_state() {
        let mut e = StateAssembler::default();
        e.update(&attitude(60_000, 1.0, 0.0), |_| {});
        e.update(&local(60_000, [5.0; 3], [0.0; 3]), |_| {});
        let mut after = Vec::new();
        let s = e.update(&attitude(100, 0.2, 0.0), |o| after.push(o)).unwrap();
        assert!(s.part(Part::Position).stamp.is_none());
        assert!((s.sim[3] - 0.2).abs() < 1e-6);
        // The reader starts its time line over too: the new stamps are measurements, not late.
        assert_eq!(
            after,
            [
                Observation::Measured(Measurement::Heading { t: 0.1, psi: f64::from(0.2f32) }),
                Observation::Measured(Measurement::YawRate { t: 0.1, r: 0.0 }),
            ]
        );
    }

    /// One reading of each message: the observations handed on are the estimator's (the
    /// position's own depth left out beside a depth sensor), and the state keeps the
    /// position's depth, of the position's own time.
    #[test]
    fn each_message_is_read_once_for_the_state_and_the_estimator() {
        let mut e = StateAssembler::default();
        let mut seen = Vec::new();
        e.update(&pressure(980, 1013.25 + 196.133), |o| seen.push(o));
        e.update(&attitude(990, 0.0, 0.0), |o| seen.push(o));
        let s = e.update(&local(1000, [1.0, 2.0, 2.5], [0.0; 3]), |o| seen.push(o)).unwrap();
        assert_eq!(s.capability, Capability::Full);
        assert_eq!(s.depth_source, Some(DepthSource::Position));
        assert!(s.sim[2] == 2.5 && s.sim[0] == 1.0, "{:?}", s.sim);
        assert!(matches!(seen[3], Observation::Measured(Measurement::Position { z, .. }) if z.is_nan()));
        let mut reader = MavlinkMeasurements::new(1013.25, 1000.0, None);
        let mut direct = Vec::new();
        for r in [pressure(980, 1013.25 + 196.133), attitude(990, 0.0, 0.0), local(1000, [1.0, 2.0, 2.5], [0.0; 3])] {
            reader.observe(0.0, &r.message, |o| direct.push(o));
        }
        // NaN (the position's depth left out) compares unequal: compare the debug text.
        assert_eq!(format!("{seen:?}"), format!("{direct:?}"));
        assert!(e.external_pressure());
    }
}
