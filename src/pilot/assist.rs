//! Pilot assist: the sticks as velocity references for the MPC, and the stop it plans when
//! they are let go (docs/MODEL.md section 14).
//!
//! Each axis group (the horizontal position, the depth, the heading) is in one of three
//! phases. Moving: the reference runs ahead of where the vehicle is at the stick's speed, so
//! the MPC tracks the speed over the ground whatever the current. Stopping (the stick let go):
//! the reference is where the vehicle was a moment ago at its present speed, every cycle, so
//! the MPC brakes hard and never plans to come back further than that. Holding: once the
//! vehicle no longer moves the way it went, the reference stays at the farthest point it
//! reached.

use super::sticks::{StickError, StickLimits, Sticks};
use crate::mpc::{Horizontal, Reference};
use crate::types::State;
use serde::Serialize;
use std::collections::VecDeque;

/// No reading for this long counts as centred sticks (s).
pub const DEADMAN_S: f64 = 0.5;
/// A stick within this of the centre is centred.
pub const DEADBAND: f64 = 0.05;
/// The shortest interval between two readings taken (s): 200 a second; a gamepad sends 60 at
/// most.
pub const MIN_INTERVAL_S: f64 = 0.005;
/// A released position or depth is at rest when its speed the way it went falls under this
/// (m/s).
const REST_SPEED: f64 = 0.02;
/// A released heading is at rest when its rate the way it turned falls under this (rad/s): 1
/// deg/s.
const REST_RATE: f64 = 0.017_453_292_519_943_295;
/// While stopping, the reference lies this long of the speed behind the vehicle (s): on the
/// simulated vehicle in a 0.3 m/s current, 0.3 s took the travel past the release point from
/// 0.122 to 0.089 m at 0.5 m/s and from 0.104 to 0.077 m at 0.3 m/s sway, the way back from 0.002
/// to 0.006-0.019 m (0.6 s: 0.075 m past, 0.012-0.020 m back; 1 s: 0.031 m back).
const BRAKE_LEAD_S: f64 = 0.3;
/// A released axis is held where it is after this long, at rest or not (s).
pub const STOP_TIMEOUT_S: f64 = 5.0;
/// The ground velocity is the estimate's positions' change over this window (s).
const VELOCITY_WINDOW_S: f64 = 0.24;

/// Where an axis group is between the pilot's stick and its hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// The stick is out: the reference runs ahead at its speed.
    Moving,
    /// Let go: braking, the reference where the vehicle is.
    Stopping,
    /// At rest (or never moved): the reference where it came to rest.
    Holding,
}

/// One axis group's phase and the point it refers to: north and east (m), depth (m) or the
/// heading (rad, unwrapped).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Axis<const N: usize> {
    phase: Phase,
    /// Where the reference is: the vehicle's place while stopping, the rest point holding.
    hold: [f64; N],
    /// The commanded velocity when last moving: the way it went.
    way: [f64; N],
    /// When the stick was let go (s).
    released: f64,
    /// While stopping, the farthest point reached the way it went: where it is held.
    farthest: [f64; N],
}

impl<const N: usize> Axis<N> {
    fn holding(here: [f64; N]) -> Self {
        Self { phase: Phase::Holding, hold: here, way: [0.0; N], released: f64::NEG_INFINITY, farthest: here }
    }

    /// The unit vector of the way the axis went.
    fn direction(&self) -> [f64; N] {
        let norm = self.way.iter().map(|w| w * w).sum::<f64>().sqrt().max(1e-12);
        self.way.map(|w| w / norm)
    }

    /// The phase after this cycle; `Some` with the new phase when it changed.
    fn advance(
        &mut self,
        t: f64,
        commanded: Option<[f64; N]>,
        here: [f64; N],
        velocity: [f64; N],
        stop: Stop,
    ) -> Option<Phase> {
        let before = self.phase;
        match (self.phase, commanded) {
            (_, Some(c)) => {
                (self.phase, self.way, self.hold) = (Phase::Moving, c, here);
            }
            (Phase::Moving, None) => {
                (self.phase, self.released, self.hold, self.farthest) = (Phase::Stopping, t, here, here);
            }
            (Phase::Stopping, None) => {
                let d = self.direction();
                let ahead = |p: &[f64; N]| d.iter().zip(p).map(|(d, p)| d * p).sum::<f64>();
                if ahead(&here) > ahead(&self.farthest) {
                    self.farthest = here;
                }
                let along: f64 = d.iter().zip(velocity).map(|(d, v)| d * v).sum();
                if along <= stop.rest || t - self.released >= STOP_TIMEOUT_S {
                    // At rest where it went farthest: the speed is seen over a window, so the
                    // vehicle may already have eased back from there; held there, it does not
                    // come back.
                    (self.phase, self.hold) = (Phase::Holding, self.farthest);
                } else {
                    // Where the vehicle would have been `lead` ago at this speed: the MPC brakes
                    // harder than for where it is, and the hold is taken at rest.
                    self.hold = std::array::from_fn(|i| here[i] - stop.lead * along * d[i]);
                }
            }
            (Phase::Holding, None) => {}
        }
        (self.phase != before).then_some(self.phase)
    }
}

