//! Real-time-iteration LTV-MPC, generic over the [`DiscreteModel`] interface, so the learned
//! PINC and the analytic vehicle (the "oracle") run the same controller. Its QP goes to
//! Clarabel (the reference) or to a Riccati interior-point method built for it
//! ([`QpSolver`]).
//!
//! Each sample: shift the previous input plan, roll the model out from the measured state
//! and linearise along it, overwrite the QP's data in the persistent solver, solve once,
//! apply the first input. Whatever goes wrong (a model error, a solver failure or time-out,
//! a missed deadline) the loop goes on with the shifted previous plan, clipped to the bounds.
//!
//! [`DiscreteModel`]: crate::traits::DiscreteModel

mod controller;
mod error;
mod fallback;
mod qp;
mod reference;
mod report;
mod riccati;
mod settings;

pub use controller::Mpc;
pub use error::MpcError;
pub use fallback::Fallback;
pub use qp::Weights;
pub use reference::{Horizontal, Reference};
pub use report::CycleReport;
pub use riccati::RiccatiInfo;
pub use settings::{FOUR_AXIS_POSITION_WEIGHT, MpcConfig, QpSolver};
