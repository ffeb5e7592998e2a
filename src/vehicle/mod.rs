//! The analytic BlueROV2: the simplified 4-DOF Fossen model of docs/MODEL.md section 1, its
//! parameters, and its zero-order-hold discretisation.

mod dynamics;
mod integrator;
mod params;

pub use dynamics::{
    RhsInputJacobian, RhsStateJacobian, rhs, rhs_jacobians, rhs_sim, to_network, to_simulator, wrap_angle,
};
pub use integrator::{DEFAULT_SUBSTEPS, Rk4Vehicle, rk4};
pub use params::{VehicleParams, terminal_speed};

#[cfg(test)]
mod tests;
