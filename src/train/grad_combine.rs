//! Combining per-loss gradients into one update direction (docs/MODEL.md section 4), on flattened
//! gradients: plain sum, the paper's normalisation, and ConFIG (Liu, Chu & Thuerey 2024).
//! Then a global-norm clip (burn's own clipping is per tensor).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// How per-loss gradients are combined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum GradCombine {
    /// `g = sum_n w_n g_n`.
    Sum,
    /// `g_n' = g_n |g_0| / |g_n|`, `g = sum_n w_n g_n'`, `g' = g |g_0| / |g|`, with `g_0`
    /// the data-loss gradient (the first one).
    Normalize,
    /// The conflict-free direction: `d` with equal positive inner product with every unit
    /// gradient (`d = U (U^T U)^+ 1`), scaled by the sum of the gradients' projections on it.
    Config,
}

fn norm(g: &[f32]) -> f64 {
    g.iter().map(|&v| f64::from(v) * f64::from(v)).sum::<f64>().sqrt()
}

/// Combines `grads` (one flattened gradient per active loss, the data loss first) with
/// `weights` (one per loss; ConFIG ignores them). Zero gradients are skipped where a
/// direction is needed.
///
/// # Panics
/// If `grads` is empty, lengths differ, or `weights.len() != grads.len()`.
pub fn combine(scheme: GradCombine, grads: &[Vec<f32>], weights: &[f64]) -> Vec<f32> {
    weighted_sum(grads, &coefficients(scheme, grads, weights))
}

/// `sum_n a_n g_n` (what [`combine`] returns, from coefficients already known).
pub fn weighted_sum(grads: &[Vec<f32>], a: &[f64]) -> Vec<f32> {
    let mut out = vec![0.0f64; grads[0].len()];
    for (g, &c) in grads.iter().zip(a) {
        if c != 0.0 {
            for (o, &v) in out.iter_mut().zip(g) {
                *o += c * f64::from(v);
            }
        }
    }
    out.into_iter().map(|v| v as f32).collect()
}

/// The coefficients `a_n` with `combine(scheme, grads, weights) = sum_n a_n g_n`: every scheme
/// is a linear combination of the per-loss gradients, so the trainer can keep `a` from a step
/// that measured each gradient and reuse it for steps that take one backward pass of
/// `sum_n a_n L_n` (the lagged combination of `TrainConfig::grad_refresh`).
///
/// # Panics
/// As [`combine`].
pub fn coefficients(scheme: GradCombine, grads: &[Vec<f32>], weights: &[f64]) -> Vec<f64> {
    assert!(!grads.is_empty() && weights.len() == grads.len(), "one weight per gradient");
    let p = grads[0].len();
    assert!(grads.iter().all(|g| g.len() == p), "gradients of different lengths");
    let norms: Vec<f64> = grads.iter().map(|g| norm(g)).collect();
    match scheme {
        GradCombine::Sum => weights.to_vec(),
        GradCombine::Normalize => {
            let n0 = norms[0];
            let mut a: Vec<f64> =
                weights.iter().zip(&norms).map(|(&w, &n)| if n == 0.0 { 0.0 } else { w * n0 / n }).collect();
            // The rescale of the sum to |g_0|.
            let mut sum = vec![0.0f64; p];
            for (g, &c) in grads.iter().zip(&a) {
                for (o, &v) in sum.iter_mut().zip(g) {
                    *o += c * f64::from(v);
                }
            }
            let n = sum.iter().map(|v| v * v).sum::<f64>().sqrt();
            if n > 0.0 {
                a.iter_mut().for_each(|c| *c *= n0 / n);
            }
            a
        }
        GradCombine::Config => {
            let live: Vec<usize> = (0..grads.len()).filter(|&i| norms[i] > 0.0).collect();
            let mut a = vec![0.0; grads.len()];
            if live.is_empty() {
                return a;
            }
            let m = live.len();
            let units = DMatrix::from_fn(p, m, |r, c| f64::from(grads[live[c]][r]) / norms[live[c]]);
            let gram = units.transpose() * &units;
            let coeff = gram.pseudo_inverse(1e-12).expect("pseudo-inverse of a small Gram matrix")
                * DVector::from_element(m, 1.0);
            let d = &units * &coeff;
            let dn = d.norm();
            if dn == 0.0 {
                return a;
            }
            // The conflict-free direction, scaled by the sum of the gradients' projections on it.
            let length: f64 = live
                .iter()
                .map(|&i| grads[i].iter().zip(d.iter()).map(|(&g, v)| f64::from(g) * v).sum::<f64>())
                .sum::<f64>()
                / dn;
            for (c, &i) in live.iter().enumerate() {
                a[i] = length / dn * coeff[c] / norms[i];
            }
            a
        }
    }
}

