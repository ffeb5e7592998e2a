//! The analytic BlueROV2: the simplified 4-DOF Fossen model of docs/MODEL.md section 1, its
//! parameters, and its zero-order-hold discretisation.

mod dynamics;
#[cfg(feature = "cli")]
mod file;
mod integrator;
mod params;
#[cfg(feature = "cli")]
mod thrusters;

pub use dynamics::{
    RhsInputJacobian, RhsStateJacobian, body_accelerations, rhs, rhs_jacobian_times, rhs_jacobians, rhs_sim,
    to_network, to_simulator, wrap_angle,
};
#[cfg(feature = "cli")]
pub use file::VehicleFileError;
pub use integrator::{CONTROL_SUBSTEPS, DEFAULT_SUBSTEPS, Rk4Vehicle, rk4};
pub use params::{ParamsError, VehicleParams, terminal_speed};
#[cfg(feature = "cli")]
pub use thrusters::{Allocation, CommandUnit, Thruster, ThrusterCurve, Thrusters, standalone_thruster_tables};

#[cfg(test)]
mod tests;
