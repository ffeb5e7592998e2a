//! # pinc — a physics-informed neural network with control for a BlueROV2
//!
//! The vehicle is the simplified 4-DOF Fossen model (see [`vehicle`]) with the state in the
//! network form `x = [x, y, z, cos psi, sin psi, u, v, w, r]` and the input
//! `u = [X, Y, Z, Mz]` held over each sample period. A PINC predicts
//! `x_hat(t) = x(0) + N([x(0), u(0), t])`; fed back on itself it rolls out long horizons.
//!
//! The embeddable core (`vehicle`, `model`, `runtime`) builds with
//! `--no-default-features`; `cli` adds vehicle files and plots, `mpc` (the default) the
//! Clarabel MPC, the closed loop and its MCAP logs, `data` dataset generation,
//! storage and evaluation, `tools` log import and the `pinc` command line, `train` the burn trainer.

#[cfg(feature = "mpc")]
pub mod closed_loop;
pub mod estimation;
#[cfg(all(feature = "train", feature = "vehicle"))]
pub mod fit;
pub mod model;
#[cfg(feature = "mpc")]
pub mod mpc;
#[cfg(feature = "mpc")]
pub mod pilot;
pub mod runtime;
#[cfg(feature = "train")]
pub mod train;
pub mod traits;
pub mod types;
pub mod vehicle;

#[cfg(feature = "cli")]
pub mod broken_pipe;
#[cfg(feature = "data")]
pub mod dataset;
#[cfg(feature = "data")]
pub mod eval;
#[cfg(feature = "tools")]
pub mod identify;
#[cfg(feature = "vehicle")]
pub mod link;
#[cfg(feature = "cli")]
pub mod plot;
#[cfg(feature = "vehicle")]
pub mod serve;
#[cfg(feature = "cli")]
pub mod trajectory_csv;
#[cfg(feature = "vehicle")]
pub mod vehicle_actions;

pub use types::*;

/// The README's code blocks, compiled and run by `cargo test` so the README cannot drift
/// from the API.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
