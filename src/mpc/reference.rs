//! What the controller tracks.

/// The reference of one sample: depth (m, down) and heading (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reference {
    /// Depth `z_ref`.
    pub depth: f64,
    /// Heading `psi_ref`.
    pub heading: f64,
}
