//! Sampling of input sequences, one held value per sample interval.

use super::Excitation;
use crate::types::{Input, NU};
use rand::Rng;
use rand_distr::{Distribution, Normal};
use std::f64::consts::PI;

/// Draws `n` inputs (one per interval of length `dt`) from `excitation`.
pub fn sample_inputs(excitation: &Excitation, rng: &mut impl Rng, n: usize, dt: f64) -> Vec<Input> {
    let mut out = vec![Input::zeros(); n];
    let t = |k: usize| k as f64 * dt;
    match excitation {
        Excitation::Ramp { offset_std } => {
            let offset_dist =
                Normal::new(0.0, *offset_std).unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero std is valid"));
            for c in 0..NU {
                let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                let offset = offset_dist.sample(rng);
                let mid = (n.saturating_sub(1)) as f64 / 2.0;
                for (k, u) in out.iter_mut().enumerate() {
                    // Triangle: 0 at the first interval, 1 at mid-trajectory, 0 at the last.
                    let ramp = if mid > 0.0 { 1.0 - (k as f64 - mid).abs() / mid } else { 0.0 };
                    u[c] = sign * ramp - 0.5 * sign + offset;
                }
            }
        }
        Excitation::Sine { amplitude, f_min_hz, f_max_hz } => {
            for c in 0..NU {
                let f = rng.random_range(*f_min_hz..=*f_max_hz);
                let phase = rng.random_range(0.0..2.0 * PI);
                for (k, u) in out.iter_mut().enumerate() {
                    u[c] = amplitude * (2.0 * PI * f * t(k) + phase).sin();
                }
            }
        }
        Excitation::Constant { input } => out.fill(Input::from(*input)),
        // Recorded inputs exist only in the files they were imported from.
        Excitation::Recorded => {}
        Excitation::Figure8 { surge, moment, freq_hz } => {
            for (k, u) in out.iter_mut().enumerate() {
                u[0] = *surge;
                u[3] = moment * (2.0 * PI * freq_hz * t(k)).sin();
            }
        }
        Excitation::Mixed { lo, hi } => {
            for c in 0..NU {
                let (a, b) = (lo[c], hi[c]);
                let channel = match rng.random_range(0..10) {
                    0..=2 => random_steps(rng, n, dt, a, b),
                    3..=5 => random_ramps(rng, n, dt, a, b),
                    6..=8 => multisine(rng, n, dt, a, b),
                    _ => vec![0.0_f64.clamp(a, b); n],
                };
                for (u, v) in out.iter_mut().zip(channel) {
                    u[c] = v;
                }
            }
        }
    }
    out
}

/// Piecewise-constant levels uniform in `[a, b]`, each held 0.3–2 s.
fn random_steps(rng: &mut impl Rng, n: usize, dt: f64, a: f64, b: f64) -> Vec<f64> {
    let mut v = Vec::with_capacity(n);
    while v.len() < n {
        let level = rng.random_range(a..=b);
        let hold = ((rng.random_range(0.3..2.0) / dt).round() as usize).max(1);
        v.extend(std::iter::repeat_n(level, hold.min(n - v.len())));
    }
    v
}

/// Straight segments between knots uniform in `[a, b]`, 0.5–2.5 s apart.
fn random_ramps(rng: &mut impl Rng, n: usize, dt: f64, a: f64, b: f64) -> Vec<f64> {
    let mut v = Vec::with_capacity(n);
    let mut from = rng.random_range(a..=b);
    while v.len() < n {
        let to = rng.random_range(a..=b);
        let len = ((rng.random_range(0.5..2.5) / dt).round() as usize).max(1);
        for i in 0..len.min(n - v.len()) {
            v.push(from + (to - from) * i as f64 / len as f64);
        }
        from = to;
    }
    v
}

/// A random offset plus three sines of 0.05–1 Hz, clipped to `[a, b]`.
fn multisine(rng: &mut impl Rng, n: usize, dt: f64, a: f64, b: f64) -> Vec<f64> {
    let mid = rng.random_range(a..=b);
    let comps: Vec<(f64, f64, f64)> = (0..3)
        .map(|_| (rng.random_range(0.0..(b - a) / 3.0), rng.random_range(0.05..1.0), rng.random_range(0.0..2.0 * PI)))
        .collect();
    (0..n)
        .map(|k| {
            let t = k as f64 * dt;
            let s: f64 = comps.iter().map(|(amp, f, ph)| amp * (2.0 * PI * f * t + ph).sin()).sum();
            (mid + s).clamp(a, b)
        })
        .collect()
}

/// The paper's input scaling: `Y *= 0.1, Z = 5|Z|, Mz *= 0.05`.
pub fn apply_paper_scaling(inputs: &mut [Input]) {
    for u in inputs {
        u[1] *= 0.1;
        u[2] = 5.0 * u[2].abs();
        u[3] *= 0.05;
    }
}
