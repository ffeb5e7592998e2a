//! The inner loops of the runtime, generic over how a multiply-add is done so the same
//! code compiles once portably and once with AVX2 + FMA (selected at run time).

/// How `a * b + c` is evaluated.
pub(crate) trait MulAdd {
    fn mul_add(a: f64, b: f64, c: f64) -> f64;
}

/// Separate multiply and add: any CPU.
pub(crate) struct Portable;
impl MulAdd for Portable {
    #[inline(always)]
    fn mul_add(a: f64, b: f64, c: f64) -> f64 {
        a * b + c
    }
}

/// Fused multiply-add: only inside functions compiled with the `fma` target feature.
pub(crate) struct Fused;
impl MulAdd for Fused {
    #[inline(always)]
    fn mul_add(a: f64, b: f64, c: f64) -> f64 {
        a.mul_add(b, c)
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
/// product whose matrix is stored one contiguous row per coefficient. Blocks of output
/// are accumulated in registers across all coefficients, so `out` is loaded and stored once.
#[inline(always)]
pub(crate) fn accumulate<F: MulAdd>(out: &mut [f64], coef: &[f64], mat: &[f64], stride: usize) {
    let n = out.len();
    let mut r = 0;
    r = block::<F, 16>(out, coef, mat, stride, r, n);
    r = block::<F, 8>(out, coef, mat, stride, r, n);
    r = block::<F, 4>(out, coef, mat, stride, r, n);
    block::<F, 1>(out, coef, mat, stride, r, n);
}

#[inline(always)]
fn block<F: MulAdd, const B: usize>(
    out: &mut [f64],
    coef: &[f64],
    mat: &[f64],
    stride: usize,
    mut r: usize,
    n: usize,
) -> usize {
    while r + B <= n {
        let mut acc: [f64; B] = out[r..r + B].try_into().expect("block");
        for (i, &c) in coef.iter().enumerate() {
            let m: &[f64; B] = mat[i * stride + r..i * stride + r + B].try_into().expect("block");
            for t in 0..B {
                acc[t] = F::mul_add(c, m[t], acc[t]);
            }
        }
        out[r..r + B].copy_from_slice(&acc);
        r += B;
    }
    r
}
