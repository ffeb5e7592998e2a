//! The public hot calls of [`Predictor`]: step, rollout and horizon linearisation. Each
//! runs its whole loop inside one function compiled either portably or with AVX2 + FMA,
//! chosen once at construction. None allocates.

use super::RuntimeError;
use super::error::check_len;
#[cfg(target_arch = "x86_64")]
use super::kernels::Fused;
use super::kernels::{MulAdd, Portable};
use super::predictor::{Predictor, Workspace};
use super::real::Real;
use crate::types::{Input, InputMatrix, State, StateMatrix};

pub(super) fn check_dt(dt: f64) -> Result<(), RuntimeError> {
    if dt.is_finite() && dt > 0.0 { Ok(()) } else { Err(RuntimeError::BadTimeStep(dt)) }
}

/// Calls the AVX2 + FMA instance of a kernel when the predictor selected it, else the
/// portable one.
macro_rules! dispatch {
    ($self:ident, $generic:ident, $fused:ident, $($arg:expr),*) => {{
        #[cfg(target_arch = "x86_64")]
        if $self.fused {
            // SAFETY: `fused` is only set when the CPU reports AVX2 and FMA.
            return unsafe { $self.$fused($($arg),*) };
        }
        $self.$generic::<Portable>($($arg),*)
    }};
}

impl<T: Real> Predictor<T> {
    /// One step of the model's own sample period: `out = x_hat(dt)` from `x` under `u`.
    ///
    /// # Errors
    /// A non-finite `x` or `u` ([`RuntimeError::NonFiniteState`] / `NonFiniteInput`), or a
    /// non-finite prediction. Envelope exits are recorded in the workspace, not errors.
    pub fn step(&self, ws: &mut Workspace<T>, x: &State, u: &Input, out: &mut State) -> Result<(), RuntimeError> {
        self.step_dt(ws, x, u, self.dt, out)
    }

    /// One step over an arbitrary `dt` (the network's time input).
    ///
    /// # Errors
    /// As [`Predictor::step`], plus [`RuntimeError::BadTimeStep`].
    pub fn step_dt(
        &self,
        ws: &mut Workspace<T>,
        x: &State,
        u: &Input,
        dt: f64,
        out: &mut State,
    ) -> Result<(), RuntimeError> {
        let mut traj = [*x, State::zeros()];
        self.rollout_dt(ws, x, std::slice::from_ref(u), dt, &mut traj)?;
        *out = traj[1];
        Ok(())
    }

    /// Autoregressive rollout: `out[0] = x0`, `out[k + 1] = step(out[k], inputs[k])`.
    ///
    /// # Errors
    /// `out.len() != inputs.len() + 1`, or as [`Predictor::step`] at any step.
    pub fn rollout(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        out: &mut [State],
    ) -> Result<(), RuntimeError> {
        self.rollout_dt(ws, x0, inputs, self.dt, out)
    }

    /// [`Predictor::rollout`] with an arbitrary `dt`.
    ///
    /// # Errors
    /// As [`Predictor::rollout`], plus [`RuntimeError::BadTimeStep`].
    pub fn rollout_dt(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        dt: f64,
        out: &mut [State],
    ) -> Result<(), RuntimeError> {
        check_dt(dt)?;
        check_len("rollout output", inputs.len() + 1, out.len())?;
        ws.envelope = Default::default();
        dispatch!(self, rollout_generic, rollout_fused, ws, x0, inputs, dt, out)
    }

    /// One step and its exact Jacobians `a = d x_next / d x`, `b = d x_next / d u`.
    ///
    /// # Errors
    /// As [`Predictor::step`].
    pub fn linearise(
        &self,
        ws: &mut Workspace<T>,
        x: &State,
        u: &Input,
        next: &mut State,
        a: &mut StateMatrix,
        b: &mut InputMatrix,
    ) -> Result<(), RuntimeError> {
        let mut traj = [*x, State::zeros()];
        let (mut aa, mut bb) = ([StateMatrix::zeros()], [InputMatrix::zeros()]);
        self.linearise_horizon(ws, x, std::slice::from_ref(u), &mut traj, &mut aa, &mut bb)?;
        (*next, *a, *b) = (traj[1], aa[0], bb[0]);
        Ok(())
    }

    /// Rolls out from `x0` under `inputs` and linearises along the way: `traj[k]` is the
    /// nominal trajectory (`traj[0] = x0`), `a[k] = d traj[k+1] / d traj[k]`,
    /// `b[k] = d traj[k+1] / d inputs[k]`, all exact.
    ///
    /// # Errors
    /// Buffer lengths other than `N + 1`, `N`, `N` for `N = inputs.len()`, or as
    /// [`Predictor::step`] at any step.
    pub fn linearise_horizon(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        traj: &mut [State],
        a: &mut [StateMatrix],
        b: &mut [InputMatrix],
    ) -> Result<(), RuntimeError> {
        check_len("trajectory", inputs.len() + 1, traj.len())?;
        check_len("A matrices", inputs.len(), a.len())?;
        check_len("B matrices", inputs.len(), b.len())?;
        ws.envelope = Default::default();
        dispatch!(self, linearise_generic, linearise_fused, ws, x0, inputs, traj, a, b)
    }

    #[inline(always)]
    fn rollout_generic<F: MulAdd>(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        dt: f64,
        out: &mut [State],
    ) -> Result<(), RuntimeError> {
        out[0] = *x0;
        for (k, u) in inputs.iter().enumerate() {
            let x = out[k];
            self.check_args(ws, k, &x, u)?;
            let next = self.step_kernel::<F>(ws, &x, u, dt);
            if next.iter().any(|v| !v.is_finite()) {
                return Err(RuntimeError::NonFiniteOutput { step: k });
            }
            out[k + 1] = next;
        }
        Ok(())
    }

    #[inline(always)]
    fn linearise_generic<F: MulAdd>(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        traj: &mut [State],
        a: &mut [StateMatrix],
        b: &mut [InputMatrix],
    ) -> Result<(), RuntimeError> {
        traj[0] = *x0;
        for (k, u) in inputs.iter().enumerate() {
            let x = traj[k];
            self.check_args(ws, k, &x, u)?;
            let next = self.linearise_kernel::<F>(ws, &x, u, self.dt, &mut a[k], &mut b[k]);
            // Three plain loops: one chained iterator over the three did not inline (5 % of a
            // linearisation).
            let finite = |v: &[f64]| v.iter().all(|v| v.is_finite());
            if !(finite(next.as_slice()) && finite(a[k].as_slice()) && finite(b[k].as_slice())) {
                return Err(RuntimeError::NonFiniteOutput { step: k });
            }
            traj[k + 1] = next;
        }
        Ok(())
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn rollout_fused(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        dt: f64,
        out: &mut [State],
    ) -> Result<(), RuntimeError> {
        self.rollout_generic::<Fused>(ws, x0, inputs, dt, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn linearise_fused(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        traj: &mut [State],
        a: &mut [StateMatrix],
        b: &mut [InputMatrix],
    ) -> Result<(), RuntimeError> {
        self.linearise_generic::<Fused>(ws, x0, inputs, traj, a, b)
    }
}
