//! The inner loops of the runtime, generic over how a multiply-add is done so the same
//! code compiles once portably and once with AVX2 + FMA (selected at run time).

use super::real::Real;

/// How `a * b + c` is evaluated.
pub(crate) trait MulAdd {
    fn mul_add<T: Real>(a: T, b: T, c: T) -> T;
}

/// Separate multiply and add: any CPU.
pub(crate) struct Portable;
impl MulAdd for Portable {
    #[inline(always)]
    fn mul_add<T: Real>(a: T, b: T, c: T) -> T {
        a * b + c
    }
}

/// Fused multiply-add: only inside functions compiled with the `fma` target feature.
pub(crate) struct Fused;
impl MulAdd for Fused {
    #[inline(always)]
    fn mul_add<T: Real>(a: T, b: T, c: T) -> T {
        a.fma(b, c)
    }
}

/// Whether this CPU can run the AVX2 + FMA kernels.
pub(crate) fn fused_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `out[r] += sum_i coef[i] * mat[i * stride + r]` for `r < out.len()`: a matrix-vector
/// product whose matrix is stored one contiguous row per coefficient. Blocks of output are
/// accumulated in registers across all coefficients (two interleaved sets, even and odd
/// coefficients, to hide the multiply-add latency), so `out` is loaded and stored once.
#[inline(always)]
pub(crate) fn accumulate<F: MulAdd, T: Real>(out: &mut [T], coef: &[T], mat: &[T], stride: usize) {
    let n = out.len();
    let mut r = 0;
    if T::WIDE_BLOCK {
        r = block::<F, T, 32>(out, coef, mat, stride, r, n);
    }
    r = block::<F, T, 16>(out, coef, mat, stride, r, n);
    r = block::<F, T, 8>(out, coef, mat, stride, r, n);
    r = block::<F, T, 4>(out, coef, mat, stride, r, n);
    block::<F, T, 1>(out, coef, mat, stride, r, n);
}

#[inline(always)]
fn block<F: MulAdd, T: Real, const B: usize>(
    out: &mut [T],
    coef: &[T],
    mat: &[T],
    stride: usize,
    mut r: usize,
    n: usize,
) -> usize {
    while r + B <= n {
        let mut even: [T; B] = out[r..r + B].try_into().expect("block");
        let mut odd = [T::ZERO; B];
        let pairs = coef.len() / 2;
        for p in 0..pairs {
            let (i, c0, c1) = (2 * p, coef[2 * p], coef[2 * p + 1]);
            let m0: &[T; B] = mat[i * stride + r..i * stride + r + B].try_into().expect("block");
            let m1: &[T; B] = mat[(i + 1) * stride + r..(i + 1) * stride + r + B].try_into().expect("block");
            for t in 0..B {
                even[t] = F::mul_add(c0, m0[t], even[t]);
                odd[t] = F::mul_add(c1, m1[t], odd[t]);
            }
        }
        if coef.len() % 2 == 1 {
            let i = coef.len() - 1;
            let m: &[T; B] = mat[i * stride + r..i * stride + r + B].try_into().expect("block");
            for t in 0..B {
                even[t] = F::mul_add(coef[i], m[t], even[t]);
            }
        }
        for t in 0..B {
            out[r + t] = even[t] + odd[t];
        }
        r += B;
    }
    r
}
