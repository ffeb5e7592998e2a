//! The allocation-free inference core: a frozen PINC steps, rolls out (one trajectory or a
//! batch) and linearises exactly along a horizon. Knows nothing of burn.
//!
//! What a user meets is at this level (the predictor, its workspaces, the horizon output,
//! the envelope record and the errors); the arithmetic is in `kernels`.

mod batch;
mod calls;
mod envelope;
mod error;
mod horizon;
mod kernels;
mod output_map;
mod predictor;

pub use batch::{BatchWorkspace, LANES};
pub use envelope::{EnvelopeExit, EnvelopeStatus, Quantity};
pub use error::RuntimeError;
pub(crate) use error::{check_input, check_state};
pub use horizon::HorizonLinearisation;
pub use kernels::{Real, SOFTPLUS_THRESHOLD};
pub use predictor::{Predictor, Workspace};
