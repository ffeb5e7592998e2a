//! The PINC trainer on burn: the network with its time tangent, the physics right-hand
//! side in tensor ops, the five losses, gradient combination, and the training loop that
//! freezes the best weights into the `.pinc` format the runtime loads.

mod config;
pub mod curves;
mod grad_combine;
mod hybrid;
mod losses;
mod members;
mod net;
mod physics;
mod trainer;

pub use config::{Backend, LossKind, LrSchedule, TrainConfig};
pub use grad_combine::{GradCombine, clip_global_norm, coefficients, combine, weighted_sum};
pub use hybrid::{Hybrid, physics_step};
pub use losses::{Batch, RolloutBatch, joint_losses, loss};
pub use members::{MembersOutcome, member_seed, train_members};
pub use net::{LAYER_NORM_EPS, PincNet, Prediction};
pub use physics::rhs;
pub use trainer::{EpochRecord, StopReason, TrainError, TrainOutcome, device, envelope_of, train};

/// Reads a tensor back as f32, whatever float dtype the device computes in.
pub(crate) fn to_f32<const D: usize>(t: burn::prelude::Tensor<D>) -> Vec<f32> {
    t.try_into_vec_as::<f32>().expect("float tensor")
}

#[cfg(test)]
mod tests;
