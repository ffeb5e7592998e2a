//! Adaptive activations and their derivatives, written branch-free so that loops over a
//! layer vectorise: `exp` and `log1p` are evaluated with range reduction and polynomials
//! accurate to a few ulps instead of calls into libm.

use super::packs::{MulAdd, PACK, Pack};
use super::real::Real;
use crate::model::Activation;

/// PyTorch's softplus returns its input unchanged where `beta * h` exceeds this.
pub const SOFTPLUS_THRESHOLD: f64 = 20.0;

// The predictor folds each layer's beta into its weights (the pre-activation is `y = beta h`)
// and `1 / beta` into whatever reads the layer's output, so the kernels below evaluate the
// unit-slope functions of `y`: `ln(1 + e^y)` (PyTorch's `softplus(beta h) / beta` is that
// divided by beta) and `tanh(y)`, with their derivatives with respect to `y`.

/// `ln(1 + e^y)` (`y` itself above PyTorch's threshold) and its derivative `sigmoid(y)`.
#[inline(always)]
fn softplus<F: MulAdd, T: Real>(y: T) -> (T, T) {
    let e = T::exp_nonpositive(-y.abs(), F::mul_add);
    // max(y, 0) as (y + |y|) / 2 (exact for finite y): `maximum` would turn a NaN (from an
    // input beyond the network's precision) into 0 and a garbage prediction into a finite one.
    let sp = T::from_f64(0.5) * (y + y.abs()) + T::log1p_unit(e, F::mul_add);
    let sigmoid = if y >= T::ZERO { T::ONE } else { e } / (T::ONE + e);
    let linear = y > T::from_f64(SOFTPLUS_THRESHOLD);
    (if linear { y } else { sp }, if linear { T::ONE } else { sigmoid })
}

/// `tanh(y)` and its derivative.
#[inline(always)]
fn tanh<T: Real>(y: T) -> (T, T) {
    let t = y.tanh();
    (t, T::ONE - t * t)
}

/// Applies `f` to every value of `pre`, writing values into `out` and derivatives into `d`
/// if given. Out of place on purpose: in place, "keep y above the threshold" compiles to a
/// masked store, which the next layer's loads cannot be forwarded from (5 % of a rollout here).
/// Packs go four at a time: the activation is a long dependency chain, and four
/// independent chains side by side keep the FMA units busy (one pack at a time, the step
/// waits on its latency).
#[inline(always)]
fn apply<T: Real>(pre: &[Pack<T>], out: &mut [Pack<T>], mut d: Option<&mut [Pack<T>]>, f: impl Fn(T) -> (T, T)) {
    let mut p = 0;
    while pre.len() - p >= 4 {
        apply_block::<T, 4>(pre, out, d.as_deref_mut(), p, &f);
        p += 4;
    }
    while p < pre.len() {
        apply_block::<T, 1>(pre, out, d.as_deref_mut(), p, &f);
        p += 1;
    }
}

/// `B` packs from `p` on, through locals (the SLP vectoriser turns each line into `B`
/// vector operations).
#[inline(always)]
fn apply_block<T: Real, const B: usize>(
    pre: &[Pack<T>],
    out: &mut [Pack<T>],
    d: Option<&mut [Pack<T>]>,
    p: usize,
    f: &impl Fn(T) -> (T, T),
) {
    let y: [Pack<T>; B] = pre[p..p + B].try_into().expect("block in range");
    let mut v = [[T::ZERO; PACK]; B];
    match d {
        Some(d) => {
            let mut dv = [[T::ZERO; PACK]; B];
            for k in 0..B {
                for t in 0..PACK {
                    (v[k][t], dv[k][t]) = f(y[k][t]);
                }
            }
            d[p..p + B].copy_from_slice(&dv);
        }
        None => {
            for k in 0..B {
                for t in 0..PACK {
                    v[k][t] = f(y[k][t]).0;
                }
            }
        }
    }
    out[p..p + B].copy_from_slice(&v);
}

