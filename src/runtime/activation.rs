//! Adaptive activations and their derivatives, written branch-free so that loops over a
//! layer vectorise: `exp` and `log1p` are evaluated with range reduction and polynomials
//! accurate to a few ulps instead of calls into libm.

use crate::model::Activation;

const LN2_HI: f64 = 6.931_471_803_691_238_164_90e-1;
const LN2_LO: f64 = 1.908_214_929_270_587_700_02e-10;
const LOG2E: f64 = std::f64::consts::LOG2_E;
/// Adding then subtracting 1.5 * 2^52 rounds to the nearest integer and leaves it in the
/// low mantissa bits.
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;
/// PyTorch's softplus returns its input unchanged where `beta * h` exceeds this.
pub const SOFTPLUS_THRESHOLD: f64 = 20.0;

/// `exp(x)` for `x <= 0` (clamped at -708, where the result underflows to ~3e-308).
#[inline(always)]
pub fn exp_nonpositive(x: f64) -> f64 {
    let x = x.max(-708.0);
    let t = x * LOG2E + ROUND_MAGIC;
    let k = t - ROUND_MAGIC;
    let r = (x - k * LN2_HI) - k * LN2_LO; // |r| <= ln2 / 2
    // Taylor series of exp(r) to degree 13: truncation below 1e-17 for |r| <= 0.347.
    let mut p = 1.0 / 6_227_020_800.0;
    for c in [
        1.0 / 479_001_600.0,
        1.0 / 39_916_800.0,
        1.0 / 3_628_800.0,
        1.0 / 362_880.0,
        1.0 / 40_320.0,
        1.0 / 5_040.0,
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        p = p * r + c;
    }
    // 2^k from the integer in t's low bits (k >= -1022 thanks to the clamp).
    let ki = t.to_bits().wrapping_sub(ROUND_MAGIC.to_bits()) as i64;
    let scale = f64::from_bits(((ki + 1023) as u64) << 52);
    p * scale
}

/// `ln(1 + e)` for `e` in `[0, 1]`, as `2 atanh(e / (2 + e))` (no cancellation for small e).
#[inline(always)]
pub fn log1p_unit(e: f64) -> f64 {
    let s = e / (2.0 + e); // in [0, 1/3]
    let s2 = s * s;
    // 2 atanh(s) = 2 (s + s^3/3 + s^5/5 + ...); s2 <= 1/9, so 17 terms reach 1e-17.
    let mut p = 1.0 / 35.0;
    for n in (0..17).rev() {
        p = p * s2 + 1.0 / (2 * n + 1) as f64;
    }
    2.0 * s * p
}

/// Activation value and derivative `d act / d h` at pre-activation `h`.
#[inline(always)]
pub fn activate(kind: Activation, beta: f64, inv_beta: f64, h: f64) -> (f64, f64) {
    let y = beta * h;
    match kind {
        Activation::Softplus => {
            let e = exp_nonpositive(-y.abs());
            let sp = (y.max(0.0) + log1p_unit(e)) * inv_beta;
            let sigmoid = if y >= 0.0 { 1.0 / (1.0 + e) } else { e / (1.0 + e) };
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
pub fn activate_value(kind: Activation, beta: f64, inv_beta: f64, h: f64) -> f64 {
    let y = beta * h;
    match kind {
        Activation::Softplus => {
            let sp = (y.max(0.0) + log1p_unit(exp_nonpositive(-y.abs()))) * inv_beta;
            if y > SOFTPLUS_THRESHOLD { h } else { sp }
        }
        Activation::Tanh => y.tanh(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_matches_libm_to_a_few_ulps() {
        let mut worst = 0.0_f64;
        for i in 0..200_000 {
            let x = -(i as f64) * 0.0035; // 0 .. -700
            let rel = ((exp_nonpositive(x) - x.exp()) / x.exp()).abs();
            worst = worst.max(rel);
        }
        assert!(worst < 4e-16, "worst relative error {worst:e}");
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
        assert!(worst < 4e-16, "worst relative error {worst:e}");
        assert_eq!(log1p_unit(1e-300), 1e-300);
    }

    #[test]
    fn softplus_follows_torch_and_its_derivative_is_the_sigmoid() {
        for beta in [1.0, -0.9, 1.7, 0.5] {
            for i in -400..=400 {
                let h = i as f64 * 0.1;
                let (v, d) = activate(Activation::Softplus, beta, 1.0 / beta, h);
                let y = beta * h;
                let want = if y > 20.0 { h } else { (1.0 + y.exp()).ln() / beta };
                assert!((v - want).abs() <= 1e-14 * want.abs().max(1.0), "beta {beta} h {h}: {v} vs {want}");
                let want_d = if y > 20.0 { 1.0 } else { 1.0 / (1.0 + (-y).exp()) };
                assert!((d - want_d).abs() < 1e-15, "derivative at beta {beta} h {h}");
                assert_eq!(v, activate_value(Activation::Softplus, beta, 1.0 / beta, h));
            }
        }
    }
}
