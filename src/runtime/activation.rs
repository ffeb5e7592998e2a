//! Adaptive activations and their derivatives, written branch-free so that loops over a
//! layer vectorise: `exp` and `log1p` are evaluated with range reduction and polynomials
//! accurate to a few ulps instead of calls into libm.

use crate::model::Activation;

const LN2_HI: f64 = 6.931_471_803_691_238e-1;
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
const LOG2E: f64 = std::f64::consts::LOG2_E;
/// Adding then subtracting 1.5 * 2^52 rounds to the nearest integer and leaves it in the
/// low mantissa bits.
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;
/// PyTorch's softplus returns its input unchanged where `beta * h` exceeds this.
pub const SOFTPLUS_THRESHOLD: f64 = 20.0;

use super::kernels::MulAdd;

/// `exp(x)` for `x <= 0` (clamped at -708, where the result underflows to ~3e-308).
#[inline(always)]
fn exp_nonpositive_with<F: MulAdd>(x: f64) -> f64 {
    let x = x.max(-708.0);
    let t = F::mul_add(x, LOG2E, ROUND_MAGIC);
    let k = t - ROUND_MAGIC;
    let r = F::mul_add(-k, LN2_LO, F::mul_add(-k, LN2_HI, x)); // |r| <= ln2 / 2
    // Taylor series of exp(r) to degree 13 (truncation below 1e-17 for |r| <= 0.347),
    // evaluated as two interleaved Horner chains in r^2 to halve the dependency depth.
    let r2 = r * r;
    let even = [1.0 / 479_001_600.0, 1.0 / 3_628_800.0, 1.0 / 40_320.0, 1.0 / 720.0, 1.0 / 24.0, 0.5, 1.0];
    let odd = [1.0 / 6_227_020_800.0, 1.0 / 39_916_800.0, 1.0 / 362_880.0, 1.0 / 5_040.0, 1.0 / 120.0, 1.0 / 6.0, 1.0];
    let (mut pe, mut po) = (even[0], odd[0]);
    for i in 1..7 {
        pe = F::mul_add(pe, r2, even[i]);
        po = F::mul_add(po, r2, odd[i]);
    }
    let p = F::mul_add(po, r, pe);
    // 2^k from the integer in t's low bits (k >= -1022 thanks to the clamp).
    let ki = t.to_bits().wrapping_sub(ROUND_MAGIC.to_bits()) as i64;
    let scale = f64::from_bits(((ki + 1023) as u64) << 52);
    p * scale
}

/// `ln(1 + e) = j ln 2 + 2 atanh(s)` with `1 + e = 2^j m`, `m` in `[sqrt(1/2), sqrt(2)]`,
/// `s = (m - 1) / (m + 1)`: for `1 + e <= sqrt 2`, `s = e / (2 + e)` (no cancellation for
/// small `e`); above, `m = (1 + e) / 2` and `s = (e - 1) / (e + 3)`. `|s| <= 0.172`.
#[inline(always)]
fn log1p_unit_with<F: MulAdd>(e: f64) -> f64 {
    let high = e > std::f64::consts::SQRT_2 - 1.0;
    let (num, den, j) = if high { (e - 1.0, e + 3.0, LN2_HI + LN2_LO) } else { (e, 2.0 + e, 0.0) };
    let s = num / den;
    let s2 = s * s;
    // 2 atanh(s) = 2 (s + s^3/3 + ...): s2 <= 0.0295, so terms to s^23 reach 1e-17.
    let mut p = 1.0 / 23.0;
    for n in (0..11).rev() {
        p = F::mul_add(p, s2, 1.0 / (2 * n + 1) as f64);
    }
    F::mul_add(2.0 * s, p, j)
}

/// Activation value and derivative `d act / d h` at pre-activation `h`.
#[inline(always)]
pub(crate) fn activate<F: MulAdd>(kind: Activation, beta: f64, inv_beta: f64, h: f64) -> (f64, f64) {
    let y = beta * h;
    match kind {
        Activation::Softplus => {
            let e = exp_nonpositive_with::<F>(-y.abs());
            let sp = (y.max(0.0) + log1p_unit_with::<F>(e)) * inv_beta;
            let sigmoid = if y >= 0.0 { 1.0 } else { e } / (1.0 + e);
            if y > SOFTPLUS_THRESHOLD { (h, 1.0) } else { (sp, sigmoid) }
        }
        Activation::Tanh => {
            let t = y.tanh();
            (t, beta * (1.0 - t * t))
        }
    }
}

