//! The dataset presets and their storage, and the evaluation metrics.
#![cfg(feature = "tools")]

#[path = "../common/mod.rs"]
mod common;

mod ardupilot_logs;
mod dataset;
mod estimated_start;
mod eval_rollouts;
mod identify;
mod import;
mod import_mapped;
mod import_ros2;
mod resample;
