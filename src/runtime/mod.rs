//! The allocation-free inference core: a frozen PINC steps, rolls out (one trajectory or a
//! batch) and linearises exactly along a horizon. Knows nothing of burn.
//!
//! What a user meets is at this level (the predictor, its workspaces, the horizon output,
//! the envelope record and the errors); the arithmetic is in `kernels`.

/// `$name`: a safe method of `Predictor` taking the [`Avx2Fma`](kernels::Avx2Fma) token,
/// which runs `$generic::<Fused>` inside a function compiled for AVX2 + FMA. Elsewhere than
/// on x86 the token has no value, and the method only says so to the compiler: the feature
/// names would not compile there, and the dispatch's AVX2 branch is dead.
macro_rules! avx2_entry {
    ($name:ident => $generic:ident ($($arg:ident: $ty:ty),*)) => {
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        #[inline(always)]
        #[allow(clippy::too_many_arguments)] // the generic body's arguments and the token
        fn $name(&self, cpu: super::kernels::Avx2Fma, $($arg: $ty),*) -> Result<(), RuntimeError> {
            #[target_feature(enable = "avx2,fma")]
            fn compiled<T: super::kernels::Real>(p: &super::Predictor<T>, $($arg: $ty),*) -> Result<(), RuntimeError> {
                p.$generic::<super::kernels::Fused>($($arg),*)
            }
            let _ = cpu;
            // SAFETY: `cpu` proves that the CPU has AVX2 and FMA.
            unsafe { compiled(self, $($arg),*) }
        }

        #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
        #[inline(always)]
        #[allow(clippy::too_many_arguments, unused_variables)] // the x86 entry's signature
        fn $name(&self, cpu: super::kernels::Avx2Fma, $($arg: $ty),*) -> Result<(), RuntimeError> {
            match cpu {}
        }
    };
}

mod batch;
mod calls;
mod envelope;
mod error;
mod horizon;
mod kernels;
mod output_map;
mod predictor;

pub use batch::{BatchWorkspace, LANES};
pub use envelope::{EnvelopeExit, EnvelopeStatus, HEADING_TOLERANCE, HeadingDrift, Quantity};
pub use error::RuntimeError;
pub(crate) use error::{check_input, check_state};
pub use horizon::HorizonLinearisation;
pub use kernels::{Real, SOFTPLUS_THRESHOLD};
pub use predictor::{Predictor, Workspace};
