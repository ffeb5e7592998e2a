//! Batch rollout: many trajectories at once, vectorised across trajectories (each layer
//! is an axpy over a block of lanes), for evaluators and sampling-based planners.

use super::RuntimeError;
use super::activation::activate_slice;
use super::calls::check_dt;
use super::envelope::EnvelopeStatus;
#[cfg(target_arch = "x86_64")]
use super::kernels::Fused;
use super::kernels::{MulAdd, Portable, accumulate};
use super::predictor::Predictor;
use super::real::Real;
use crate::types::{Input, NU, NX, State};

/// Trajectories advanced together; 32 keeps a 32-wide layer block in L1.
pub const LANES: usize = 32;

/// Scratch memory for [`Predictor::rollout_batch`], component-major over [`LANES`] lanes.
///
/// # Memory allocation
/// `BatchWorkspace::new` allocates `(inputs + 2 width + 2 * 9 + 2) * 32` floats; rollouts
/// allocate nothing.
#[derive(Debug, Clone)]
pub struct BatchWorkspace<T: Real = f32> {
    z: Vec<T>,
    ha: Vec<T>,
    hb: Vec<T>,
    x: Vec<f64>,
    o: Vec<T>,
    mean: Vec<T>,
    var: Vec<T>,
    envelope: EnvelopeStatus,
}

impl<T: Real> BatchWorkspace<T> {
    /// Sizes every buffer for `p`.
    pub fn new(p: &Predictor<T>) -> Self {
        Self {
            z: vec![T::ZERO; p.n_in * LANES],
            ha: vec![T::ZERO; p.width * LANES],
            hb: vec![T::ZERO; p.width * LANES],
            x: vec![0.0; NX * LANES],
            o: vec![T::ZERO; NX * LANES],
            mean: vec![T::ZERO; LANES],
            var: vec![T::ZERO; LANES],
            envelope: EnvelopeStatus::default(),
        }
    }

    /// Envelope exits (one per trajectory step outside) of the last batch rollout.
    pub fn envelope_status(&self) -> EnvelopeStatus {
        self.envelope
    }
}

impl<T: Real> Predictor<T> {
    /// Rolls out `x0.len()` trajectories of `N = inputs.len() / x0.len()` steps each.
    /// `inputs` holds trajectory `i`'s inputs at `[i N, (i + 1) N)`; `out` receives its
    /// `N + 1` states at `[i (N + 1), (i + 1)(N + 1))`, the first being `x0[i]`.
    ///
    /// # Errors
    /// Lengths that do not fit, non-finite initial states or inputs (checked before
    /// anything runs), or a non-finite prediction.
    pub fn rollout_batch(
        &self,
        ws: &mut BatchWorkspace<T>,
        x0: &[State],
        inputs: &[Input],
        out: &mut [State],
    ) -> Result<(), RuntimeError> {
        self.rollout_batch_dt(ws, x0, inputs, self.dt, out)
    }

