//! Vectors in packs of eight and the inner loops over them, generic over how a multiply-add is done so the same
//! code compiles once portably and once with AVX2 + FMA (selected at run time).
//!
//! Vectors of hidden units are stored as packs of [`PACK`] values (one AVX2 register of
//! `f32`), zero-padded, so every loop below runs over whole packs and vectorises without
//! remainder code.

use super::real::Real;

/// Values per pack.
pub(crate) const PACK: usize = 8;

/// Eight consecutive values of a vector.
pub(crate) type Pack<T> = [T; PACK];

/// Packs needed for `n` values.
pub(crate) const fn packs(n: usize) -> usize {
    n.div_ceil(PACK)
}

/// How `a * b + c` is evaluated, and how wide the registers of the code using it are.
pub(crate) trait MulAdd {
    /// Registers hold 32 bytes (AVX2) rather than 16 (baseline x86-64 SSE2).
    const WIDE_REGISTERS: bool;
    fn mul_add<T: Real>(a: T, b: T, c: T) -> T;
}

/// Separate multiply and add: any CPU.
pub(crate) struct Portable;
impl MulAdd for Portable {
    const WIDE_REGISTERS: bool = false;
    #[inline(always)]
    fn mul_add<T: Real>(a: T, b: T, c: T) -> T {
        a * b + c
    }
}

/// Fused multiply-add, in code compiled with the `avx2` and `fma` target features (reached
/// only through an [`Avx2Fma`](super::Avx2Fma) token). Elsewhere it would still be exact, but
/// a library call per operation (the kernel tests run it on every architecture).
#[cfg(any(target_arch = "x86", target_arch = "x86_64", test))]
pub(crate) struct Fused;
#[cfg(any(target_arch = "x86", target_arch = "x86_64", test))]
impl MulAdd for Fused {
    const WIDE_REGISTERS: bool = true;
    #[inline(always)]
    fn mul_add<T: Real>(a: T, b: T, c: T) -> T {
        a.mul_add(b, c)
    }
}

/// `out[p] = sum_i coef[i] * mat[i * stride + p]` for every pack `p < out.len()`: a
/// matrix-vector product whose matrix holds one row of `stride` packs per coefficient.
/// Blocks of output packs stay in registers across all coefficients.
#[inline(always)]
pub(crate) fn matvec<F: MulAdd, T: Real>(out: &mut [Pack<T>], coef: &[T], mat: &[Pack<T>], stride: usize) {
    let n = out.len();
    let mut p = 0;
    while n - p >= block_packs::<F, T>() {
        match block_packs::<F, T>() {
            4 => block::<F, T, 4>(out, coef, mat, stride, p),
            2 => block::<F, T, 2>(out, coef, mat, stride, p),
            _ => block::<F, T, 1>(out, coef, mat, stride, p),
        }
        p += block_packs::<F, T>();
    }
    if n - p >= 2 {
        block::<F, T, 2>(out, coef, mat, stride, p);
        p += 2;
    }
    if n - p == 1 {
        block::<F, T, 1>(out, coef, mat, stride, p);
    }
}

/// Packs of output kept in registers: two sets of accumulators must fit in the sixteen
/// vector registers, which hold half as much without AVX2.
pub(crate) const fn block_packs<F: MulAdd, T: Real>() -> usize {
    if F::WIDE_REGISTERS {
        T::BLOCK
    } else if T::BLOCK > 1 {
        T::BLOCK / 2
    } else {
        1
    }
}

/// One block of `B` output packs. Even and odd coefficients go to two sets of accumulators:
/// a layer is a chain of dependent multiply-adds per accumulator, and two sets halve its
/// length (the single-vector step is bound by that latency, not by throughput).
#[inline(always)]
fn block<F: MulAdd, T: Real, const B: usize>(
    out: &mut [Pack<T>],
    coef: &[T],
    mat: &[Pack<T>],
    stride: usize,
    p: usize,
) {
    // Checked once here, so that the loop below carries no bounds checks.
    assert!(p + B <= stride && coef.len() * stride <= mat.len(), "matrix block out of range");
    // Accumulators start at zero, not from `out`: loading them made LLVM split one of the
    // register blocks into scalar pieces.
    let mut even = [[T::ZERO; PACK]; B];
    let mut odd = [[T::ZERO; PACK]; B];
    let pairs = coef.chunks_exact(2);
    let last = pairs.remainder().first().map(|&c| (c, coef.len() - 1));
    for (c, rows) in pairs.zip(mat.chunks_exact(2 * stride)) {
        let (r0, r1) = rows.split_at(stride);
        for k in 0..B {
            for t in 0..PACK {
                even[k][t] = F::mul_add(c[0], r0[p + k][t], even[k][t]);
                odd[k][t] = F::mul_add(c[1], r1[p + k][t], odd[k][t]);
            }
        }
    }
    if let Some((c, i)) = last {
        let r = &mat[i * stride..(i + 1) * stride];
        for k in 0..B {
            for t in 0..PACK {
                even[k][t] = F::mul_add(c, r[p + k][t], even[k][t]);
            }
        }
    }
    for k in 0..B {
        for t in 0..PACK {
            out[p + k][t] = even[k][t] + odd[k][t];
        }
    }
}

