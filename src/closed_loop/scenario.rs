//! The tracking scenarios: references over time and the plant each runs against.

use crate::mpc::Reference;
use crate::types::{Input, SimState};
use crate::vehicle::{Rk4Vehicle, VehicleParams};
use serde::Serialize;

/// A closed-loop scenario: references over time and the plant they run against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Scenario {
    /// 60 s from rest at the surface; depth 0 -> 1 m (2 s) -> 2 m (20 s) -> 0.5 m (40 s);
    /// heading 0 -> 45 deg (10 s) -> -30 deg (30 s) -> 0 (50 s). The plant is the nominal vehicle.
    Default,
    /// The same references; the plant's damping is 20 % higher and a 0.1 m/s current flows
    /// along the world x axis.
    Disturbed,
}

/// Depth reference steps `(time s, depth m)`.
pub(super) const DEPTH_STEPS: [(f64, f64); 4] = [(0.0, 0.0), (2.0, 1.0), (20.0, 2.0), (40.0, 0.5)];
/// Heading reference steps `(time s, heading deg)`.
pub(super) const HEADING_STEPS: [(f64, f64); 4] = [(0.0, 0.0), (10.0, 45.0), (30.0, -30.0), (50.0, 0.0)];

fn piecewise(steps: &[(f64, f64)], t: f64) -> f64 {
    steps.iter().rev().find(|(t0, _)| t >= *t0 - 1e-9).map_or(steps[0].1, |s| s.1)
}

impl Scenario {
    /// The name used on the command line and in logs.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Default => "default",
            Scenario::Disturbed => "disturbed",
        }
    }

    /// Length of the run (s).
    pub fn duration(self) -> f64 {
        60.0
    }

    /// The reference at time `t`.
    pub fn reference(self, t: f64) -> Reference {
        Reference { depth: piecewise(&DEPTH_STEPS, t), heading: piecewise(&HEADING_STEPS, t).to_radians() }
    }

    /// The plant of this scenario for `vehicle`, sampled at `dt`.
    pub fn plant(self, dt: f64, vehicle: &VehicleParams) -> Plant {
        let mut vehicle = Rk4Vehicle { params: *vehicle, ..Rk4Vehicle::with_dt(dt) };
        match self {
            Scenario::Default => Plant { vehicle, current: [0.0, 0.0] },
            Scenario::Disturbed => {
                vehicle.params = vehicle.params.with_damping_scaled(1.2);
                Plant { vehicle, current: [0.1, 0.0] }
            }
        }
    }
}

/// The simulated vehicle: body velocities are relative to the water, which moves with a
/// constant world-frame `current`; with no position dependence in the dynamics that adds
/// exactly `current * dt` to the position each sample.
#[derive(Debug, Clone)]
pub struct Plant {
    /// The vehicle and its integrator.
    pub vehicle: Rk4Vehicle,
    /// Water velocity in the world frame `(x, y)` (m/s).
    pub current: [f64; 2],
}

impl Plant {
    /// One sample period under the held input `u`.
    pub fn step(&self, s: &SimState, u: &Input) -> SimState {
        let mut next = self.vehicle.step_sim(s, u);
        next[0] += self.current[0] * self.vehicle.dt;
        next[1] += self.current[1] * self.vehicle.dt;
        next
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn references_follow_the_scenario_schedule() {
        let s = Scenario::Default;
        assert_eq!(s.reference(1.99).depth, 0.0);
        assert_eq!(s.reference(2.0).depth, 1.0);
        assert_eq!(s.reference(45.0).depth, 0.5);
        assert!((s.reference(10.0).heading - 45f64.to_radians()).abs() < 1e-12);
        assert!((s.reference(35.0).heading + 30f64.to_radians()).abs() < 1e-12);
        assert_eq!(s.reference(59.0).heading, 0.0);
    }

    #[test]
    fn the_current_moves_the_disturbed_plant_exactly_by_current_times_dt() {
        let (nominal, disturbed) = {
            let v = VehicleParams::default();
            (Scenario::Default.plant(0.08, &v), Scenario::Disturbed.plant(0.08, &v))
        };
        let s = SimState::from([0.0, 0.0, 1.0, 0.3, 0.0, 0.0, 0.0, 0.0]);
        let u = Input::zeros();
        let a = nominal.step(&s, &u);
        let b = disturbed.step(&s, &u);
        // At rest the damping does not act, so only the drift differs.
        assert!((b[0] - a[0] - 0.008).abs() < 1e-12 && (b[1] - a[1]).abs() < 1e-12);
    }
}
