//! The allocation-free inference core: a frozen PINC steps, rolls out (one trajectory or a
//! batch) and linearises exactly along a horizon. Knows nothing of burn.

mod activation;
mod batch;
mod calls;
mod envelope;
mod error;
mod fold;
mod kernels;
mod network;
mod predictor;
mod real;
#[cfg(target_arch = "x86_64")]
mod registers;

pub use activation::SOFTPLUS_THRESHOLD;
pub use batch::{BatchWorkspace, LANES};
pub use envelope::{EnvelopeExit, EnvelopeStatus, Quantity};
pub use error::RuntimeError;
pub(crate) use error::{check_input, check_len, check_state};
pub use predictor::{Predictor, Workspace};
pub use real::Real;