/// Activation value only (cheaper: no derivative).
#[inline(always)]
pub(crate) fn activate_value<F: MulAdd>(kind: Activation, beta: f64, inv_beta: f64, h: f64) -> f64 {
    let y = beta * h;
    match kind {
        Activation::Softplus => {
            let sp = (y.max(0.0) + log1p_unit_with::<F>(exp_nonpositive_with::<F>(-y.abs()))) * inv_beta;
            if y > SOFTPLUS_THRESHOLD { h } else { sp }
        }
        Activation::Tanh => y.tanh(),
    }
}

/// Elements processed together so that independent dependency chains overlap.
const CHUNK: usize = 8;

/// Applies the activation in place over a layer; with `deriv`, also writes derivatives.
#[inline(always)]
pub(crate) fn activate_slice<F: MulAdd>(
    kind: Activation,
    beta: f64,
    inv_beta: f64,
    h: &mut [f64],
    deriv: Option<&mut [f64]>,
) {
    match deriv {
        Some(d) => {
            let mut hc = h.chunks_exact_mut(CHUNK);
            let mut dc = d.chunks_exact_mut(CHUNK);
            for (h, d) in (&mut hc).zip(&mut dc) {
                let h: &mut [f64; CHUNK] = h.try_into().expect("chunk");
                let d: &mut [f64; CHUNK] = d.try_into().expect("chunk");
                for i in 0..CHUNK {
                    (h[i], d[i]) = activate::<F>(kind, beta, inv_beta, h[i]);
                }
            }
            for (h, d) in hc.into_remainder().iter_mut().zip(dc.into_remainder()) {
                (*h, *d) = activate::<F>(kind, beta, inv_beta, *h);
            }
        }
        None => {
            let mut hc = h.chunks_exact_mut(CHUNK);
            for h in &mut hc {
                let h: &mut [f64; CHUNK] = h.try_into().expect("chunk");
                for v in h.iter_mut() {
                    *v = activate_value::<F>(kind, beta, inv_beta, *v);
                }
            }
            for v in hc.into_remainder() {
                *v = activate_value::<F>(kind, beta, inv_beta, *v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::kernels::{Fused, Portable};

    fn exp_nonpositive(x: f64) -> f64 {
        exp_nonpositive_with::<Portable>(x)
    }

    fn log1p_unit(e: f64) -> f64 {
        log1p_unit_with::<Portable>(e)
    }

    #[test]
    fn exp_matches_libm_to_a_few_ulps() {
        let mut worst = 0.0_f64;
        for i in 0..200_000 {
            let x = -(i as f64) * 0.0035; // 0 .. -700
            let rel = ((exp_nonpositive(x) - x.exp()) / x.exp()).abs();
            worst = worst.max(rel);
        }
        assert!(worst < 6e-16, "worst relative error {worst:e}");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert!(exp_nonpositive(-1e6) < 1e-300);
    }

    #[test]
    fn log1p_matches_libm_to_a_few_ulps() {
        let mut worst = 0.0_f64;
        for i in 0..=100_000 {
            let e = i as f64 / 100_000.0;
            let want = e.ln_1p();
            let got = log1p_unit(e);
            let rel = if want == 0.0 { got.abs() } else { ((got - want) / want).abs() };
            worst = worst.max(rel);
        }
        assert!(worst < 6e-16, "worst relative error {worst:e}");
        assert_eq!(log1p_unit(1e-300), 1e-300);
        // The fused variant is as accurate.
        for i in 0..=1000 {
            let e = i as f64 / 1000.0;
            assert!((log1p_unit_with::<Fused>(e) - e.ln_1p()).abs() <= 6e-16 * e.ln_1p().max(1e-300));
            let x = -(i as f64) * 0.7;
            assert!((exp_nonpositive_with::<Fused>(x) - x.exp()).abs() <= 6e-16 * x.exp());
        }
    }

    #[test]
    fn softplus_follows_torch_and_its_derivative_is_the_sigmoid() {
        for beta in [1.0, -0.9, 1.7, 0.5] {
            for i in -400..=400 {
                let h = i as f64 * 0.1;
                let (v, d) = activate::<Portable>(Activation::Softplus, beta, 1.0 / beta, h);
                let y = beta * h;
                let want = if y > 20.0 { h } else { (1.0 + y.exp()).ln() / beta };
                assert!((v - want).abs() <= 1e-14 * want.abs().max(1.0), "beta {beta} h {h}: {v} vs {want}");
                let want_d = if y > 20.0 { 1.0 } else { 1.0 / (1.0 + (-y).exp()) };
                assert!((d - want_d).abs() < 1e-15, "derivative at beta {beta} h {h}");
                assert_eq!(v, activate_value::<Portable>(Activation::Softplus, beta, 1.0 / beta, h));
            }
        }
    }
}
