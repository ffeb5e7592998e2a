//! A hybrid model's physics in the trainer (docs/MODEL.md section 13). The step is computed
//! on the host in `f64` by the runtime's own integrator, so that training and the runtime
//! agree on the physics exactly, and enters the graph as a constant plus the product of its
//! RK4 sensitivity with the state's deviation from a detached copy of itself: the value is
//! the physics' step, the gradient (where the state depends on the weights, in a rollout)
//! is the step's exact Jacobian.

use super::to_f32;
use crate::model::HybridPhysics;
use crate::types::{Input, NU, NX, State};
use crate::vehicle::{Rk4Vehicle, VehicleParams};
use burn::prelude::*;
use rayon::prelude::*;

/// A hybrid's analytic part in the form its file keeps: the vehicle and how its step is
/// integrated (and whether the correction is anchored at rest).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hybrid {
    /// The vehicle whose step the network corrects.
    pub vehicle: VehicleParams,
    /// Its sub-steps and the anchoring.
    pub physics: HybridPhysics,
}

impl Hybrid {
    /// The vehicle's integrator over a step of `dt`.
    pub fn over(&self, dt: f64) -> Rk4Vehicle {
        Rk4Vehicle { params: self.vehicle, dt, substeps: self.physics.substeps as usize }
    }
}

/// `Phi_t(x, u)` per row: the hybrid's vehicle with its sub-step count over each row's `t`; with
/// `tracked`, the gradient flows into `x` through the step's Jacobian (`x` is then a
/// prediction, not data).
///
/// # Shapes
/// - `x`: `[N, 9]`, `u`: `[N, 4]`, `t`: `[N, 1]`; returns `[N, 9]`
pub fn physics_step(hybrid: &Hybrid, x: Tensor<2>, u: Tensor<2>, t: Tensor<2>, tracked: bool) -> Tensor<2> {
    let device = x.device();
    let [n, _] = x.dims();
    let (xs, us, ts) = (to_f32(x.clone().detach()), to_f32(u), to_f32(t));
    let row = |i: usize| {
        let xi = State::from_fn(|c, _| f64::from(xs[i * NX + c]));
        let ui = Input::from_fn(|c, _| f64::from(us[i * NU + c]));
        (hybrid.over(f64::from(ts[i])), xi, ui)
    };
    if !tracked {
        let next: Vec<f32> = (0..n)
            .into_par_iter()
            .flat_map_iter(|i| {
                let (v, xi, ui) = row(i);
                v.step_network(&xi, &ui).iter().map(|&c| c as f32).collect::<Vec<_>>()
            })
            .collect();
        return Tensor::from_data(TensorData::new(next, [n, NX]), &device);
    }
    let rows: Vec<(Vec<f32>, Vec<f32>)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let (v, xi, ui) = row(i);
            let (next, a, _) = v.step_with_jacobians(&xi, &ui);
            // Row-major: a[(r, c)] at r * 9 + c.
            let jac = (0..NX * NX).map(|k| a[(k / NX, k % NX)] as f32).collect();
            (next.iter().map(|&c| c as f32).collect(), jac)
        })
        .collect();
    let (next, jac): (Vec<Vec<f32>>, Vec<Vec<f32>>) = rows.into_iter().unzip();
    let value = Tensor::<2>::from_data(TensorData::new(next.concat(), [n, NX]), &device);
    let jac = Tensor::<3>::from_data(TensorData::new(jac.concat(), [n, NX, NX]), &device);
    // Zero in value; its gradient is d Phi / d x applied to the gradient arriving here.
    let deviation = (x.clone() - x.detach()).unsqueeze_dim::<3>(1); // [N, 1, 9]
    value + (jac * deviation).sum_dim(2).reshape([n, NX])
}
