//! Stage 5, the heave gain: the heave force the identified vehicle still misses, as the
//! filter's heave gain estimates it, and the vehicle with it taken into its heave equation.
//! Apart because it is the one stage that changes the identified coefficients by a rule
//! rather than by a fit.

use crate::estimation::ekf::HEAVE_GAIN;
use crate::estimation::replay::Replay;
use crate::vehicle::VehicleParams;

/// The heave gain below which the heave equation is left as identified.
pub(super) const HEAVE_GAIN_TOLERANCE: f64 = 0.02;
/// Most times the heave equation takes the filter's heave gain in.
pub(super) const MAX_HEAVE_GAIN_STEPS: usize = 3;

/// The mean over every smoothed step of the filter's heave gain.
pub(super) fn mean_heave_gain(runs: &[Replay]) -> f64 {
    let gains: Vec<f64> = runs.iter().flat_map(|r| r.smoothed.iter().map(|s| s.state[HEAVE_GAIN])).collect();
    gains.iter().sum::<f64>() / gains.len().max(1) as f64
}

/// `p` with its heave equation scaled so that a heave force acts on it as `1 + gain` times
/// that force acts on `p`: the effective mass, the damping and the net buoyancy all divided
/// by `1 + gain` (`m` stays: the added mass takes the change).
pub fn with_heave_gain(p: VehicleParams, gain: f64) -> VehicleParams {
    let s = 1.0 + gain;
    let mut q = p;
    q.z_wd = p.m - (p.m - p.z_wd) / s;
    q.z_w = p.z_w / s;
    q.z_ww = p.z_ww / s;
    q.volume = (p.m * p.g - p.net_buoyancy() / s) / (p.rho * p.g);
    q
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::Input;

    /// Taken in, a heave gain makes a force act on the vehicle as `1 + gain` times it acts on
    /// the original, at any heave rate; nothing else changes.
    #[test]
    fn a_heave_gain_taken_in_scales_the_heave_force() {
        let p = VehicleParams::default();
        let gain = 0.3;
        let q = with_heave_gain(p, gain);
        for (w, force) in [(0.0, 10.0), (0.4, -20.0), (-0.3, 5.0)] {
            let mut x = crate::State::zeros();
            (x[3], x[7]) = (1.0, w);
            let on = |v: &VehicleParams, f: f64| crate::vehicle::rhs(v, &x, &Input::new(0.0, 0.0, f, 0.0))[7];
            approx::assert_relative_eq!(on(&q, force), on(&p, (1.0 + gain) * force), epsilon = 1e-12);
        }
        assert_eq!((q.m, q.x_ud, q.n_rr), (p.m, p.x_ud, p.n_rr));
    }
}
