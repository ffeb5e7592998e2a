//! The two precisions the runtime computes in. `f32` is the fast path (eight lanes per AVX2
//! register, the precision the network was trained in); `f64` is the reference path whose
//! Jacobians are checked against finite differences.

use std::fmt::Debug;
use std::iter::Sum;
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub};

mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for f64 {}
}

/// A floating-point type the runtime can compute in: `f32` or `f64`.
pub trait Real:
    sealed::Sealed
    + Copy
    + Debug
    + Default
    + Send
    + Sync
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + MulAssign
    + Sum
    + 'static
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// Packs of output the matrix kernels keep in registers (two sets of accumulators of
    /// this many packs must fit in the sixteen AVX2 registers).
    #[doc(hidden)]
    const BLOCK: usize;
    /// Rounds an `f64` to this type.
    fn from_f64(v: f64) -> Self;
    /// Widens to `f64`.
    fn to_f64(self) -> f64;
    /// Fused `self * a + b`.
    fn mul_add(self, a: Self, b: Self) -> Self;
    /// IEEE maximum.
    fn max(self, o: Self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Hyperbolic tangent.
    fn tanh(self) -> Self;
    /// `Some(x)` where `Self` is `f32`, `None` otherwise: how the kernels select the `f32`-only
    /// register forward pass at compile time, without a type-id check or a cast.
    #[doc(hidden)]
    fn as_f32<C: Family>(x: C::Of<'_, Self>) -> Option<C::Of<'_, f32>>;
    /// `exp(x)` for `x <= 0`, branch-free; `mul_add` says how multiply-adds are done.
    #[doc(hidden)]
    fn exp_nonpositive(x: Self, mul_add: impl Fn(Self, Self, Self) -> Self) -> Self;
    /// `ln(1 + e)` for `e` in `[0, 1]`, branch-free.
    #[doc(hidden)]
    fn log1p_unit(e: Self, mul_add: impl Fn(Self, Self, Self) -> Self) -> Self;
}

/// A family of types parameterised by the precision (for example "a network and its
/// scratch memory in precision `T`"), so that [`Real::as_f32`] can hand the `f32` member
/// of the family to code that exists for `f32` only.
#[doc(hidden)]
pub trait Family {
    /// The member in precision `T`.
    type Of<'a, T: Real>;
}

/// `1 / n!`.
const fn inv_factorial(n: usize) -> f64 {
    let mut f = 1.0;
    let mut i = 2;
    while i <= n {
        f *= i as f64;
        i += 1;
    }
    1.0 / f
}

/// `1 / (2 n + 1)`.
const fn inv_odd(n: usize) -> f64 {
    1.0 / (2 * n + 1) as f64
}

macro_rules! real_impl {
    ($t:ty, $bits:ty, $mant:expr, $bias:expr, $min_x:expr, exp($r:ident, $ma:ident) $exp_poly:block, $ln2_hi:expr, $ln2_lo:expr, $block:expr, log1p($e:ident, $mul_add:ident) $log1p:block, as_f32($x:ident) $as_f32:expr) => {
        impl Real for $t {
            #[inline(always)]
            fn as_f32<C: Family>($x: C::Of<'_, Self>) -> Option<C::Of<'_, f32>> {
                $as_f32
            }
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const BLOCK: usize = $block;
            #[inline(always)]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn mul_add(self, a: Self, b: Self) -> Self {
                self.mul_add(a, b)
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                self.max(o)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                self.abs()
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                self.sqrt()
            }
            #[inline(always)]
            fn tanh(self) -> Self {
                self.tanh()
            }
            #[inline(always)]
            fn exp_nonpositive(x: Self, mul_add: impl Fn(Self, Self, Self) -> Self) -> Self {
                // exp(x) = 2^k exp(r), k = round(x / ln 2), |r| <= ln2 / 2; rounding by adding
                // 1.5 * 2^mantissa leaves k in the low bits. The clamp keeps 2^k normal.
                const MAGIC: $t = 1.5 * ((1 as $bits) << $mant) as $t;
                let x = x.max($min_x);
                let t = mul_add(x, std::f64::consts::LOG2_E as $t, MAGIC);
                let k = t - MAGIC;
                let $r = mul_add(-k, $ln2_lo, mul_add(-k, $ln2_hi, x));
                let $ma = mul_add;
                let p = $exp_poly;
                let ki = t.to_bits().wrapping_sub(MAGIC.to_bits());
                let scale = <$t>::from_bits(ki.wrapping_add($bias) << $mant);
                p * scale
            }
            #[inline(always)]
            fn log1p_unit($e: Self, $mul_add: impl Fn(Self, Self, Self) -> Self) -> Self $log1p
        }
    };
}

// f64: Taylor series (exp to degree 13, atanh to s^23) reach ~1e-17.
real_impl!(
    f64,
    u64,
    52,
    1023,
    -708.0,
    exp(r, mul_add) {
        // Taylor polynomial to degree 13 as two Horner chains in r^2 (half the depth).
        const EVEN: [f64; 7] =
            [inv_factorial(12), inv_factorial(10), inv_factorial(8), inv_factorial(6), inv_factorial(4), inv_factorial(2), 1.0];
        const ODD: [f64; 7] =
            [inv_factorial(13), inv_factorial(11), inv_factorial(9), inv_factorial(7), inv_factorial(5), inv_factorial(3), 1.0];
        let r2 = r * r;
        let (mut pe, mut po) = (0.0, 0.0);
        for c in EVEN {
            pe = mul_add(pe, r2, c);
        }
        for c in ODD {
            po = mul_add(po, r2, c);
        }
        mul_add(po, r, pe)
    },
    6.931_471_803_691_238e-1,
    1.908_214_929_270_587_7e-10,
    2,
    log1p(e, mul_add) {
        // ln(1 + e) = j ln2 + 2 atanh(s), 1 + e = 2^j m, m in [sqrt(1/2), sqrt 2],
        // s = (m - 1)/(m + 1): s = e/(2 + e) below sqrt 2 (no cancellation for small e),
        // else m = (1 + e)/2 and s = (e - 1)/(e + 3); |s| <= 0.172.
        const ATANH: &[f64] = &[
            inv_odd(11),
            inv_odd(10),
            inv_odd(9),
            inv_odd(8),
            inv_odd(7),
            inv_odd(6),
            inv_odd(5),
            inv_odd(4),
            inv_odd(3),
            inv_odd(2),
            inv_odd(1),
            1.0,
        ];
        let high = e > std::f64::consts::SQRT_2 - 1.0;
        let (num, den, j) = if high { (e - 1.0, e + 3.0, std::f64::consts::LN_2) } else { (e, 2.0 + e, 0.0) };
        let s = num / den;
        let s2 = s * s;
        let mut p = 0.0;
        for &c in ATANH {
            p = mul_add(p, s2, c);
        }
        mul_add(2.0 * s, p, j)
    },
    as_f32(_x) None
);
// f32: polynomials fitted for f32 accuracy, evaluated with short dependency chains (shared
// with the register kernel, which evaluates the same operations eight lanes at a time).

/// `exp(r)` on `|r| <= ln2 / 2`: degree 6, fitted for relative error (2e-9 before rounding).
pub(crate) const F32_EXP: [f32; 7] =
    [1.0, 1.0, 0.499_999_9, 0.166_664_2, 0.041_668_225, 0.008_374_816, 0.001_383_683_5];
/// `ln 2` split so that `k ln2_hi` is exact for the `k` an `f32` exponent can take.
pub(crate) const F32_LN2: (f32, f32) = (6.931_457_5e-1, 1.428_606_8e-6);
/// Below this `exp` would leave the normal range; arguments are clamped to it.
pub(crate) const F32_EXP_MIN: f32 = -87.0;
/// `ln(1 + e) = e P(e)` on `[0, 1]`: `P` of degree 8, fitted for relative error (2e-8 before
/// rounding).
pub(crate) const F32_LOG1P: [f32; 9] = [
    0.999_999_94,
    -0.499_994_93,
    0.333_190_98,
    -0.248_429_85,
    0.191_060_14,
    -0.136_632_58,
    0.078_226_045,
    -0.029_505_279,
    0.005_232_701,
];
real_impl!(
    f32,
    u32,
    23,
    127,
    F32_EXP_MIN,
    exp(r, mul_add) {
        // Estrin's scheme: a chain of four operations after r instead of seven.
        const C: [f32; 7] = F32_EXP;
        let r2 = r * r;
        let r4 = r2 * r2;
        let lo = mul_add(mul_add(C[3], r, C[2]), r2, r + C[0]);
        let hi = mul_add(C[6], r2, mul_add(C[5], r, C[4]));
        mul_add(hi, r4, lo)
    },
    F32_LN2.0,
    F32_LN2.1,
    4,
    log1p(e, mul_add) {
        // ln(1 + e) = e P(e) by Estrin's scheme: no division and a dependency chain of five
        // operations instead of a Horner chain of nine. Every hidden unit's softplus runs this.
        const C: [f32; 9] = F32_LOG1P;
        let e2 = e * e;
        let e4 = e2 * e2;
        let q0 = mul_add(C[1], e, C[0]);
        let q1 = mul_add(C[3], e, C[2]);
        let q2 = mul_add(C[5], e, C[4]);
        let q3 = mul_add(C[7], e, C[6]);
        let r0 = mul_add(q1, e2, q0);
        let r1 = mul_add(q3, e2, q2);
        let r1 = mul_add(C[8], e4, r1);
        e * mul_add(r1, e4, r0)
    },
    as_f32(x) Some(x)
);
