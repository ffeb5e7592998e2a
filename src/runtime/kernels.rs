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
/// accumulated in registers (four AVX2 registers per block) across all coefficients, so
/// `out` is loaded and stored once.
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
        let mut acc: [T; B] = out[r..r + B].try_into().expect("block");
        for (i, &c) in coef.iter().enumerate() {
            let m: &[T; B] = mat[i * stride + r..i * stride + r + B].try_into().expect("block");
            for t in 0..B {
                acc[t] = F::mul_add(c, m[t], acc[t]);
            }
        }
        out[r..r + B].copy_from_slice(&acc);
        r += B;
    }
    r
}

/// Lanes of the partial sums in [`sum`] and [`dot`]: a float sum in one accumulator is a
/// serial chain; eight independent ones vectorise.
const PARTIALS: usize = 8;

/// `sum_i a[i]`.
#[inline(always)]
pub(crate) fn sum<T: Real>(a: &[T]) -> T {
    let mut acc = [T::ZERO; PARTIALS];
    let mut chunks = a.chunks_exact(PARTIALS);
    for c in &mut chunks {
        for t in 0..PARTIALS {
            acc[t] += c[t];
        }
    }
    chunks.remainder().iter().copied().sum::<T>() + acc.iter().copied().sum::<T>()
}

/// `sum_i a[i] * b[i]`.
#[inline(always)]
pub(crate) fn dot<F: MulAdd, T: Real>(a: &[T], b: &[T]) -> T {
    let mut acc = [T::ZERO; PARTIALS];
    let mut ca = a.chunks_exact(PARTIALS);
    let mut cb = b.chunks_exact(PARTIALS);
    for (x, y) in (&mut ca).zip(&mut cb) {
        for t in 0..PARTIALS {
            acc[t] = F::mul_add(x[t], y[t], acc[t]);
        }
    }
    let tail: T = ca.remainder().iter().zip(cb.remainder()).map(|(&x, &y)| x * y).sum();
    tail + acc.iter().copied().sum::<T>()
}
