//! The per-thread scratch memory of a [`Predictor`]'s single-trajectory calls.

use super::envelope::EnvelopeStatus;
use super::kernels::{NetScratch, Real};
use super::{Predictor, RuntimeError};

/// Scratch memory for one thread's calls into a [`Predictor`].
///
/// # Memory allocation
/// `Workspace::new` allocates about `(3 L + 1 + 2 * 9) * width + inputs + L` floats for `L`
/// hidden layers (widths rounded up to packs of 8); no call that takes a workspace
/// allocates afterwards.
#[derive(Debug, Clone)]
pub struct Workspace<T: Real = f32> {
    /// The network's buffers.
    pub(crate) net: NetScratch<T>,
    /// Envelope exits of the last call.
    pub(crate) envelope: EnvelopeStatus,
}

impl<T: Real> Workspace<T> {
    /// Sizes every buffer for `p`.
    pub fn new(p: &Predictor<T>) -> Self {
        Self { net: NetScratch::new(&p.net), envelope: EnvelopeStatus::default() }
    }

    /// Envelope exits seen during the last `step`, `rollout` or linearisation call.
    pub fn envelope_status(&self) -> EnvelopeStatus {
        self.envelope
    }

    /// Refuses a workspace sized for another network (its buffers would be too small or
    /// laid out for other widths), then clears the envelope record for a new call.
    #[inline(always)]
    pub(crate) fn start_call(&mut self, p: &Predictor<T>) -> Result<(), RuntimeError> {
        if self.net.shape != p.net.shape() {
            return Err(RuntimeError::WorkspaceMismatch { what: "workspace" });
        }
        // Only when something was recorded: the record is larger than a step's arithmetic.
        if !self.envelope.inside() {
            self.envelope = EnvelopeStatus::default();
        }
        Ok(())
    }
}
