//! Errors of the runtime's hot calls: bad input is refused, never turned into garbage.

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
    /// The time step is not a positive finite number.
    #[error("dt = {0} is not a positive finite number of seconds")]
    BadTimeStep(f64),
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
