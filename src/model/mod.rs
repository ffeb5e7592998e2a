//! The frozen `.pinc` weight file: format, validation, encoding, and (with the `tools`
//! feature) import of PyTorch state dicts in the layout of the paper's implementation.

mod codec;
mod error;
mod format;
#[cfg(feature = "tools")]
mod import_torch;
mod summary;
mod validate;

pub use error::ModelError;
pub use format::{
    Activation, Affine, Architecture, Envelope, FORMAT_VERSION, FittedVehicle, HEADER_SIZE, HiddenLayer, HybridPhysics,
    LayerNormWeights, Linear, MAGIC, MAX_FILE_BYTES, MAX_LAYERS, MAX_WIDTH, OLDEST_READ_VERSION, PincModel, Provenance,
    SensorModel, Weights,
};
#[cfg(feature = "tools")]
pub use import_torch::import_state_dict;
pub use summary::ModelSummary;
pub use validate::{MAX_SUBSTEPS, validate};