    /// [`rollout_batch`](Self::rollout_batch) with a sample period other than the model's
    /// (the paper's interpolation and extrapolation sets use 0.06 s and 0.10 s).
    ///
    /// # Errors
    /// As `rollout_batch`, plus a non-finite or non-positive `dt`.
    pub fn rollout_batch_dt(
        &self,
        ws: &mut BatchWorkspace<T>,
        x0: &[State],
        inputs: &[Input],
        dt: f64,
        out: &mut [State],
    ) -> Result<(), RuntimeError> {
        check_dt(dt)?;
        let n = x0.len();
        if n == 0 {
            return if inputs.is_empty() && out.is_empty() {
                Ok(())
            } else {
                Err(RuntimeError::LengthMismatch { what: "batch inputs", expected: 0, found: inputs.len() })
            };
        }
        let steps = inputs.len() / n;
        if steps * n != inputs.len() {
            return Err(RuntimeError::LengthMismatch {
                what: "batch inputs",
                expected: n * steps,
                found: inputs.len(),
            });
        }
        if out.len() != n * (steps + 1) {
            return Err(RuntimeError::LengthMismatch {
                what: "batch output",
                expected: n * (steps + 1),
                found: out.len(),
            });
        }
        for (i, x) in x0.iter().enumerate() {
            if let Some(index) = x.iter().position(|v| !v.is_finite()) {
                let _ = i;
                return Err(RuntimeError::NonFiniteState { step: 0, index, value: x[index] });
            }
        }
        for (j, u) in inputs.iter().enumerate() {
            if let Some(index) = u.iter().position(|v| !v.is_finite()) {
                return Err(RuntimeError::NonFiniteInput { step: j % steps, index, value: u[index] });
            }
        }
        ws.envelope = EnvelopeStatus::default();
        #[cfg(target_arch = "x86_64")]
        if self.fused {
            // SAFETY: `fused` is only set when the CPU reports AVX2 and FMA.
            return unsafe { self.batch_fused(ws, x0, inputs, steps, dt, out) };
        }
        self.batch_generic::<Portable>(ws, x0, inputs, steps, dt, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn batch_fused(
        &self,
        ws: &mut BatchWorkspace<T>,
        x0: &[State],
        inputs: &[Input],
        steps: usize,
        dt: f64,
        out: &mut [State],
    ) -> Result<(), RuntimeError> {
        self.batch_generic::<Fused>(ws, x0, inputs, steps, dt, out)
    }

    #[inline(always)]
    fn batch_generic<F: MulAdd>(
        &self,
        ws: &mut BatchWorkspace<T>,
        x0: &[State],
        inputs: &[Input],
        steps: usize,
        dt: f64,
        out: &mut [State],
    ) -> Result<(), RuntimeError> {
        const L: usize = LANES;
        let ns = self.seen.len();
        let w = self.width;
        for start in (0..x0.len()).step_by(L) {
            let m = L.min(x0.len() - start);
            for b in 0..m {
                for c in 0..NX {
                    ws.x[c * L + b] = x0[start + b][c];
                }
                out[(start + b) * (steps + 1)] = x0[start + b];
            }
            for k in 0..steps {
                let u_of = |b: usize| &inputs[(start + b) * steps + k];
                // Network input, component-major.
                for (q, &i) in self.seen.iter().enumerate() {
                    for b in 0..m {
                        ws.z[q * L + b] = (T::of(ws.x[i * L + b]) - self.in_mean[q]) * self.in_inv_std[q];
                    }
                }
                for c in 0..NU {
                    let q = ns + c;
                    for b in 0..m {
                        ws.z[q * L + b] = (T::of(u_of(b)[c]) - self.in_mean[q]) * self.in_inv_std[q];
                    }
                }
                let q = self.n_in - 1;
                ws.z[q * L..q * L + m].fill((T::of(dt) - self.in_mean[q]) * self.in_inv_std[q]);

                for (l, layer) in self.layers.iter().enumerate() {
                    let (input, h) = if l == 0 {
                        (&ws.z[..], &mut ws.ha)
                    } else if l % 2 == 1 {
                        (&ws.ha[..], &mut ws.hb)
                    } else {
                        (&ws.hb[..], &mut ws.ha)
                    };
                    for j in 0..w {
                        let hj = &mut h[j * L..j * L + m];
                        hj.fill(layer.bias[j]);
                        accumulate::<F, T>(hj, &layer.w_row[j * layer.cols..(j + 1) * layer.cols], input, L);
                        activate_slice::<F, T>(self.activation, layer.beta, layer.inv_beta, hj, None);
                    }
                    if let Some(norm) = &layer.norm {
                        let (mean, var) = (&mut ws.mean[..m], &mut ws.var[..m]);
                        mean.fill(T::ZERO);
                        var.fill(T::ZERO);
                        for j in 0..w {
                            for (s, &v) in mean.iter_mut().zip(&h[j * L..j * L + m]) {
                                *s += v;
                            }
                        }
                        let inv_w = T::of(1.0 / w as f64);
                        mean.iter_mut().for_each(|s| *s *= inv_w);
                        for j in 0..w {
                            for ((s, &v), &mu) in var.iter_mut().zip(&h[j * L..j * L + m]).zip(mean.iter()) {
                                *s += (v - mu) * (v - mu);
                            }
                        }
                        var.iter_mut().for_each(|s| *s = T::ONE / (*s * inv_w + norm.eps).root());
                        for j in 0..w {
                            let (g, beta) = (norm.gain[j], norm.bias[j]);
                            for ((v, &mu), &is) in h[j * L..j * L + m].iter_mut().zip(mean.iter()).zip(var.iter()) {
                                *v = F::mul_add(g, (*v - mu) * is, beta);
                            }
                        }
                    }
                }
                let y = if self.layers.len() % 2 == 1 { &ws.ha } else { &ws.hb };
                for kk in 0..NX {
                    let ok = &mut ws.o[kk * L..kk * L + m];
                    ok.fill(self.output.bias[kk]);
                    accumulate::<F, T>(ok, &self.output.w_row[kk * w..(kk + 1) * w], y, L);
                    for v in ok.iter_mut() {
                        *v = F::mul_add(*v, self.out_std[kk], self.out_mean[kk]);
                    }
                }
                for b in 0..m {
                    let mut x = State::zeros();
                    let mut o = [0.0; NX];
                    for c in 0..NX {
                        x[c] = ws.x[c * L + b];
                        o[c] = ws.o[c * L + b].to_f64();
                    }
                    self.envelope.check(&mut ws.envelope, k, &x, u_of(b));
                    let next = self.compose(&x, &o);
                    if next.iter().any(|v| !v.is_finite()) {
                        return Err(RuntimeError::NonFiniteOutput { step: k });
                    }
                    for c in 0..NX {
                        ws.x[c * L + b] = next[c];
                    }
                    out[(start + b) * (steps + 1) + k + 1] = next;
                }
            }
        }
        Ok(())
    }
}
