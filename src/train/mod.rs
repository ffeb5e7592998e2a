//! The PINC trainer on burn: the network with its time tangent, the physics right-hand
//! side in tensor ops, and freezing into the `.pinc` format the runtime loads.

mod grad_combine;
mod net;
mod physics;

pub use grad_combine::{GradCombine, clip_global_norm, combine};
pub use net::{LAYER_NORM_EPS, PincNet, Prediction};
pub use physics::rhs;

#[cfg(test)]
mod tests;
