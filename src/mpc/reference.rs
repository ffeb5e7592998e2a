//! What the controller tracks.

/// The reference of one sample: depth (m, down), heading (rad) and, where the vehicle knows
/// where it is, a horizontal position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reference {
    /// Depth `z_ref`.
    pub depth: f64,
    /// Heading `psi_ref`.
    pub heading: f64,
    /// The horizontal goal, if any: a controller built with a position weight
    /// ([`MpcConfig::position`](super::MpcConfig::position)) tracks it; without one (or with
    /// `None`) the horizontal position is left free.
    pub horizontal: Option<Horizontal>,
}

impl Reference {
    /// Depth and heading only.
    pub fn depth_heading(depth: f64, heading: f64) -> Self {
        Self { depth, heading, horizontal: None }
    }
}

/// A horizontal goal in the world frame (NED: north `x`, east `y`, m) with the path's
/// velocity there (m/s, world frame) as feed-forward: zero for a point to hold.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Horizontal {
    /// North (m).
    pub north: f64,
    /// East (m).
    pub east: f64,
    /// The path's velocity `(north, east)` (m/s).
    pub velocity: [f64; 2],
}

impl Horizontal {
    /// A point to hold.
    pub fn hold(north: f64, east: f64) -> Self {
        Self { north, east, velocity: [0.0, 0.0] }
    }

    /// The feed-forward velocity in the body frame of a vehicle at heading `(cos, sin)`:
    /// surge and sway `(u, v)`.
    pub fn body_velocity(&self, cos: f64, sin: f64) -> (f64, f64) {
        let [vn, ve] = self.velocity;
        (cos * vn + sin * ve, -sin * vn + cos * ve)
    }
}
