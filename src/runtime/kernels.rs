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

/// `y += a * x`.
#[inline(always)]
pub(crate) fn axpy<F: MulAdd>(y: &mut [f64], a: f64, x: &[f64]) {
    for (y, &x) in y.iter_mut().zip(x) {
        *y = F::mul_add(a, x, *y);
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
