//! Errors of the runtime's hot calls: bad input is refused, never turned into garbage.

use crate::types::{Input, State};

/// Why a step, rollout or linearisation was refused or failed.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum RuntimeError {
    /// A state component is NaN or infinite.
    #[error("state[{index}] = {value} is not finite (step {step})")]
    NonFiniteState {
        /// Step of the rollout (0 for the initial state).
        step: usize,
        /// Component index in the 9-state.
        index: usize,
        /// The value.
        value: f64,
    },
    /// An input component is NaN or infinite.
    #[error("input[{index}] = {value} is not finite (step {step})")]
    NonFiniteInput {
        /// Step of the rollout.
        step: usize,
        /// Component index.
        index: usize,
        /// The value.
        value: f64,
    },
    /// The model produced a non-finite prediction from finite arguments.
    #[error("the model's prediction at step {step} is not finite")]
    NonFiniteOutput {
        /// Step of the rollout.
        step: usize,
    },
    /// In a batch rollout, some trajectories' predictions stopped being finite (from finite
    /// arguments). The other trajectories are complete; each diverged one holds its states
    /// up to the last finite one and NaN after it.
    #[error("{count} trajectories of the batch diverged (the first found: trajectory {trajectory} at step {step})")]
    BatchDiverged {
        /// How many trajectories diverged.
        count: usize,
        /// The first found: lanes go in blocks of 32 trajectories, each block step by step.
        trajectory: usize,
        /// The step whose prediction was not finite.
        step: usize,
    },
    /// The time step is not a positive finite number.
    #[error("dt = {0} is not a positive finite number of seconds")]
    BadTimeStep(f64),
    /// A linearisation output made for another horizon.
    #[error("horizon linearisation sized for {expected} steps, given {found} inputs")]
    HorizonMismatch {
        /// The horizon the output was made for.
        expected: usize,
        /// Inputs given.
        found: usize,
    },
    /// A workspace made for a predictor with another network shape.
    #[error("{what} was made for another predictor (its buffers are sized for a different network)")]
    WorkspaceMismatch {
        /// Which workspace.
        what: &'static str,
    },
    /// Buffers of the wrong length were passed.
    #[error("{what}: length {found}, expected {expected}")]
    LengthMismatch {
        /// Which buffer.
        what: &'static str,
        /// Required length.
        expected: usize,
        /// Given length.
        found: usize,
    },
}

/// Refuses a time step that is not a positive finite number.
pub(crate) fn check_dt(dt: f64) -> Result<(), RuntimeError> {
    if dt.is_finite() && dt > 0.0 { Ok(()) } else { Err(RuntimeError::BadTimeStep(dt)) }
}

/// Refuses a NaN or infinite state component.
pub(crate) fn check_state(step: usize, x: &State) -> Result<(), RuntimeError> {
    match x.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(RuntimeError::NonFiniteState { step, index, value: x[index] }),
        None => Ok(()),
    }
}

/// Refuses a NaN or infinite input component.
pub(crate) fn check_input(step: usize, u: &Input) -> Result<(), RuntimeError> {
    match u.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(RuntimeError::NonFiniteInput { step, index, value: u[index] }),
        None => Ok(()),
    }
}

/// Refuses a buffer of the wrong length.
pub(crate) fn check_len(what: &'static str, expected: usize, found: usize) -> Result<(), RuntimeError> {
    if expected == found { Ok(()) } else { Err(RuntimeError::LengthMismatch { what, expected, found }) }
}
