//! The dataset presets and their storage, and the evaluation metrics.

#[path = "../common/mod.rs"]
mod common;

mod dataset;
mod eval_rollouts;
mod identify;
mod import;
mod import_ros2;
