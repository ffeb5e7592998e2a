//! Zero-order-hold discretisation of the vehicle: classic RK4 with sub-steps over one
//! sample period, the input held constant, in both state forms, with the exact Jacobian
//! of the discrete map.

use super::VehicleParams;
use super::dynamics::{rhs, rhs_jacobian_times, rhs_jacobians, rhs_sim, wrap_angle};
use crate::types::{DEFAULT_DT, Input, InputMatrix, NU, NX, SimState, State, StateMatrix};
use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

/// Default number of RK4 sub-steps per 0.08 s sample period: keeps a 5.2 s trajectory
/// within 1e-9 of a 64x finer integration (see the `rk4_accuracy` test).
pub const DEFAULT_SUBSTEPS: usize = 16;

/// RK4 sub-steps per 0.08 s sample period of the analytic vehicle as a controller's model (the
/// oracle's): 20 ms each. Chosen by the accuracy it gives against [`DEFAULT_SUBSTEPS`] along
/// a manoeuvre faster than the default closed loop (`control_substeps_*` test): the next state
/// within 2e-7 and the Jacobians within 1e-5, far under the plant-model mismatch a controller
/// meets and the estimate's noise. The plant and the estimator keep the default.
pub const CONTROL_SUBSTEPS: usize = 4;

/// `n` classic RK4 steps of size `h` for `x' = f(x)`.
pub fn rk4<const D: usize>(
    f: impl Fn(&SVector<f64, D>) -> SVector<f64, D>,
    mut x: SVector<f64, D>,
    h: f64,
    n: usize,
) -> SVector<f64, D> {
    for _ in 0..n {
        let k1 = f(&x);
        let k2 = f(&(x + k1 * (0.5 * h)));
        let k3 = f(&(x + k2 * (0.5 * h)));
        let k4 = f(&(x + k3 * h));
        x += (k1 + (k2 + k3) * 2.0 + k4) * (h / 6.0);
    }
    x
}

/// The analytic vehicle over one sample period with the input held (zero-order hold).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rk4Vehicle {
    /// Vehicle coefficients. Default: BlueROV2.
    pub params: VehicleParams,
    /// Sample period (s). Default: 0.08
    pub dt: f64,
    /// RK4 sub-steps per sample period. Default: [`DEFAULT_SUBSTEPS`]
    pub substeps: usize,
}

impl Default for Rk4Vehicle {
    fn default() -> Self {
        Self { params: VehicleParams::default(), dt: DEFAULT_DT, substeps: DEFAULT_SUBSTEPS }
    }
}

impl Rk4Vehicle {
    /// A BlueROV2 with the given sample period and default sub-step size.
    pub fn with_dt(dt: f64) -> Self {
        // Keep the sub-step no longer than the default's 5 ms.
        let substeps = ((dt / DEFAULT_DT) * DEFAULT_SUBSTEPS as f64).ceil().max(1.0) as usize;
        Self { dt, substeps, ..Self::default() }
    }

    /// The vehicle as a controller's model over a sample period of `dt`: sub-steps as long as
    /// [`CONTROL_SUBSTEPS`] makes them at 0.08 s.
    pub fn for_control(params: VehicleParams, dt: f64) -> Self {
        let substeps = ((dt / DEFAULT_DT) * CONTROL_SUBSTEPS as f64).ceil().max(1.0) as usize;
        Self { params, dt, substeps }
    }

    /// The same vehicle and sub-step count over a step of `dt` (each sub-step `dt / substeps`):
    /// how a hybrid model integrates its physics over whatever step it is asked for.
    #[must_use]
    pub fn over(&self, dt: f64) -> Self {
        Self { dt, ..*self }
    }

    fn h(&self) -> f64 {
        self.dt / self.substeps as f64
    }

    /// One sample period in the simulator form; the returned yaw is wrapped to `(-pi, pi]`.
    pub fn step_sim(&self, s: &SimState, u: &Input) -> SimState {
        let mut next = rk4(|s| rhs_sim(&self.params, s, u), *s, self.h(), self.substeps);
        next[3] = wrap_angle(next[3]);
        next
    }

    /// One sample period in the network form (cos and sin integrated as states, not
    /// renormalised).
    pub fn step_network(&self, x: &State, u: &Input) -> State {
        rk4(|x| rhs(&self.params, x, u), *x, self.h(), self.substeps)
    }

    /// Simulates from `s0` under `inputs` (one per sample period); returns
    /// `inputs.len() + 1` states, the first being `s0`.
    pub fn simulate(&self, s0: &SimState, inputs: &[Input]) -> Vec<SimState> {
        let mut out = Vec::with_capacity(inputs.len() + 1);
        out.push(*s0);
        let mut s = *s0;
        for u in inputs {
            s = self.step_sim(&s, u);
            out.push(s);
        }
        out
    }

    /// One sample period in the network form together with the exact Jacobians of the
    /// discrete RK4 map: `A = d x_next / d x` and `B = d x_next / d u`.
    pub fn step_with_jacobians(&self, x: &State, u: &Input) -> (State, StateMatrix, InputMatrix) {
        // Sensitivities S = d x_n / d [cos psi_0 .. r_0, u] propagated through every RK4 stage.
        // Nothing depends on x, y or z (the depth): their columns of A stay the identity's, so S
        // leaves them out.
        const NS: usize = NX - 3;
        type Sens = SMatrix<f64, NX, { NS + NU }>;
        let h = self.h();
        let p = &self.params;
        let mut xs = *x;
        let mut s = Sens::zeros();
        for c in 0..NS {
            s[(c + 3, c)] = 1.0;
        }
        // `fu` is constant; `fx * S` is formed without `fx` (sparse, rhs_jacobian_times).
        let (_, fu) = rhs_jacobians(p, x);
        let stage = |xi: &State, si: &Sens| -> (State, Sens) {
            let mut ks = rhs_jacobian_times(p, xi, si);
            let mut kb = ks.fixed_view_mut::<NX, NU>(0, NS);
            kb += fu;
            (rhs(p, xi, u), ks)
        };
        for _ in 0..self.substeps {
            let (k1, s1) = stage(&xs, &s);
            let (k2, s2) = stage(&(xs + k1 * (0.5 * h)), &(s + s1 * (0.5 * h)));
            let (k3, s3) = stage(&(xs + k2 * (0.5 * h)), &(s + s2 * (0.5 * h)));
            let (k4, s4) = stage(&(xs + k3 * h), &(s + s3 * h));
            xs += (k1 + (k2 + k3) * 2.0 + k4) * (h / 6.0);
            s += (s1 + (s2 + s3) * 2.0 + s4) * (h / 6.0);
        }
        let mut a = StateMatrix::identity();
        a.fixed_view_mut::<NX, NS>(0, 3).copy_from(&s.fixed_view::<NX, NS>(0, 0));
        (xs, a, s.fixed_view::<NX, NU>(0, NS).into())
    }
}
