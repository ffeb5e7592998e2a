//! Pilot assist: the sticks as velocity references for the MPC, and the stop it plans when
//! they are let go (docs/MODEL.md section 14).
//!
//! Each axis group (the horizontal position, the depth, the heading) is in one of three
//! phases. Moving: the reference runs ahead of where the vehicle is at the stick's speed, so
//! the MPC tracks the speed over the ground whatever the current. Stopping (the stick let go):
//! the reference is where the vehicle was a moment ago at its speed now, every cycle, so the
//! MPC brakes hard and never plans to come back further than that. Holding: the position once
//! half its speed is gone, at where it will come to rest; depth and heading once they no longer
//! move the way they went, at the farthest point reached.

use super::sticks::{StickError, StickLimits, Sticks};
use crate::mpc::{Horizontal, Reference};
use crate::types::State;
use serde::Serialize;
use std::collections::VecDeque;

/// No reading for this long counts as centred sticks (s).
pub const DEADMAN_S: f64 = 0.5;
/// A stick within this of the centre is centred.
pub const DEADBAND: f64 = 0.05;
/// A released position or depth is at rest when its speed the way it went falls under this
/// (m/s).
const REST_SPEED: f64 = 0.02;
/// A released heading is at rest when its rate the way it turned falls under this (rad/s): 1
/// deg/s.
const REST_RATE: f64 = 0.017_453_292_519_943_295;
/// While stopping, the reference lies this long of the speed behind the vehicle (s): the MPC
/// brakes harder than for a reference where it is (on the simulated vehicle in a 0.3 m/s current,
/// 0.3 s took the travel past the release point from 0.122 to 0.079 m at 0.5 m/s and from 0.104 to
/// 0.072-0.077 m at 0.3 m/s sway). The speed is the vehicle's now ([`Axis::speed_now`]), and the
/// hold is latched before the vehicle stops ([`LATCH_SHARE`]), so the lead is gone by then.
const BRAKE_LEAD_S: f64 = 0.3;
/// A released position is latched once its speed is down to this share of the speed at the
/// release, where it will come to rest ([`LATCH_AHEAD_S`]): braking behind it to the end swung
/// the vehicle back on the firmware (0.067 m within 2 s at up to 0.17 m/s after a 0.9 m/s push).
const LATCH_SHARE: f64 = 0.5;
/// At most this long of its speed ahead of the farthest point reached (s).
const LATCH_AHEAD_S: f64 = 0.4;
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
    /// Where the reference is: behind the vehicle while stopping, the rest point holding.
    hold: [f64; N],
    /// The commanded velocity when last moving: the way it went.
    way: [f64; N],
    /// When the stick was let go (s).
    released: f64,
    /// While stopping: the speed the way it went at the last cycle and when (the window's), and
    /// the farthest point reached the way it went (where it is held).
    last_speed: Option<(f64, f64)>,
    release_speed: f64,
    farthest: [f64; N],
}

impl<const N: usize> Axis<N> {
    fn holding(here: [f64; N]) -> Self {
        Self {
            phase: Phase::Holding,
            hold: here,
            way: [0.0; N],
            released: f64::NEG_INFINITY,
            last_speed: None,
            release_speed: 0.0,
            farthest: here,
        }
    }

    /// The unit vector of the way the axis went.
    fn direction(&self) -> [f64; N] {
        let norm = self.way.iter().map(|w| w * w).sum::<f64>().sqrt().max(1e-12);
        self.way.map(|w| w / norm)
    }

