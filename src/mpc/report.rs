//! What one control cycle did: the input, its saturation, any fallback, the solver's outcome
//! and where the time went.

use super::fallback::Fallback;
use crate::runtime::EnvelopeStatus;
use crate::types::{Input, NU};
use clarabel::solver::SolverStatus;

/// What one control cycle did.
#[derive(Debug, Clone, PartialEq)]
pub struct CycleReport {
    /// The input to apply.
    pub input: Input,
    /// Channels of `input` at a bound.
    pub saturated: [bool; NU],
    /// Set when the shifted previous plan was applied instead of a fresh solution.
    pub fallback: Option<Fallback>,
    /// Training-envelope exits along the nominal rollout (always inside for a model
    /// without an envelope).
    pub envelope: EnvelopeStatus,
    /// Clarabel's status (`Unsolved` when the model failed first).
    pub status: SolverStatus,
    /// Interior-point iterations.
    pub iterations: u32,
    /// Objective of the QP (deviation form, without constant terms).
    pub objective: f64,
    /// Rollout and linearisation (µs).
    pub linearise_us: f64,
    /// Writing the new data into the solver (µs).
    pub update_us: f64,
    /// Clarabel's solve (µs).
    pub solve_us: f64,
    /// The whole cycle (µs).
    pub cycle_us: f64,
    /// The cycle took longer than the deadline.
    pub deadline_missed: bool,
}