/// [`matvec`] for `R` coefficient vectors against the same matrix (rows of a reverse pass,
/// units of a batch layer): each loaded matrix pack feeds `R` multiply-adds. The block of
/// output packs shrinks as `R` grows, so that the `R` accumulator sets still fit the
/// registers that two sets of [`matvec`] fill.
#[inline(always)]
pub(crate) fn matvec_rows<F: MulAdd, T: Real, const R: usize>(
    mut out: [&mut [Pack<T>]; R],
    coef: [&[T]; R],
    mat: &[Pack<T>],
    stride: usize,
) {
    let n = out[0].len();
    let wide = (2 * block_packs::<F, T>() / R).max(1);
    let mut p = 0;
    while n - p >= wide {
        match wide {
            4 => block_rows::<F, T, R, 4>(&mut out, coef, mat, stride, p),
            2 => block_rows::<F, T, R, 2>(&mut out, coef, mat, stride, p),
            _ => block_rows::<F, T, R, 1>(&mut out, coef, mat, stride, p),
        }
        p += wide;
    }
    if n - p >= 2 && wide > 2 {
        block_rows::<F, T, R, 2>(&mut out, coef, mat, stride, p);
        p += 2;
    }
    while p < n {
        block_rows::<F, T, R, 1>(&mut out, coef, mat, stride, p);
        p += 1;
    }
}

#[inline(always)]
fn block_rows<F: MulAdd, T: Real, const R: usize, const B: usize>(
    out: &mut [&mut [Pack<T>]; R],
    coef: [&[T]; R],
    mat: &[Pack<T>],
    stride: usize,
    p: usize,
) {
    let n = coef[0].len();
    assert!(p + B <= stride && n * stride <= mat.len(), "matrix block out of range");
    assert!(coef.iter().all(|c| c.len() == n) && out.iter().all(|o| o.len() >= p + B), "rows of unequal length");
    let mut acc = [[[T::ZERO; PACK]; B]; R];
    for (i, row) in mat.chunks_exact(stride).take(n).enumerate() {
        let c: [T; R] = std::array::from_fn(|r| coef[r][i]);
        for k in 0..B {
            for t in 0..PACK {
                for r in 0..R {
                    acc[r][k][t] = F::mul_add(c[r], row[p + k][t], acc[r][k][t]);
                }
            }
        }
    }
    for (o, a) in out.iter_mut().zip(&acc) {
        o[p..p + B].copy_from_slice(a);
    }
}

/// Sum of the lanes of a pack, as a tree (three dependent adds, not seven).
#[inline(always)]
pub(crate) fn lane_sum<T: Real>(a: Pack<T>) -> T {
    let h: [T; 4] = std::array::from_fn(|t| a[t] + a[t + 4]);
    (h[0] + h[2]) + (h[1] + h[3])
}

/// `sum_p a[p]` lane-wise.
#[inline(always)]
pub(crate) fn sum<T: Real>(a: &[Pack<T>]) -> T {
    let mut acc = [T::ZERO; PACK];
    for v in a {
        for t in 0..PACK {
            acc[t] += v[t];
        }
    }
    lane_sum(acc)
}

/// `sum_p a[p] . b[p]`.
#[inline(always)]
pub(crate) fn dot<F: MulAdd, T: Real>(a: &[Pack<T>], b: &[Pack<T>]) -> T {
    let mut acc = [T::ZERO; PACK];
    for (x, y) in a.iter().zip(b) {
        for t in 0..PACK {
            acc[t] = F::mul_add(x[t], y[t], acc[t]);
        }
    }
    lane_sum(acc)
}