/// How an axis group stops: at rest under `rest` (m/s or rad/s) the way it went, the
/// reference `lead` s of its speed behind it until then.
#[derive(Debug, Clone, Copy)]
struct Stop {
    rest: f64,
    lead: f64,
}

/// The horizontal position brakes on a reference behind it; depth and heading, whose
/// controllers hold against buoyancy and a yaw moment, stop on one where they are (on the
/// firmware a lead there swung the heading back 1 deg after a 15 deg/s turn).
const HORIZONTAL_STOP: Stop = Stop { rest: REST_SPEED, lead: BRAKE_LEAD_S };
const DEPTH_STOP: Stop = Stop { rest: REST_SPEED, lead: 0.0 };
const HEADING_STOP: Stop = Stop { rest: REST_RATE, lead: 0.0 };

/// A change of phase, for the log and the terminal.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PhaseChange {
    /// When (s, the session's time).
    pub t: f64,
    /// `horizontal`, `depth` or `heading`.
    pub axis: &'static str,
    /// The new phase.
    pub phase: Phase,
    /// The reference there: north and east (m), the depth (m, the second 0) or the heading
    /// (deg, the second 0).
    pub at: [f64; 2],
}

/// The three axis groups' phases.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Phases {
    /// The horizontal position (`None`: no position to hold).
    pub horizontal: Option<Phase>,
    /// The depth.
    pub depth: Phase,
    /// The heading.
    pub heading: Phase,
}

/// The pilot's sticks turned into the MPC's references, cycle by cycle.
#[derive(Debug, Clone)]
pub struct PilotAssist {
    limits: StickLimits,
    /// The depths the reference stays within (m).
    depth_band: (f64, f64),
    sticks: Sticks,
    /// When the last reading was taken (s).
    last_reading: Option<f64>,
    horizontal: Option<Axis<2>>,
    depth: Option<Axis<1>>,
    heading: Option<Axis<1>>,
    /// `(t, [north, east, depth, unwrapped heading])` over the last velocity window.
    history: VecDeque<(f64, [f64; 4])>,
    changes: Vec<PhaseChange>,
    refused: usize,
}

impl PilotAssist {
    /// Full deflection asks for `limits`; the depth reference stays within `depth_band`
    /// `(shallowest, deepest)` m.
    pub fn new(limits: StickLimits, depth_band: (f64, f64)) -> Self {
        Self {
            limits,
            depth_band,
            sticks: Sticks::CENTRED,
            last_reading: None,
            horizontal: None,
            depth: None,
            heading: None,
            history: VecDeque::new(),
            changes: Vec::new(),
            refused: 0,
        }
    }

    /// What full deflection asks for.
    pub fn limits(&self) -> StickLimits {
        self.limits
    }

    /// A reading taken at `t` (s, the session's time): checked, it replaces the last. A
    /// refused one centres the sticks (the vehicle holds) until the next good one.
    ///
    /// # Errors
    /// The reading is refused: an axis not finite or out of range, or sooner than
    /// [`MIN_INTERVAL_S`] after the last one taken.
    pub fn take(&mut self, t: f64, reading: Result<Sticks, StickError>) -> Result<(), StickError> {
        let checked = reading.and_then(|s| Sticks::new(s.axes())).and_then(|s| match self.last_reading {
            Some(last) if t - last < MIN_INTERVAL_S => {
                Err(StickError::TooFast { interval_ms: (t - last) * 1e3, min_ms: MIN_INTERVAL_S * 1e3 })
            }
            _ => Ok(s),
        });
        match checked {
            Ok(s) => {
                (self.sticks, self.last_reading) = (s, Some(t));
                Ok(())
            }
            Err(e) => {
                self.sticks = Sticks::CENTRED;
                self.refused += 1;
                Err(e)
            }
        }
    }

    /// The sticks in force at `t`: the last reading, or centred once it is older than
    /// [`DEADMAN_S`].
    pub fn commanded(&self, t: f64) -> Sticks {
        match self.last_reading {
            Some(last) if t - last <= DEADMAN_S => self.sticks,
            _ => Sticks::CENTRED,
        }
    }

    /// Readings refused so far.
    pub fn refused(&self) -> usize {
        self.refused
    }

