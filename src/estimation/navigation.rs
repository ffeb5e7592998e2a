//! Where the horizontal estimate stands, for the controller that steers on it: measured (a
//! position or a velocity fused lately), dead reckoned (nothing horizontal measured since, the
//! model moving the estimate under the applied thrust and the current estimated before, its
//! added uncertainty still under a bound) or lost. And the fixes of a position source put on the
//! estimator's local frame: latitude and longitude about an origin.
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

/// Metres per 1e-7 degree of latitude, as ArduPilot's `LOCATION_SCALING_FACTOR` (its flat
/// earth about the EKF origin, which is what `LOCAL_POSITION_NED` is measured in).
const METRES_PER_E7: f64 = 0.011_131_884_502_145_034;

/// A position source's frame: north and east (m) of a geodetic origin, on ArduPilot's flat
/// earth (longitude scaled by the cosine of the latitude it is measured at).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalFrame {
    lat_e7: i32,
    lon_e7: i32,
}

impl LocalFrame {
    /// The frame about an origin in 1e-7 degrees (`GPS_GLOBAL_ORIGIN`'s).
    pub fn new(lat_e7: i32, lon_e7: i32) -> Self {
        Self { lat_e7, lon_e7 }
    }

    /// North and east (m) of the origin of a position in 1e-7 degrees.
    pub fn north_east(&self, lat_e7: i32, lon_e7: i32) -> (f64, f64) {
        let d_lat = f64::from(lat_e7) - f64::from(self.lat_e7);
        let d_lon = wrap_lon_e7(i64::from(lon_e7) - i64::from(self.lon_e7));
        // ArduPilot scales longitude by the cosine of the mean of the two latitudes.
        let mid = (f64::from(lat_e7) + f64::from(self.lat_e7)) * 0.5e-7;
        let scale = mid.to_radians().cos().max(0.01);
        (d_lat * METRES_PER_E7, d_lon * METRES_PER_E7 * scale)
    }
}

/// A longitude difference (1e-7 degrees) wrapped into +-180 degrees.
fn wrap_lon_e7(d: i64) -> f64 {
    const FULL: i64 = 3_600_000_000;
    let mut d = d % FULL;
    if d > FULL / 2 {
        d -= FULL;
    } else if d < -FULL / 2 {
        d += FULL;
    }
    d as f64
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

    /// One degree of latitude is 111.32 km on ArduPilot's scale; a degree of longitude at
    /// 60 degrees half that; across the date line the short way round.
    #[test]
    fn north_and_east_of_an_origin_on_ardupilots_flat_earth() {
        let f = LocalFrame::new(0, 0);
        let (n, e) = f.north_east(10_000_000, 0);
        assert!((n - 111_318.845).abs() < 0.01 && e == 0.0, "{n} {e}");
        let f = LocalFrame::new(600_000_000, 1_799_999_999);
        let (n, e) = f.north_east(600_000_000, -1_799_999_999);
        assert_eq!(n, 0.0);
        assert!((e - 2.0 * METRES_PER_E7 * 0.5).abs() < 1e-9, "{e}");
        // 10 m north and 5 m east of the simulator's home, and back.
        let home = LocalFrame::new(338_103_130, -1_183_938_670);
        let d_lat = (10.0 / METRES_PER_E7).round() as i32;
        let (n, _) = home.north_east(338_103_130 + d_lat, -1_183_938_670);
        assert!((n - 10.0).abs() < 0.006, "{n}");
    }
}
