//! Batch rollout: many trajectories at once, vectorised across trajectories (each layer
//! is an axpy over a block of lanes), for evaluators and sampling-based planners.

use super::RuntimeError;
use super::activation::activate;
use super::calls::check_dt;
use super::envelope::EnvelopeStatus;
use super::error::{check_input, check_len, check_state};
use super::fold::Dense;
#[cfg(target_arch = "x86_64")]
use super::kernels::Fused;
use super::kernels::{MulAdd, PACK, Pack, Portable, block_packs, matvec, matvec_rows};
use super::predictor::Predictor;
use super::real::Real;
use crate::model::Activation;
use crate::types::{Input, NU, NX, State};

/// Trajectories advanced together; 32 keeps a 32-wide layer block in L1.
pub const LANES: usize = 32;

/// Packs per component of the lane-major buffers.
const LANE_PACKS: usize = LANES / PACK;

/// Scratch memory for [`Predictor::rollout_batch`], component-major over [`LANES`] lanes.
///
/// # Memory allocation
/// `BatchWorkspace::new` allocates `(inputs + 2 width + 3 * 9) * 32` floats (widths
/// rounded up to packs of 8); rollouts allocate nothing.
#[derive(Debug, Clone)]
pub struct BatchWorkspace<T: Real = f32> {
    z: Vec<Pack<T>>,
    ha: Vec<Pack<T>>,
    hb: Vec<Pack<T>>,
    x: Vec<[f64; LANES]>,
    o: Vec<Pack<T>>,
    envelope: EnvelopeStatus,
}

