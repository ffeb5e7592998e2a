//! An excitation designed for the fit (docs/FIT.md, "The designed excitation"): per axis a
//! train of reversals between two levels of opposite sign, with the level and the half-period
//! drawn from ladders, and pauses at zero between trains.
//!
//! Why this shape. Each of the axes the controller needs is `M_eff a = F - d1 v - d2 v|v| (+
//! B)`. A reversal changes the force by twice the level while the velocity is near its steady
//! value: the acceleration just after it is the force step over the effective mass, and only
//! the effective mass explains it; the steady stretch before the next reversal is damping
//! alone. The ladder of levels separates the linear from the quadratic damping (their ratio
//! changes with the speed), and its low rungs keep the transients slow enough to be sampled
//! (the simulator's yaw settles in 0.02 s at 1 rad/s and in 0.1 s at 0.2 rad/s; a sample is
//! 0.08 s). A pause at zero lets the vehicle coast: the net buoyancy alone moves it in heave.
//! Symmetric trains leave the depth and the heading where they were, so a depth band rarely
//! has to step in.
//!
//! The axes are chosen, not all four always: surge and sway without a position source are
//! the starting file's own motion, and driven they couple into the yaw through the starting
//! file's added masses (a Munk moment the vehicle may not have), which spoils the yaw's fit.

use crate::types::{Input, NU};
use rand::Rng;

/// The levels, as fractions of an axis's largest force: a thruster's force grows as its
/// command squared, so these are commands of about 0.09, 0.14, 0.22, 0.32 and 0.45 of full
/// stick, all outside a T200's deadband and inside a stock joystick gain's reach (0.5).
pub const LEVELS: [f64; 5] = [0.008, 0.02, 0.05, 0.1, 0.2];

/// Half-periods of the reversals per axis (s): yaw settles faster than heave.
fn half_periods(axis: usize) -> &'static [f64] {
    match axis {
        3 => &[0.4, 0.8, 1.6, 2.4],
        _ => &[0.8, 1.6, 3.2],
    }
}

/// Which axes an excitation drives, by their names (`surge`, `sway`, `heave`, `yaw`).
///
/// # Errors
/// A name that is not an axis, or none.
pub fn axes_from_names(names: &[String]) -> Result<[bool; NU], String> {
    let mut on = [false; NU];
    for n in names {
        let i = ["surge", "sway", "heave", "yaw"]
            .iter()
            .position(|a| a.eq_ignore_ascii_case(n.trim()))
            .ok_or_else(|| format!("--axes: `{n}` is not an axis (surge, sway, heave, yaw)"))?;
        on[i] = true;
    }
    if !on.contains(&true) {
        return Err("--axes: name at least one axis".into());
    }
    Ok(on)
}

/// `n` inputs, one per `dt`, driving the `axes` inside `[lo, hi]` (each axis independently:
/// trains of reversals, pauses at zero), the others held at zero.
pub fn designed_inputs(
    rng: &mut impl Rng,
    n: usize,
    dt: f64,
    lo: [f64; NU],
    hi: [f64; NU],
    axes: [bool; NU],
) -> Vec<Input> {
    let mut out = vec![Input::zeros(); n];
    for c in (0..NU).filter(|&c| axes[c]) {
        let largest = lo[c].abs().min(hi[c].abs());
        for (u, v) in out.iter_mut().zip(reversal_trains(rng, n, dt, largest, half_periods(c))) {
            u[c] = v.clamp(lo[c], hi[c]);
        }
    }
    out
}

/// One axis: trains of 4-8 half-periods alternating between `+level` and `-level` (a random
/// first sign), each followed with probability 0.4 by a pause at zero of 1-3 s.
fn reversal_trains(rng: &mut impl Rng, n: usize, dt: f64, largest: f64, halves: &[f64]) -> Vec<f64> {
    let samples = |s: f64| ((s / dt).round() as usize).max(1);
    let mut v = Vec::with_capacity(n);
    // Every level once before any twice: the ladder is covered early, whatever the length.
    let mut ladder: Vec<f64> = Vec::new();
    while v.len() < n {
        if ladder.is_empty() {
            ladder = LEVELS.to_vec();
        }
        let level = largest * ladder.swap_remove(rng.random_range(0..ladder.len()));
        let half = samples(halves[rng.random_range(0..halves.len())]);
        let mut sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        for _ in 0..rng.random_range(4..=8) {
            v.extend(std::iter::repeat_n(sign * level, half));
            sign = -sign;
        }
        if rng.random_bool(0.4) {
            v.extend(std::iter::repeat_n(0.0, samples(rng.random_range(1.0..3.0))));
        }
    }
    v.truncate(n);
    v
}

/// The inputs of `pinc excitation`: `n` samples of `dt` drawn with `rng`, designed for the fit
/// on `axes` (`kind` `fit`), or random steps, ramps and multisines drawn per `segment` seconds
/// (`generic`: the `mpc` preset's excitation), inside `bounds` (a vehicle file's thrusters;
/// without them the BlueROV2's).
pub fn excitation_inputs(
    kind: &str,
    axes: &[String],
    segment: f64,
    n: usize,
    dt: f64,
    bounds: Option<super::InputBounds>,
    rng: &mut impl Rng,
) -> Result<Vec<Input>, String> {
    Ok(match kind {
        "fit" => {
            let axes = axes_from_names(axes)?;
            let (lo, hi) = bounds.unwrap_or((super::BLUEROV2_INPUT_LO, super::BLUEROV2_INPUT_HI));
            designed_inputs(rng, n, dt, lo, hi, axes)
        }
        "generic" => {
            let per = ((segment / dt).round() as usize).max(1);
            // The `mpc` preset's excitation and bounds: what the controller's model is trained on.
            let excitation = match bounds {
                Some((lo, hi)) => super::Excitation::Mixed { lo, hi },
                None => super::DatasetPreset::mpc().sets[0].excitation.clone(),
            };
            let mut inputs = Vec::with_capacity(n);
            while inputs.len() < n {
                let len = per.min(n - inputs.len());
                inputs.extend(super::sample_inputs(&excitation, rng, len, dt));
            }
            inputs
        }
        other => return Err(format!("--design: `{other}` is not a design (fit, generic)")),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn only_the_chosen_axes_move_and_every_level_is_played_inside_the_bounds() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (lo, hi) = ([-200.0, -200.0, -100.0, -50.0], [200.0, 200.0, 100.0, 50.0]);
        let u = designed_inputs(&mut rng, 7500, 0.08, lo, hi, [false, false, true, true]);
        assert_eq!(u.len(), 7500);
        assert!(u.iter().all(|u| u[0] == 0.0 && u[1] == 0.0));
        for (c, largest) in [(2, 100.0), (3, 50.0)] {
            for level in LEVELS {
                let played = u.iter().filter(|u| (u[c].abs() - level * largest).abs() < 1e-9).count();
                assert!(played > 100, "axis {c} level {level}: {played} samples");
            }
            // Symmetric: the mean force is a small fraction of the smallest level.
            let mean = u.iter().map(|u| u[c]).sum::<f64>() / 7500.0;
            assert!(mean.abs() < LEVELS[1] * largest, "axis {c} mean {mean}");
            assert!(u.iter().all(|u| u[c] >= lo[c] && u[c] <= hi[c]));
        }
    }

    #[test]
    fn axes_are_named() {
        assert_eq!(axes_from_names(&["heave".into(), "Yaw".into()]).unwrap(), [false, false, true, true]);
        assert!(axes_from_names(&["roll".into()]).unwrap_err().contains("roll"));
        assert!(axes_from_names(&[]).is_err());
    }
}
