//! Fixed-size types shared by every module, so public APIs never take bare arrays.

use nalgebra::{SMatrix, SVector};

/// Length of the network-form state `[x, y, z, cos psi, sin psi, u, v, w, r]`.
pub const NX: usize = 9;
/// Length of the simulator-form state `[x, y, z, psi, u, v, w, r]`.
pub const NS: usize = 8;
/// Length of the input `[X, Y, Z, Mz]` (N, N, N, N m).
pub const NU: usize = 4;
/// The paper's sample period (s).
pub const DEFAULT_DT: f64 = 0.08;

/// Network-form state `[x, y, z, cos psi, sin psi, u, v, w, r]` (m, -, -, m/s, rad/s).
pub type State = SVector<f64, NX>;
/// Simulator-form state `[x, y, z, psi, u, v, w, r]` (m, rad, m/s, rad/s).
pub type SimState = SVector<f64, NS>;
/// Input `[X, Y, Z, Mz]`: body forces (N) and yaw moment (N m), held over a sample period.
pub type Input = SVector<f64, NU>;
/// `d x_{k+1} / d x_k` in the network form.
pub type StateMatrix = SMatrix<f64, NX, NX>;
/// `d x_{k+1} / d u_k` in the network form.
pub type InputMatrix = SMatrix<f64, NX, NU>;

/// Names of the network-form state components, in order.
pub const STATE_NAMES: [&str; NX] = ["x", "y", "z", "cos_psi", "sin_psi", "u", "v", "w", "r"];
/// Names of the simulator-form state components, in order.
pub const SIM_STATE_NAMES: [&str; NS] = ["x", "y", "z", "psi", "u", "v", "w", "r"];
/// Names of the input components, in order.
pub const INPUT_NAMES: [&str; NU] = ["X", "Y", "Z", "Mz"];
