//! Why a cycle applied the shifted previous plan instead of a fresh solution.

use clarabel::solver::SolverStatus;

/// Why a sample fell back to the shifted previous plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fallback {
    /// The model's rollout or linearisation failed (non-finite state or prediction).
    Model,
    /// Clarabel did not return a solution (status attached).
    Solver(SolverStatus),
    /// The nominal rollout left the training envelope (with [`MpcConfig::envelope_fallback`](super::MpcConfig::envelope_fallback)).
    Envelope,
}

impl std::fmt::Display for Fallback {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Fallback::Model => f.write_str("model rollout or linearisation failed"),
            Fallback::Solver(status) => write!(f, "QP not solved ({status:?})"),
            Fallback::Envelope => f.write_str("nominal rollout outside the training envelope"),
        }
    }
}
