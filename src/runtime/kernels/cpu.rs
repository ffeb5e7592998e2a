//! "This CPU has AVX2 and FMA" as a value: the only way to get an [`Avx2Fma`] is to detect
//! the features, so a function that receives one may use them without further checks.
//!
//! On x86 the token is a unit struct; on every other architecture (ARM: a Raspberry Pi) it is
//! an empty enum, so no value of it exists, `Option<Avx2Fma>` is always `None` and the
//! compiler drops the AVX2 branches of the dispatch altogether.

/// Proof that the CPU running this process supports AVX2 and FMA.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Avx2Fma(());

/// Proof that the CPU running this process supports AVX2 and FMA: none can exist on this
/// architecture.
#[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Avx2Fma {}

impl Avx2Fma {
    /// The token if this CPU has AVX2 and FMA (never on other architectures, nor on 32-bit
    /// x86, whose register kernels are not written).
    pub fn detect() -> Option<Self> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            return Some(Self(()));
        }
        None
    }
}