/// Scales `g` so its global L2 norm is at most `max_norm`; returns the norm before clipping.
pub fn clip_global_norm(g: &mut [f32], max_norm: f64) -> f64 {
    let n = norm(g);
    if n > max_norm {
        let s = (max_norm / n) as f32;
        g.iter_mut().for_each(|v| *v *= s);
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dot(a: &[f32], b: &[f32]) -> f64 {
        a.iter().zip(b).map(|(&x, &y)| f64::from(x) * f64::from(y)).sum()
    }

    /// Deterministic gradients with strong conflicts (pairs at obtuse angles).
    fn conflicting(m: usize, p: usize, seed: u64) -> Vec<Vec<f32>> {
        let mut s = seed;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 33) as f64 / (1u64 << 31) as f64 - 1.0) as f32
        };
        let base: Vec<f32> = (0..p).map(|_| next()).collect();
        (0..m)
            .map(|i| {
                let sign = if i % 2 == 0 { 1.0 } else { -0.8 };
                base.iter().map(|&b| sign * b + 0.7 * next()).collect::<Vec<f32>>()
            })
            .map(|g| g.iter().map(|v| v * (1.0 + m as f32)).collect())
            .collect()
    }

    #[test]
    fn config_direction_never_opposes_any_loss_gradient() {
        let mut sum_conflicts = 0;
        for seed in 0..50 {
            for m in 2..=5 {
                let grads = conflicting(m, 40, seed);
                let sum = combine(GradCombine::Sum, &grads, &vec![1.0; m]);
                if grads.iter().any(|gi| dot(&sum, gi) < 0.0) {
                    sum_conflicts += 1;
                }
                let g = combine(GradCombine::Config, &grads, &vec![1.0; m]);
                for (i, gi) in grads.iter().enumerate() {
                    assert!(
                        dot(&g, gi) >= -1e-6 * norm(&g) * norm(gi),
                        "seed {seed} m {m}: g . g_{i} = {}",
                        dot(&g, gi)
                    );
                }
                // ... and its projections on the unit gradients are all equal.
                let proj: Vec<f64> = grads.iter().map(|gi| dot(&g, gi) / norm(gi)).collect();
                let (lo, hi) = proj.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
                assert!(hi - lo <= 1e-4 * hi.abs().max(1e-9), "seed {seed} m {m}: projections {proj:?}");
            }
        }
        // The cases do conflict: the plain sum opposes some loss gradient in many of them.
        assert!(sum_conflicts >= 20, "only {sum_conflicts} of 200 cases conflict under the plain sum");
    }

    #[test]
    fn normalisation_follows_the_paper_formula() {
        let g0 = vec![3.0f32, 4.0]; // |g0| = 5
        let g1 = vec![0.0f32, 10.0]; // rescaled to (0, 5)
        let g2 = vec![-1.0f32, 0.0]; // rescaled to (-5, 0)
        let w = [1.0, 0.5, 0.5];
        let g = combine(GradCombine::Normalize, &[g0.clone(), g1, g2], &w);
        // sum = (3, 4) + 0.5 (0, 5) + 0.5 (-5, 0) = (0.5, 6.5), rescaled to |g0| = 5.
        let s = (0.5f64 * 0.5 + 6.5 * 6.5).sqrt();
        assert!((f64::from(g[0]) - 0.5 * 5.0 / s).abs() < 1e-6 && (f64::from(g[1]) - 6.5 * 5.0 / s).abs() < 1e-6);
        assert!((norm(&g) - 5.0).abs() < 1e-5);
        let sum = combine(GradCombine::Sum, &[g0.clone(), vec![1.0, 1.0]], &[1.0, 2.0]);
        assert_eq!(sum, vec![5.0, 6.0]);
    }

    #[test]
    fn global_clip_scales_the_whole_vector() {
        let mut g = vec![30.0f32, 40.0, 0.0];
        assert_eq!(clip_global_norm(&mut g, 5.0), 50.0);
        assert!((norm(&g) - 5.0).abs() < 1e-6 && (g[0] / g[1] - 0.75).abs() < 1e-6);
        let mut small = vec![0.3f32, 0.4];
        clip_global_norm(&mut small, 5.0);
        assert_eq!(small, vec![0.3, 0.4]);
    }
}
