//! The analytic part of a hybrid model: the vehicle's RK4 step that the network corrects
//! (docs/MODEL.md section 13). In `f64` whatever precision the network computes in.

use crate::model::PincModel;
use crate::types::{Input, InputMatrix, State, StateMatrix};
use crate::vehicle::{Rk4Vehicle, VehicleParams};

/// The vehicle and its sub-steps per step, from a hybrid model's file.
#[derive(Debug, Clone, Copy)]
pub(crate) struct HybridBase {
    params: VehicleParams,
    substeps: usize,
}

impl HybridBase {
    /// The analytic part of `model`, if it is a hybrid.
    pub(crate) fn of(model: &PincModel) -> Option<Self> {
        model.hybrid.map(|h| Self { params: model.vehicle, substeps: h.substeps as usize })
    }

    /// The vehicle over a step of `dt`: the file's sub-step count, each `dt / substeps`
    /// long (the trainer's convention for every time it evaluates the model at).
    #[inline(always)]
    fn over(&self, dt: f64) -> Rk4Vehicle {
        Rk4Vehicle { params: self.params, dt, substeps: self.substeps }
    }

    /// The physics' next state in the network form.
    #[inline(always)]
    pub(crate) fn step(&self, x: &State, u: &Input, dt: f64) -> State {
        self.over(dt).step_network(x, u)
    }

    /// The physics' next state and its exact Jacobians (RK4 sensitivities).
    #[inline(always)]
    pub(crate) fn linearise(&self, x: &State, u: &Input, dt: f64) -> (State, StateMatrix, InputMatrix) {
        self.over(dt).step_with_jacobians(x, u)
    }

    /// The vehicle's coefficients.
    pub(crate) fn params(&self) -> &VehicleParams {
        &self.params
    }

    /// RK4 sub-steps per step.
    pub(crate) fn substeps(&self) -> usize {
        self.substeps
    }
}