impl<T: Real> BatchWorkspace<T> {
    /// Sizes every buffer for `p`.
    pub fn new(p: &Predictor<T>) -> Self {
        let zero = [T::ZERO; PACK];
        let units = p.packs * PACK;
        Self {
            z: vec![zero; p.n_in * LANE_PACKS],
            ha: vec![zero; units * LANE_PACKS],
            hb: vec![zero; units * LANE_PACKS],
            x: vec![[0.0; LANES]; NX],
            o: vec![zero; NX * LANE_PACKS],
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
    /// anything runs), or [`RuntimeError::BatchDiverged`] if some predictions stop being
    /// finite: every other trajectory is then complete in `out`, and a diverged one holds
    /// NaN from its first non-finite prediction on.
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
            // No trajectories: nothing to read or write, and no step count to infer.
            check_len("batch inputs", 0, inputs.len())?;
            return check_len("batch output", 0, out.len());
        }
        let steps = inputs.len() / n;
        check_len("batch inputs", n * steps, inputs.len())?;
        check_len("batch output", n * (steps + 1), out.len())?;
        for x in x0 {
            check_state(0, x)?;
        }
        for (j, u) in inputs.iter().enumerate() {
            check_input(j % steps, u)?;
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
        const P: usize = LANE_PACKS;
        let ns = self.seen.len();
        let net = &self.net;
        // Trajectories whose prediction stopped being finite, and the first found.
        let (mut diverged, mut first_diverged) = (0, None);
        for start in (0..x0.len()).step_by(L) {
            let m = L.min(x0.len() - start);
            // Lanes past the last trajectory compute on zeros and are never read.
            ws.x.fill([0.0; L]);
            ws.z.fill([T::ZERO; PACK]);
            for b in 0..m {
                for c in 0..NX {
                    ws.x[c][b] = x0[start + b][c];
                }
                out[(start + b) * (steps + 1)] = x0[start + b];
            }
            ws.z[(ns + NU) * P..(ns + NU + 1) * P].fill([T::of(dt); PACK]);
            let x: &mut [[f64; L]; NX] = (&mut ws.x[..]).try_into().expect("NX components");
            // Lanes whose prediction stopped being finite: they go on computing (from zeros)
            // but are no longer checked or written.
            let mut dead = [false; L];
            for k in 0..steps {
                // This step's inputs, component-major (padding lanes stay 0).
                let mut u = [[0.0; L]; NU];
                for b in 0..m {
                    let ub = &inputs[(start + b) * steps + k];
                    for c in 0..NU {
                        u[c][b] = ub[c];
                    }
                }
                // Raw network input, component-major, converted a whole component at a time
                // (element by element, the conversion did not vectorise).
                let components = self.seen.iter().map(|&i| &x[i]).chain(&u);
                for (q, v) in components.enumerate() {
                    for (d, &v) in ws.z[q * P..(q + 1) * P].as_flattened_mut().iter_mut().zip(v) {
                        *d = T::of(v);
                    }
                }

                // As in the single path, a LayerNorm is applied inside the next product,
                // with per-lane statistics.
                let mut norm: Option<LaneNorm<T>> = None;
                for (l, layer) in net.hidden.iter().enumerate() {
                    let (input, h) = if l == 0 {
                        (&ws.z[..], &mut ws.ha)
                    } else if l % 2 == 1 {
                        (&ws.ha[..], &mut ws.hb)
                    } else {
                        (&ws.hb[..], &mut ws.ha)
                    };
                    if quads::<F, T>() {
                        hidden_layer::<F, T, 4>(self.activation, layer, input, norm.as_ref(), h);
                    } else {
                        hidden_layer::<F, T, 2>(self.activation, layer, input, norm.as_ref(), h);
                    }
                    norm = net.norm_eps[l].map(|eps| lane_norm::<F, T>(&h[..net.width * P], eps, net.inv_width));
                }
                let y = if net.hidden.len() % 2 == 1 { &ws.ha } else { &ws.hb };
                if quads::<F, T>() {
                    output_layer::<F, T, 4>(&net.output, y, norm.as_ref(), &mut ws.o);
                } else {
                    output_layer::<F, T, 2>(&net.output, y, norm.as_ref(), &mut ws.o);
                }
                let o_flat = ws.o.as_flattened();
                let o: [[f64; L]; NX] = std::array::from_fn(|c| std::array::from_fn(|b| o_flat[c * L + b].to_f64()));
                // The envelope per lane only where some value left it.
                let mut outside = [false; L];
                if self.envelope.mark_lanes(x, &u, &mut outside) {
                    for b in (0..m).filter(|&b| outside[b] && !dead[b]) {
                        let xb = State::from_fn(|c, _| x[c][b]);
                        self.envelope.check(&mut ws.envelope, k, &xb, &inputs[(start + b) * steps + k]);
                    }
                }
                self.compose_lanes(x, &o);
                let mut finite = [true; L];
                for c in x.iter() {
                    for (f, v) in finite.iter_mut().zip(c) {
                        *f &= v.is_finite();
                    }
                }
                for b in 0..m {
                    let traj = start + b;
                    if !finite[b] && !dead[b] {
                        dead[b] = true;
                        diverged += 1;
                        first_diverged.get_or_insert((traj, k));
                        // The trajectory's remaining states are NaN.
                        out[traj * (steps + 1) + k + 1..(traj + 1) * (steps + 1)].fill(State::repeat(f64::NAN));
                    }
                    if dead[b] {
                        x.iter_mut().for_each(|c| c[b] = 0.0);
                    } else {
                        out[traj * (steps + 1) + k + 1] = State::from_fn(|c, _| x[c][b]);
                    }
                }
            }
        }
        match first_diverged {
            Some((trajectory, step)) => Err(RuntimeError::BatchDiverged { count: diverged, trajectory, step }),
            None => Ok(()),
        }
    }
}

/// Per-lane LayerNorm statistics of a layer: `1 / sqrt(var + eps)` and `-mean / sqrt(..)`.
struct LaneNorm<T> {
    inv_std: [Pack<T>; LANE_PACKS],
    shift: [Pack<T>; LANE_PACKS],
}

/// Whether the batch layers take units four at a time (each loaded input pack feeds four
/// multiply-adds, over half the lanes) rather than two: where four accumulator sets of a
/// block still fit the registers.
const fn quads<F: MulAdd, T: Real>() -> bool {
    block_packs::<F, T>() >= 2
}

/// A hidden layer in every lane, `R` units at a time, activated into `h`.
#[inline(always)]
fn hidden_layer<F: MulAdd, T: Real, const R: usize>(
    activation: Activation,
    layer: &Dense<T>,
    input: &[Pack<T>],
    norm: Option<&LaneNorm<T>>,
    h: &mut [Pack<T>],
) {
    for (j, hj) in h.chunks_exact_mut(R * LANE_PACKS).enumerate() {
        let pre = units::<F, T, R>(layer, R * j, input, norm);
        activate::<F, T>(activation, pre.as_flattened(), hj, None);
    }
}

/// The output layer's nine units in every lane, `R` at a time, into `o`.
#[inline(always)]
fn output_layer<F: MulAdd, T: Real, const R: usize>(
    layer: &Dense<T>,
    y: &[Pack<T>],
    norm: Option<&LaneNorm<T>>,
    o: &mut [Pack<T>],
) {
    let (groups, last) = o.split_at_mut((NX - 1) / R * R * LANE_PACKS);
    for (j, oj) in groups.chunks_exact_mut(R * LANE_PACKS).enumerate() {
        oj.copy_from_slice(units::<F, T, R>(layer, R * j, y, norm).as_flattened());
    }
    for (j, oj) in last.chunks_exact_mut(LANE_PACKS).enumerate() {
        oj.copy_from_slice(&units::<F, T, 1>(layer, (NX - 1) / R * R + j, y, norm)[0]);
    }
}

/// Outputs `j..j + R` of `layer` in every lane (those the layer has):
/// `W[j] . input + b[j]`, or after a LayerNorm of the input,
/// `r (W[j] . input) - r mean (W[j] . 1) + b[j]` (the single path's arithmetic).
#[inline(always)]
fn units<F: MulAdd, T: Real, const R: usize>(
    layer: &Dense<T>,
    j: usize,
    input: &[Pack<T>],
    norm: Option<&LaneNorm<T>>,
) -> [[Pack<T>; LANE_PACKS]; R] {
    let q = layer.in_packs();
    let rows = layer.rev.len() / q;
    let row = |j: usize| &layer.rev[j * q..(j + 1) * q].as_flattened()[..layer.cols];
    let mut acc = [[[T::ZERO; PACK]; LANE_PACKS]; R];
    if j + R <= rows {
        matvec_rows::<F, T, R>(
            acc.each_mut().map(|a| &mut a[..]),
            std::array::from_fn(|r| row(j + r)),
            input,
            LANE_PACKS,
        );
    } else {
        for (r, a) in acc.iter_mut().enumerate().take(rows - j) {
            matvec::<F, T>(a, row(j + r), input, LANE_PACKS);
        }
    }
    for (u, acc) in acc.iter_mut().enumerate().take(rows - j) {
        let (jj, b) = (j + u, PACK);
        let bias = layer.bias[jj / b][jj % b];
        match norm {
            Some(n) => {
                let w1 = layer.row_sum[jj / b][jj % b];
                for k in 0..LANE_PACKS {
                    for t in 0..PACK {
                        acc[k][t] = F::mul_add(n.inv_std[k][t], acc[k][t], F::mul_add(n.shift[k][t], w1, bias));
                    }
                }
            }
            None => {
                for k in 0..LANE_PACKS {
                    for t in 0..PACK {
                        acc[k][t] += bias;
                    }
                }
            }
        }
    }
    acc
}

/// LayerNorm statistics of every lane over the (real) units of a component-major layer.
#[inline(always)]
fn lane_norm<F: MulAdd, T: Real>(h: &[Pack<T>], eps: T, inv_width: T) -> LaneNorm<T> {
    const P: usize = LANE_PACKS;
    let mut mean = [[T::ZERO; PACK]; P];
    for hj in h.chunks_exact(P) {
        for k in 0..P {
            for t in 0..PACK {
                mean[k][t] += hj[k][t];
            }
        }
    }
    let mut var = [[T::ZERO; PACK]; P];
    for k in 0..P {
        for t in 0..PACK {
            mean[k][t] *= inv_width;
        }
    }
    for hj in h.chunks_exact(P) {
        for k in 0..P {
            for t in 0..PACK {
                let dev = hj[k][t] - mean[k][t];
                var[k][t] = F::mul_add(dev, dev, var[k][t]);
            }
        }
    }
    let mut n = LaneNorm { inv_std: var, shift: mean };
    for k in 0..P {
        for t in 0..PACK {
            let r = T::ONE / (var[k][t] * inv_width + eps).root();
            n.inv_std[k][t] = r;
            n.shift[k][t] = -(r * mean[k][t]);
        }
    }
    n
}
