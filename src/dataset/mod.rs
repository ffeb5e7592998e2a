//! The paper's datasets (docs/MODEL.md section 2) and an MPC operating-envelope preset: seeded
//! generation with the analytic vehicle, and `.npy` + JSON storage numpy can read.

mod collocation;
pub mod design;
mod error;
mod excitation;
mod generate;
#[cfg(feature = "tools")]
pub mod import;
mod preset;
mod source;
mod storage;

pub use error::DatasetError;
pub use excitation::{apply_paper_scaling, sample_inputs};
pub use generate::{Dataset, TrajectorySet, generate, generate_set};
pub use preset::{
    BLUEROV2_INPUT_HI, BLUEROV2_INPUT_LO, DatasetPreset, Excitation, InitialRanges, InputBounds, SetSpec,
    TRAJECTORY_POINTS, VelocityBox, input_bounds_from_file, reachable_velocities,
};
pub use storage::{ArrayEntry, MANIFEST_FILE, MANIFEST_FORMAT, MANIFEST_VERSION, Manifest, SetEntry, load, save};
