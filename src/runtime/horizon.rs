//! The output of a horizon linearisation, sized once for a horizon: the nominal
//! trajectory and every `A_k`, `B_k` along it.

use super::error::RuntimeError;
use crate::types::{Input, InputMatrix, State, StateMatrix};

/// A nominal trajectory of `N` steps and the exact linearisation along it:
/// `trajectory()[k + 1] = f(trajectory()[k], u_k)`, `a()[k] = d x_{k+1} / d x_k`,
/// `b()[k] = d x_{k+1} / d u_k`.
///
/// Filled by [`Predictor::linearise_horizon`](super::Predictor::linearise_horizon) and by
/// every [`DiscreteModel`](crate::traits::DiscreteModel); shared by the MPC.
///
/// # Memory allocation
/// `new(n)` allocates `(n + 1) * 9 + n * (81 + 36)` doubles; filling it allocates nothing.
#[derive(Debug, Clone, PartialEq)]
pub struct HorizonLinearisation {
    trajectory: Vec<State>,
    a: Vec<StateMatrix>,
    b: Vec<InputMatrix>,
}

impl HorizonLinearisation {
    /// Zeros for a horizon of `n` steps.
    pub fn new(n: usize) -> Self {
        Self {
            trajectory: vec![State::zeros(); n + 1],
            a: vec![StateMatrix::zeros(); n],
            b: vec![InputMatrix::zeros(); n],
        }
    }

    /// The number of steps `N`.
    pub fn horizon(&self) -> usize {
        self.a.len()
    }

    /// The `N + 1` states `x_0 .. x_N`.
    pub fn trajectory(&self) -> &[State] {
        &self.trajectory
    }

    /// `A_k = d x_{k+1} / d x_k` for `k < N`.
    pub fn a(&self) -> &[StateMatrix] {
        &self.a
    }

    /// `B_k = d x_{k+1} / d u_k` for `k < N`.
    pub fn b(&self) -> &[InputMatrix] {
        &self.b
    }

    /// The buffers to fill for `inputs`, for implementations of
    /// [`DiscreteModel`](crate::traits::DiscreteModel): trajectory, `A_k`, `B_k`.
    ///
    /// # Errors
    /// [`RuntimeError::HorizonMismatch`] if `inputs` is not `N` long.
    #[allow(clippy::type_complexity)] // three named buffers, documented above
    pub fn buffers_for(
        &mut self,
        inputs: &[Input],
    ) -> Result<(&mut [State], &mut [StateMatrix], &mut [InputMatrix]), RuntimeError> {
        if inputs.len() != self.horizon() {
            return Err(RuntimeError::HorizonMismatch { expected: self.horizon(), found: inputs.len() });
        }
        Ok((&mut self.trajectory, &mut self.a, &mut self.b))
    }
}
