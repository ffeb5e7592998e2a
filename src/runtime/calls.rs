//! The public hot calls of [`Predictor`]: step, rollout and horizon linearisation. Each
//! runs its whole loop inside one function compiled either portably or, given an
//! `Avx2Fma` token, for AVX2 + FMA. None allocates.

use super::error::{RuntimeError, check_dt, check_len};
use super::horizon::HorizonLinearisation;
use super::kernels::{MulAdd, NetOut, Portable, Real};
use super::predictor::{Predictor, Workspace};
use crate::types::{Input, InputMatrix, State, StateMatrix};

impl<T: Real> Predictor<T> {
    /// One step of the model's own sample period: `out = x_hat(dt)` from `x` under `u`.
    ///
    /// # Errors
    /// A non-finite `x` or `u` ([`RuntimeError::NonFiniteState`] / `NonFiniteInput`), a
    /// non-finite prediction, or a workspace made for another predictor. Envelope exits
    /// are recorded in the workspace, not errors.
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
        ws.start_call(self)?;
        match self.cpu {
            Some(cpu) => self.rollout_avx2(cpu, ws, x0, inputs, dt, out),
            None => self.rollout_generic::<Portable>(ws, x0, inputs, dt, out),
        }
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
        ws.start_call(self)?;
        let (traj, aa, bb) = (std::slice::from_mut(next), std::slice::from_mut(a), std::slice::from_mut(b));
        let inputs = std::slice::from_ref(u);
        match self.cpu {
            Some(cpu) => self.linearise_avx2(cpu, ws, x, inputs, traj, aa, bb),
            None => self.linearise_generic::<Portable>(ws, x, inputs, traj, aa, bb),
        }
    }

    /// Rolls out from `x0` under `inputs` and linearises along the way, into `lin`: the
    /// nominal trajectory (`x0` first) and every `A_k`, `B_k`, all exact.
    ///
    /// # Errors
    /// `inputs.len()` other than the horizon `lin` was made for
    /// ([`RuntimeError::HorizonMismatch`]), or as [`Predictor::step`] at any step.
    pub fn linearise_horizon(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        lin: &mut HorizonLinearisation,
    ) -> Result<(), RuntimeError> {
        let (traj, a, b) = lin.buffers_for(inputs)?;
        ws.start_call(self)?;
        let (first, next) = traj.split_at_mut(1);
        first[0] = *x0;
        match self.cpu {
            Some(cpu) => self.linearise_avx2(cpu, ws, x0, inputs, next, a, b),
            None => self.linearise_generic::<Portable>(ws, x0, inputs, next, a, b),
        }
    }

    avx2_entry!(rollout_avx2 => rollout_generic(ws: &mut Workspace<T>, x0: &State, inputs: &[Input], dt: f64, out: &mut [State]));
    avx2_entry!(linearise_avx2 => linearise_generic(
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        next: &mut [State],
        a: &mut [StateMatrix],
        b: &mut [InputMatrix]
    ));

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
        let rest = self.rest_output::<F>(&mut ws.net, dt);
        for (k, u) in inputs.iter().enumerate() {
            let x = out[k];
            self.check_args(ws, k, &x, u)?;
            let o = anchored(self.net.forward::<F>(self.cpu, &mut ws.net, &x, u, dt, false), &rest);
            let base = match &self.physics {
                Some(p) => p.over(dt).step_network(&x, u),
                None => x,
            };
            let (next, heading) = self.output.apply(&base, &o);
            ws.envelope.record_heading(k, heading);
            if next.iter().any(|v| !v.is_finite()) {
                return Err(RuntimeError::NonFiniteOutput { step: k });
            }
            out[k + 1] = next;
        }
        Ok(())
    }

    /// `next[k]` is the state after `inputs[k]`, from `x0` for `k = 0` and from
    /// `next[k - 1]` after.
    #[inline(always)]
    fn linearise_generic<F: MulAdd>(
        &self,
        ws: &mut Workspace<T>,
        x0: &State,
        inputs: &[Input],
        next: &mut [State],
        a: &mut [StateMatrix],
        b: &mut [InputMatrix],
    ) -> Result<(), RuntimeError> {
        let rest = self.rest_output::<F>(&mut ws.net, self.dt);
        for (k, u) in inputs.iter().enumerate() {
            let x = if k == 0 { *x0 } else { next[k - 1] };
            self.check_args(ws, k, &x, u)?;
            // The output at rest is a constant: it shifts the value, not the Jacobians.
            let o = anchored(self.net.forward::<F>(self.cpu, &mut ws.net, &x, u, self.dt, true), &rest);
            self.net.reverse::<F>(&mut ws.net);
            let physics = self.physics.map(|p| p.step_with_jacobians(&x, u));
            let (base, base_jacobians) = match &physics {
                Some((s, pa, pb)) => (*s, Some((pa, pb))),
                None => (x, None),
            };
            self.output.jacobians(&self.net, &ws.net, &base, base_jacobians, &o, &mut a[k], &mut b[k]);
            let (x_next, heading) = self.output.apply(&base, &o);
            ws.envelope.record_heading(k, heading);
            // Three plain loops: one chained iterator over the three did not inline (5 % of a
            // linearisation).
            let finite = |v: &[f64]| v.iter().all(|v| v.is_finite());
            if !(finite(x_next.as_slice()) && finite(a[k].as_slice()) && finite(b[k].as_slice())) {
                return Err(RuntimeError::NonFiniteOutput { step: k });
            }
            next[k] = x_next;
        }
        Ok(())
    }
}

/// A network output taken relative to the output at rest, where the model anchors there.
#[inline(always)]
pub(crate) fn anchored(mut o: NetOut, rest: &Option<NetOut>) -> NetOut {
    if let Some(r) = rest {
        for (o, r) in o.iter_mut().zip(r) {
            *o -= r;
        }
    }
    o
}