/// The activation of a layer's pre-activations `pre`, into `out`; with `deriv`, also the
/// derivatives.
#[inline(always)]
pub(crate) fn activate<F: MulAdd, T: Real>(
    kind: Activation,
    pre: &[Pack<T>],
    out: &mut [Pack<T>],
    deriv: Option<&mut [Pack<T>]>,
) {
    // One loop per activation kind: a libm call in a shared loop body would stop the
    // softplus loop from vectorising.
    match kind {
        Activation::Softplus => apply(pre, out, deriv, softplus::<F, T>),
        Activation::Tanh => apply(pre, out, deriv, tanh),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::kernels::{Fused, Portable};

    fn worst_exp<T: Real>(fused: bool) -> f64 {
        let mut worst = 0.0_f64;
        for i in 0..200_000 {
            let x = -(i as f64) * 0.0035; // 0 .. -700
            if x < -86.0 && T::from_f64(1e-50).to_f64() == 0.0 {
                break; // f32 underflows below
            }
            let got = if fused {
                T::exp_nonpositive(T::from_f64(x), Fused::mul_add)
            } else {
                T::exp_nonpositive(T::from_f64(x), Portable::mul_add)
            };
            let want = T::from_f64(x).to_f64().exp();
            worst = worst.max(((got.to_f64() - want) / want).abs());
        }
        worst
    }

    fn worst_log1p<T: Real>(fused: bool) -> f64 {
        let mut worst = 0.0_f64;
        for i in 0..=100_000 {
            let e = T::from_f64(i as f64 / 100_000.0);
            let got = if fused { T::log1p_unit(e, Fused::mul_add) } else { T::log1p_unit(e, Portable::mul_add) };
            let want = e.to_f64().ln_1p();
            let rel = if want == 0.0 { got.to_f64().abs() } else { ((got.to_f64() - want) / want).abs() };
            worst = worst.max(rel);
        }
        worst
    }

    #[test]
    fn exp_and_log1p_match_libm_to_a_few_ulps() {
        for fused in [false, true] {
            assert!(worst_exp::<f64>(fused) < 6e-16, "f64 exp {:e}", worst_exp::<f64>(fused));
            assert!(worst_log1p::<f64>(fused) < 6e-16, "f64 log1p {:e}", worst_log1p::<f64>(fused));
            assert!(worst_exp::<f32>(fused) < 4e-7, "f32 exp {:e}", worst_exp::<f32>(fused));
            assert!(worst_log1p::<f32>(fused) < 4e-7, "f32 log1p {:e}", worst_log1p::<f32>(fused));
        }
        assert_eq!(f64::log1p_unit(1e-300, Portable::mul_add), 1e-300);
        assert!(f64::exp_nonpositive(-1e6, Portable::mul_add) < 1e-300);
    }

    #[test]
    fn softplus_follows_torch_and_its_derivative_is_the_sigmoid() {
        // torch: softplus(h; beta) = ln(1 + e^(beta h)) / beta, h where beta h > 20; the
        // runtime evaluates ln(1 + e^y) at y = beta h and leaves the 1 / beta to the next layer.
        for beta in [1.0, -0.9, 1.7, 0.5] {
            for i in -400..=400 {
                let h = i as f64 * 0.1;
                let y = beta * h;
                let (v, d) = softplus::<Portable, f64>(y);
                let want = if y > 20.0 { h } else { (1.0 + y.exp()).ln() / beta };
                assert!((v / beta - want).abs() <= 1e-14 * want.abs().max(1.0), "beta {beta} h {h}: {v} vs {want}");
                let want_d = if y > 20.0 { 1.0 } else { 1.0 / (1.0 + (-y).exp()) };
                assert!((d - want_d).abs() < 1e-15, "derivative at beta {beta} h {h}");
                let mut pack = [[0.0; PACK]];
                activate::<Fused, f64>(Activation::Softplus, &[[y; PACK]], &mut pack, None);
                assert!(pack[0].iter().all(|&p| (p - v).abs() <= 1e-15 * v.abs().max(1.0)));
                let v32 = softplus::<Portable, f32>(y as f32).0;
                assert!((f64::from(v32) - v).abs() <= 1e-6 * v.abs().max(1.0), "f32 at beta {beta} h {h}");
            }
        }
    }
}
