//! Adaptive activations and their derivatives, written branch-free so that loops over a
//! layer vectorise: `exp` and `log1p` are evaluated with range reduction and polynomials
//! accurate to a few ulps instead of calls into libm.

use super::kernels::MulAdd;
use super::real::Real;
use crate::model::Activation;

/// PyTorch's softplus returns its input unchanged where `beta * h` exceeds this.
pub const SOFTPLUS_THRESHOLD: f64 = 20.0;

/// Softplus `softplus(beta h) / beta` (PyTorch's threshold) and its derivative
/// `sigmoid(beta h)`.
#[inline(always)]
fn softplus<F: MulAdd, T: Real>(beta: T, inv_beta: T, h: T) -> (T, T) {
    let y = beta * h;
    let e = T::exp_nonpositive(-y.absolute(), F::mul_add);
    let sp = (y.maximum(T::ZERO) + T::log1p_unit(e, F::mul_add)) * inv_beta;
    let sigmoid = if y >= T::ZERO { T::ONE } else { e } / (T::ONE + e);
    let linear = y > T::of(SOFTPLUS_THRESHOLD);
    (if linear { h } else { sp }, if linear { T::ONE } else { sigmoid })
}

/// Adaptive tanh `tanh(beta h)` and its derivative.
#[inline(always)]
fn tanh<T: Real>(beta: T, h: T) -> (T, T) {
    let t = (beta * h).hyperbolic_tangent();
    (t, beta * (T::ONE - t * t))
}

/// Applies `f` to every element of `h` (in place), writing derivatives into `d` if given.
/// The loops are branch-free for softplus, so they vectorise.
#[inline(always)]
fn apply<T: Real>(h: &mut [T], d: Option<&mut [T]>, f: impl Fn(T) -> (T, T)) {
    match d {
        Some(d) => {
            for (h, d) in h.iter_mut().zip(d.iter_mut()) {
                let (v, dv) = f(*h);
                *h = v;
                *d = dv;
            }
        }
        None => {
            for h in h.iter_mut() {
                *h = f(*h).0;
            }
        }
    }
}

/// Applies the activation in place over a layer; with `deriv`, also writes derivatives.
#[inline(always)]
pub(crate) fn activate_slice<F: MulAdd, T: Real>(
    kind: Activation,
    beta: T,
    inv_beta: T,
    h: &mut [T],
    deriv: Option<&mut [T]>,
) {
    // One loop per activation kind: a libm call in a shared loop body would stop the
    // softplus loop from vectorising.
    match kind {
        Activation::Softplus => apply(h, deriv, |h| softplus::<F, T>(beta, inv_beta, h)),
        Activation::Tanh => apply(h, deriv, |h| tanh(beta, h)),
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
            if x < -86.0 && T::of(1e-50).to_f64() == 0.0 {
                break; // f32 underflows below
            }
            let got = if fused {
                T::exp_nonpositive(T::of(x), Fused::mul_add)
            } else {
                T::exp_nonpositive(T::of(x), Portable::mul_add)
            };
            let want = T::of(x).to_f64().exp();
            worst = worst.max(((got.to_f64() - want) / want).abs());
        }
        worst
    }

    fn worst_log1p<T: Real>(fused: bool) -> f64 {
        let mut worst = 0.0_f64;
        for i in 0..=100_000 {
            let e = T::of(i as f64 / 100_000.0);
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
        for beta in [1.0, -0.9, 1.7, 0.5] {
            for i in -400..=400 {
                let h = i as f64 * 0.1;
                let (v, d) = softplus::<Portable, f64>(beta, 1.0 / beta, h);
                let y = beta * h;
                let want = if y > 20.0 { h } else { (1.0 + y.exp()).ln() / beta };
                assert!((v - want).abs() <= 1e-14 * want.abs().max(1.0), "beta {beta} h {h}: {v} vs {want}");
                let want_d = if y > 20.0 { 1.0 } else { 1.0 / (1.0 + (-y).exp()) };
                assert!((d - want_d).abs() < 1e-15, "derivative at beta {beta} h {h}");
                let mut slice = [h];
                activate_slice::<Portable, f64>(Activation::Softplus, beta, 1.0 / beta, &mut slice, None);
                assert_eq!(v, slice[0]);
                let v32 = softplus::<Portable, f32>(beta as f32, 1.0 / beta as f32, h as f32).0;
                assert!((f64::from(v32) - want).abs() <= 1e-6 * want.abs().max(1.0), "f32 at beta {beta} h {h}");
            }
        }
    }
}
