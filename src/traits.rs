//! The discrete-time interface shared by the frozen PINC and the analytic vehicle, so a
//! controller can run either (learned-model MPC and true-model "oracle" MPC are the same
//! code).

use crate::runtime::{
    EnvelopeStatus, HorizonLinearisation, Predictor, Real, RuntimeError, Workspace, check_input, check_state,
};
use crate::types::{Input, State};
use crate::vehicle::Rk4Vehicle;

/// A model of the 9-state over one held-input sample period.
pub trait DiscreteModel {
    /// Scratch memory the model computes in (one per thread).
    type Workspace;

    /// A fresh workspace; the only allocation the hot calls need.
    fn workspace(&self) -> Self::Workspace;

    /// The sample period (s).
    fn dt(&self) -> f64;

    /// Input bounds `(min, max)` the model is valid for, if it knows them.
    fn input_bounds(&self) -> Option<(Input, Input)>;

    /// `out = x_{k+1}` from `x` under `u`.
    ///
    /// # Errors
    /// Non-finite arguments or prediction.
    fn step(&self, ws: &mut Self::Workspace, x: &State, u: &Input, out: &mut State) -> Result<(), RuntimeError>;

    /// Rolls out from `x0` under `inputs` and linearises along the trajectory, into `lin`:
    /// its `N + 1` states, `A_k = d x_{k+1} / d x_k` and `B_k = d x_{k+1} / d u_k`.
    ///
    /// # Errors
    /// `inputs` not as long as `lin`'s horizon, non-finite arguments or predictions.
    fn linearise_horizon(
        &self,
        ws: &mut Self::Workspace,
        x0: &State,
        inputs: &[Input],
        lin: &mut HorizonLinearisation,
    ) -> Result<(), RuntimeError>;

    /// State bounds `(min, max)` of the network form the model is valid in (its training
    /// envelope), if it knows them.
    fn state_bounds(&self) -> Option<(State, State)> {
        None
    }

    /// Training-envelope exits seen by the last call on `ws` (a model without an envelope,
    /// like the analytic vehicle, is valid everywhere).
    fn envelope_status(&self, _ws: &Self::Workspace) -> EnvelopeStatus {
        EnvelopeStatus::default()
    }

    /// True if the dynamics do not depend on the horizontal position: `x_{k+1}, y_{k+1}`
    /// depend on `x_k, y_k` through the identity only, and nothing else depends on them. A
    /// controller can then leave `x, y` out of its optimisation (the MPC does).
    fn position_free(&self) -> bool {
        false
    }
}

impl<T: Real> DiscreteModel for Predictor<T> {
    type Workspace = Workspace<T>;

    fn workspace(&self) -> Workspace<T> {
        Workspace::new(self)
    }

    fn dt(&self) -> f64 {
        self.dt()
    }

    fn input_bounds(&self) -> Option<(Input, Input)> {
        self.envelope().map(|e| (Input::from(e.input_min), Input::from(e.input_max)))
    }

    /// The envelope of the states the network sees (none for a hybrid whose correction is
    /// zero); the others are unbounded (a hybrid's physics holds everywhere, and a state the
    /// network never sees cannot take it outside what it learnt: a fit without a position
    /// source trains on `u = v = 0`, whose zero-width range as a bound pinned the controller's
    /// rotation).
    fn state_bounds(&self) -> Option<(State, State)> {
        if self.is_physics_only() {
            return None;
        }
        self.envelope().map(|e| {
            let (mut lo, mut hi) = (State::from(e.state_min), State::from(e.state_max));
            for i in (0..crate::NX).filter(|i| !self.state_inputs().contains(i)) {
                (lo[i], hi[i]) = (f64::NEG_INFINITY, f64::INFINITY);
            }
            (lo, hi)
        })
    }

    fn step(&self, ws: &mut Workspace<T>, x: &State, u: &Input, out: &mut State) -> Result<(), RuntimeError> {
        Predictor::step(self, ws, x, u, out)
    }

    fn linearise_horizon(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        lin: &mut HorizonLinearisation,
    ) -> Result<(), RuntimeError> {
        Predictor::linearise_horizon(self, ws, x0, inputs, lin)
    }

    fn envelope_status(&self, ws: &Workspace<T>) -> EnvelopeStatus {
        ws.envelope_status()
    }

    /// The network predicts increments `x_{k+1} = x_k + N(..)`: without `x, y` among its
    /// inputs, position enters only through that identity.
    fn position_free(&self) -> bool {
        !self.state_inputs().iter().any(|&i| i < 2)
    }
}

fn check_finite(step: usize, x: &State, u: &Input) -> Result<(), RuntimeError> {
    check_state(step, x)?;
    check_input(step, u)
}

impl DiscreteModel for Rk4Vehicle {
    type Workspace = ();

    fn workspace(&self) {}

    fn dt(&self) -> f64 {
        self.dt
    }

    fn input_bounds(&self) -> Option<(Input, Input)> {
        None
    }

    fn position_free(&self) -> bool {
        true
    }

    fn step(&self, _: &mut (), x: &State, u: &Input, out: &mut State) -> Result<(), RuntimeError> {
        check_finite(0, x, u)?;
        *out = self.step_network(x, u);
        if out.iter().any(|v| !v.is_finite()) {
            return Err(RuntimeError::NonFiniteOutput { step: 0 });
        }
        Ok(())
    }

    fn linearise_horizon(
        &self,
        _: &mut (),
        x0: &State,
        inputs: &[Input],
        lin: &mut HorizonLinearisation,
    ) -> Result<(), RuntimeError> {
        let (traj, a, b) = lin.buffers_for(inputs)?;
        traj[0] = *x0;
        for (k, u) in inputs.iter().enumerate() {
            check_finite(k, &traj[k], u)?;
            let (next, ak, bk) = self.step_with_jacobians(&traj[k], u);
            if next.iter().any(|v| !v.is_finite()) {
                return Err(RuntimeError::NonFiniteOutput { step: k });
            }
            (traj[k + 1], a[k], b[k]) = (next, ak, bk);
        }
        Ok(())
    }
}
