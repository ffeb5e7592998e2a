//! Where the horizontal estimate stands, for the controller that steers on it: measured (a
//! position or a velocity fused lately), dead reckoned (nothing horizontal measured since, the
//! model moving the estimate under the applied thrust and the current estimated before, its
//! added uncertainty still under a bound) or lost.
//!
//! The dead reckoning's uncertainty is what the filter added to the horizontal position since
//! the last horizontal measurement: `sqrt(s_now^2 - s_then^2)`, `s` the larger standard
//! deviation of the position's 2x2 covariance. The total would also count how well the
//! position was known before, which on a DVL alone (no absolute fix) grows with the dive and
//! says nothing of the gap.

use serde::Serialize;

/// The dead reckoning's added horizontal uncertainty (m, one standard deviation) past which
/// the horizontal estimate counts as lost, unless set.
pub const DEFAULT_DEAD_RECKONING_BOUND_M: f64 = 10.0;

/// The standing of the horizontal estimate at one time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "mode", rename_all = "snake_case")]
pub enum Navigation {
    /// A position or velocity was fused within [`super::HORIZONTAL_FRESH_S`].
    Measured,
    /// Nothing horizontal was measured since `since` (s); the uncertainty added since then is
    /// `std` (m), under the bound.
    DeadReckoning {
        /// Time of the last horizontal measurement (s).
        since: f64,
        /// Added horizontal uncertainty (m, one standard deviation).
        std: f64,
    },
    /// Never measured, or dead reckoned past the bound.
    Lost,
}

impl Navigation {
    /// Whether the horizontal estimate can be steered on (measured or dead reckoned).
    pub fn usable(&self) -> bool {
        !matches!(self, Navigation::Lost)
    }

    /// Its name in output (`measured`, `dead_reckoning`, `lost`).
    pub fn name(&self) -> &'static str {
        match self {
            Navigation::Measured => "measured",
            Navigation::DeadReckoning { .. } => "dead_reckoning",
            Navigation::Lost => "lost",
        }
    }
}

/// The larger eigenvalue of the symmetric 2x2 matrix `[[a, b], [b, c]]`: the variance along
/// the direction the horizontal position is least known in.
pub fn larger_variance(a: f64, b: f64, c: f64) -> f64 {
    let mean = 0.5 * (a + c);
    let half = 0.5 * (a - c);
    mean + (half * half + b * b).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_larger_variance_is_the_larger_eigenvalue() {
        assert!((larger_variance(4.0, 0.0, 1.0) - 4.0).abs() < 1e-12);
        // [[2, 1], [1, 2]] has eigenvalues 1 and 3.
        assert!((larger_variance(2.0, 1.0, 2.0) - 3.0).abs() < 1e-12);
    }
}