    /// Every change of phase so far.
    pub fn changes(&self) -> &[PhaseChange] {
        &self.changes
    }

    /// The phases now (before the first cycle: all holding).
    pub fn phases(&self) -> Phases {
        Phases {
            horizontal: self.horizontal.map(|a| a.phase),
            depth: self.depth.map_or(Phase::Holding, |a| a.phase),
            heading: self.heading.map_or(Phase::Holding, |a| a.phase),
        }
    }

    /// The references `refs[k]` for the predicted samples `k + 1` (`dt` apart) from the state
    /// estimate `x` at `t`; `position`: whether the horizontal position is known (without it
    /// the horizontal is left free and the depth and heading are still held). The first call
    /// holds where the vehicle is. Returns the reference at `t` itself.
    pub fn references(&mut self, t: f64, x: &State, position: bool, dt: f64, refs: &mut [Reference]) -> Reference {
        let norm = x[3].hypot(x[4]).max(1e-12);
        let (c, s) = (x[3] / norm, x[4] / norm);
        let psi = self.unwrapped(s.atan2(c));
        self.remember(t, [x[0], x[1], x[2], psi]);
        let [vn_now, ve_now, vz_now, rate_now] = self.ground_velocity();
        let sticks = self.commanded(t);
        let out = |a: f64| a.abs() > DEADBAND;
        let (u, v) = (sticks.surge * self.limits.surge, sticks.sway * self.limits.sway);
        let (vn, ve) = (c * u - s * v, s * u + c * v);
        let (w, r) = (sticks.heave * self.limits.heave, sticks.yaw * self.limits.yaw_rate);
        let band = self.depth_band;
        let here_depth = x[2].clamp(band.0, band.1);

        if position {
            let a = self.horizontal.get_or_insert_with(|| Axis::holding([x[0], x[1]]));
            let moving = (out(sticks.surge) || out(sticks.sway)).then_some([vn, ve]);
            if let Some(p) = a.advance(t, moving, [x[0], x[1]], [vn_now, ve_now], HORIZONTAL_STOP) {
                self.changes.push(PhaseChange { t, axis: "horizontal", phase: p, at: a.hold });
            }
        } else {
            self.horizontal = None;
        }
        let d = self.depth.get_or_insert_with(|| Axis::holding([here_depth]));
        if let Some(p) = d.advance(t, out(sticks.heave).then_some([w]), [here_depth], [vz_now], DEPTH_STOP) {
            self.changes.push(PhaseChange { t, axis: "depth", phase: p, at: [d.hold[0], 0.0] });
        }
        let h = self.heading.get_or_insert_with(|| Axis::holding([psi]));
        if let Some(p) = h.advance(t, out(sticks.yaw).then_some([r]), [psi], [rate_now], HEADING_STOP) {
            self.changes.push(PhaseChange { t, axis: "heading", phase: p, at: [h.hold[0].to_degrees(), 0.0] });
        }

        let (horizontal, depth, heading) = (self.horizontal, *d, *h);
        let at = |ahead: f64| Reference {
            depth: match depth.phase {
                Phase::Moving => (x[2] + w * ahead).clamp(band.0, band.1),
                _ => depth.hold[0],
            },
            heading: match heading.phase {
                Phase::Moving => psi + r * ahead,
                _ => heading.hold[0],
            },
            horizontal: horizontal.map(|a| match a.phase {
                Phase::Moving => Horizontal { north: x[0] + vn * ahead, east: x[1] + ve * ahead, velocity: [vn, ve] },
                _ => Horizontal::hold(a.hold[0], a.hold[1]),
            }),
        };
        for (k, reference) in refs.iter_mut().enumerate() {
            *reference = at((k + 1) as f64 * dt);
        }
        at(0.0)
    }

    /// `psi` (rad) continued from the last heading remembered, without jumps of a turn.
    fn unwrapped(&self, psi: f64) -> f64 {
        match self.history.back() {
            Some((_, [.., last])) => {
                let d = (psi - last).sin().atan2((psi - last).cos());
                last + d
            }
            None => psi,
        }
    }

    fn remember(&mut self, t: f64, p: [f64; 4]) {
        self.history.push_back((t, p));
        while self.history.front().is_some_and(|(t0, _)| t - t0 > VELOCITY_WINDOW_S + 1e-9) {
            self.history.pop_front();
        }
    }

    /// North, east and down velocities (m/s) and the heading's rate (rad/s) over the window.
    fn ground_velocity(&self) -> [f64; 4] {
        match (self.history.front(), self.history.back()) {
            (Some((t0, a)), Some((t1, b))) if t1 - t0 > 1e-9 => std::array::from_fn(|i| (b[i] - a[i]) / (t1 - t0)),
            _ => [0.0; 4],
        }
    }
}