    /// The speed the way it went now, from `windowed` (the positions' change over
    /// [`VELOCITY_WINDOW_S`], which is the speed of half a window ago) moved on by the rate it
    /// changed since the last cycle: braking, the windowed speed lags the vehicle's by a tenth of
    /// a second, and a reference behind a vehicle already at rest swung it back (0.10-0.11 m at
    /// up to 0.39 m/s after a 0.9 m/s push on the firmware).
    fn speed_now(&self, t: f64, windowed: f64) -> f64 {
        match self.last_speed {
            Some((t0, s0)) if t > t0 => (windowed + (windowed - s0) / (t - t0) * 0.5 * VELOCITY_WINDOW_S).max(0.0),
            _ => windowed.max(0.0),
        }
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
        let d = self.direction();
        let ahead = |p: &[f64; N]| d.iter().zip(p).map(|(d, p)| d * p).sum::<f64>();
        let windowed = ahead(&velocity);
        match (self.phase, commanded) {
            (_, Some(c)) => {
                (self.phase, self.way, self.hold) = (Phase::Moving, c, here);
            }
            (Phase::Moving, None) => {
                (self.phase, self.released, self.farthest) = (Phase::Stopping, t, here);
                let now = self.speed_now(t, windowed);
                self.release_speed = now;
                self.hold = std::array::from_fn(|i| here[i] - stop.lead * now * d[i]);
                self.last_speed = Some((t, windowed));
            }
            (Phase::Stopping, None) => {
                if ahead(&here) > ahead(&self.farthest) {
                    self.farthest = here;
                }
                let decel = match self.last_speed {
                    Some((t0, s0)) if t > t0 => (s0 - windowed) / (t - t0),
                    _ => 0.0,
                };
                let now = self.speed_now(t, windowed);
                self.last_speed = Some((t, windowed));
                // Braking behind the vehicle is for the first part of the stop: once half the
                // speed is gone, the hold is latched where the vehicle will come to rest at the
                // deceleration it has (at most LATCH_AHEAD_S of its speed ahead), and the MPC
                // eases onto a point it has not passed.
                let latch = stop.lead > 0.0 && decel > 0.0 && now <= LATCH_SHARE * self.release_speed;
                if now <= stop.rest || latch || t - self.released >= STOP_TIMEOUT_S {
                    let rest = if now > stop.rest && decel > 0.0 {
                        (now * now / (2.0 * decel)).min(now * LATCH_AHEAD_S)
                    } else {
                        0.0
                    };
                    let hold = std::array::from_fn(|i| self.farthest[i] + rest * d[i]);
                    (self.phase, self.hold) = (Phase::Holding, hold);
                } else {
                    // Where the vehicle would have been `lead` ago at its speed now: the MPC
                    // brakes harder than for where it is, and less as the speed goes.
                    self.hold = std::array::from_fn(|i| here[i] - stop.lead * now * d[i]);
                }
            }
            (Phase::Holding, None) => {}
        }
        (self.phase != before).then_some(self.phase)
    }
}

/// How an axis group stops: at rest under `rest` (m/s or rad/s) the way it went, the
/// reference `lead` (s) of its speed behind it meanwhile.
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

    /// A reading taken at `t` (s, the session's time): checked, it replaces the last. Readings
    /// closer together than a cycle (a browser's gamepad polled twice under load, a burst passed
    /// on at once) merge: the newest is in force at the next cycle, and none of them centres the
    /// sticks. A refused one (an axis not finite or out of range) centres the sticks (the
    /// vehicle holds) until the next good one.
    ///
    /// # Errors
    /// The reading is refused: an axis not finite or out of range.
    pub fn take(&mut self, t: f64, reading: Result<Sticks, StickError>) -> Result<(), StickError> {
        match reading.and_then(|s| Sticks::new(s.axes())) {
            Ok(s) => {
                // A reading that arrived out of order (older than the newest taken) is left out.
                if self.last_reading.is_none_or(|last| t >= last) {
                    (self.sticks, self.last_reading) = (s, Some(t));
                }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A 0.9 m/s push whose readings come in bursts (pairs 1 ms apart every 40 ms, as a browser
    /// polling its gamepad under load passes them on) stays a push: the assist never stops it
    /// mid-push, and the release afterwards stops it at once.
    #[test]
    fn sticks_in_bursts_never_brake_a_push() {
        let limits = StickLimits { surge: 1.0, sway: 0.5, heave: 0.4, yaw_rate: 0.5 };
        let mut assist = PilotAssist::new(limits, (0.0, 10.0));
        let push = Sticks { surge: 0.9, ..Sticks::CENTRED };
        let (dt, mut refs) = (0.08, vec![Reference::depth_heading(0.0, 0.0); 10]);
        let mut next_burst = 0.0;
        for k in 0..150 {
            let t = k as f64 * dt;
            while next_burst <= t {
                let stick = if next_burst < 10.0 { push } else { Sticks::CENTRED };
                assist.take(next_burst, Ok(stick)).unwrap();
                assist.take(next_burst + 0.001, Ok(stick)).unwrap();
                next_burst += 0.04;
            }
            // The vehicle going north at the stick's speed until 10 s, then braking.
            let north = 0.9 * t.min(10.0);
            let x = State::from([north, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            assist.references(t, &x, true, dt, &mut refs);
        }
        let horizontal: Vec<_> = assist.changes().iter().filter(|c| c.axis == "horizontal").collect();
        assert_eq!(horizontal[0].phase, Phase::Moving, "{horizontal:?}");
        assert!(horizontal[0].t < 0.1, "{horizontal:?}");
        assert_eq!(horizontal[1].phase, Phase::Stopping, "{horizontal:?}");
        assert!((10.0..10.1).contains(&horizontal[1].t), "stopped mid-push: {horizontal:?}");
        assert_eq!(assist.refused(), 0);
        // A bad value is still refused, and holds.
        assert!(assist.take(12.0, Sticks::new([f64::NAN, 0.0, 0.0, 0.0])).is_err());
        assert_eq!(assist.commanded(12.0), Sticks::CENTRED);
    }
}
