//! "This CPU has AVX2 and FMA" as a value: the only way to get an [`Avx2Fma`] is to detect
//! the features, so a function that receives one may use them without further checks.

/// Proof that the CPU running this process supports AVX2 and FMA.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Avx2Fma(());

impl Avx2Fma {
    /// The token if this CPU has AVX2 and FMA (never on other architectures).
    pub fn detect() -> Option<Self> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            return Some(Self(()));
        }
        None
    }
}
