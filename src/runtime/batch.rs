//! Batch rollout: many trajectories at once, vectorised across trajectories (each layer
//! is an axpy over a block of lanes), for evaluators and sampling-based planners.

use super::envelope::EnvelopeStatus;
use super::error::{RuntimeError, check_dt, check_input, check_len, check_state};
use super::kernels::{
    Dense, MulAdd, NetScratch, PACK, Pack, Portable, Real, Shape, activate, block_packs, matvec, matvec_rows,
};
use super::predictor::Predictor;
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
    /// The network shape the buffers were sized for.
    shape: Shape,
    /// Raw network input `[x_seen, u, t]`, component-major over the lanes.
    net_input: Vec<Pack<T>>,
    /// Hidden activations; layers alternate between the two (one is read while the other
    /// is written).
    hidden_even: Vec<Pack<T>>,
    hidden_odd: Vec<Pack<T>>,
    /// The states of the lanes, component-major, in f64.
    states: Vec<[f64; LANES]>,
    /// Raw network output, component-major.
    net_output: Vec<Pack<T>>,
    envelope: EnvelopeStatus,
    /// For a hybrid anchored at rest: where its output at rest over another period is computed.
    rest_scratch: Option<NetScratch<T>>,
}

impl<T: Real> BatchWorkspace<T> {
    /// Sizes every buffer for `p`.
    pub fn new(p: &Predictor<T>) -> Self {
        let zero = [T::ZERO; PACK];
        let units = p.net.packs * PACK;
        Self {
            shape: p.net.shape(),
            net_input: vec![zero; p.net.n_in * LANE_PACKS],
            hidden_even: vec![zero; units * LANE_PACKS],
            hidden_odd: vec![zero; units * LANE_PACKS],
            states: vec![[0.0; LANES]; NX],
            net_output: vec![zero; NX * LANE_PACKS],
            envelope: EnvelopeStatus::default(),
            rest_scratch: p.rest.map(|_| NetScratch::new(&p.net)),
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
        if ws.shape != self.net.shape() {
            return Err(RuntimeError::WorkspaceMismatch { what: "batch workspace" });
        }
        ws.envelope = EnvelopeStatus::default();
        match self.cpu {
            Some(cpu) => self.batch_avx2(cpu, ws, x0, inputs, steps, dt, out),
            None => self.batch_generic::<Portable>(ws, x0, inputs, steps, dt, out),
        }
    }

    avx2_entry!(batch_avx2 => batch_generic(
        ws: &mut BatchWorkspace<T>,
        x0: &[State],
        inputs: &[Input],
        steps: usize,
        dt: f64,
        out: &mut [State]
    ));

    /// The batch, one block of [`LANES`] trajectories at a time.
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
        let mut divergence = Divergence::default();
        let rest = match &mut ws.rest_scratch {
            Some(scratch) => self.rest_output::<F>(scratch, dt),
            None => None,
        };
        for start in (0..x0.len()).step_by(LANES) {
            let block = Block { start, lanes: LANES.min(x0.len() - start), steps };
            self.load_block(ws, &block, x0, dt, out);
            // Lanes whose prediction stopped being finite: they go on computing (from zeros)
            // but are no longer checked or written.
            let mut dead = [false; LANES];
            for k in 0..block.steps {
                let u = self.load_step_inputs(ws, &block, inputs, k);
                self.network_lanes::<F>(ws);
                self.check_envelope_lanes(ws, &block, inputs, k, &u, &dead);
                let o_flat = ws.net_output.as_flattened();
                let at_rest = |c: usize| rest.map_or(0.0, |r| r[c]);
                let o: [[f64; LANES]; NX] =
                    std::array::from_fn(|c| std::array::from_fn(|b| o_flat[c * LANES + b].to_f64() - at_rest(c)));
                let x: &mut [[f64; LANES]; NX] = (&mut ws.states[..]).try_into().expect("NX components");
                if let Some(p) = self.physics.map(|p| p.over(dt)) {
                    // A hybrid's output is added to the physics' step, lane by lane.
                    for b in (0..block.lanes).filter(|&b| !dead[b]) {
                        let xb = State::from_fn(|c, _| x[c][b]);
                        let ub = Input::from_fn(|c, _| u[c][b]);
                        let next = p.step_network(&xb, &ub);
                        for c in 0..NX {
                            x[c][b] = next[c];
                        }
                    }
                }
                let heading = self.output.apply_lanes(x, &o);
                for b in (0..block.lanes).filter(|&b| !dead[b]) {
                    ws.envelope.record_heading(k, heading[b]);
                }
                store_step(x, &block, k, &mut dead, &mut divergence, out);
            }
        }
        match divergence.first {
            Some((trajectory, step)) => Err(RuntimeError::BatchDiverged { count: divergence.count, trajectory, step }),
            None => Ok(()),
        }
    }

    /// The block's initial states into the lanes (and the output), the time input into
    /// every lane. Lanes past the last trajectory compute on zeros and are never read.
    #[inline(always)]
    fn load_block(&self, ws: &mut BatchWorkspace<T>, block: &Block, x0: &[State], dt: f64, out: &mut [State]) {
        let ns = self.net.seen.len();
        ws.states.fill([0.0; LANES]);
        ws.net_input.fill([T::ZERO; PACK]);
        for b in 0..block.lanes {
            let x = x0[block.start + b];
            for c in 0..NX {
                ws.states[c][b] = x[c];
            }
            out[(block.start + b) * (block.steps + 1)] = x;
        }
        ws.net_input[(ns + NU) * LANE_PACKS..(ns + NU + 1) * LANE_PACKS].fill([T::from_f64(dt); PACK]);
    }

    /// Step `k`'s inputs, component-major (padding lanes 0), and the raw network input
    /// from the lanes' states and those inputs.
    #[inline(always)]
    fn load_step_inputs(
        &self,
        ws: &mut BatchWorkspace<T>,
        block: &Block,
        inputs: &[Input],
        k: usize,
    ) -> [[f64; LANES]; NU] {
        let mut u = [[0.0; LANES]; NU];
        for b in 0..block.lanes {
            let ub = &inputs[(block.start + b) * block.steps + k];
            for c in 0..NU {
                u[c][b] = ub[c];
            }
        }
        // Converted a whole component at a time (element by element, the conversion did
        // not vectorise).
        let components = self.net.seen.iter().map(|&i| &ws.states[i]).chain(&u);
        for (q, v) in components.enumerate() {
            for (d, &v) in ws.net_input[q * LANE_PACKS..(q + 1) * LANE_PACKS].as_flattened_mut().iter_mut().zip(v) {
                *d = T::from_f64(v);
            }
        }
        u
    }

    /// The network in every lane, from `net_input` to `net_output`. As in the single path,
    /// a LayerNorm is applied inside the next product, with per-lane statistics.
    #[inline(always)]
    fn network_lanes<F: MulAdd>(&self, ws: &mut BatchWorkspace<T>) {
        let net = &self.net.folded;
        let mut norm: Option<LaneNorm<T>> = None;
        for (l, layer) in net.hidden.iter().enumerate() {
            let (input, h) = if l == 0 {
                (&ws.net_input[..], &mut ws.hidden_even)
            } else if l % 2 == 1 {
                (&ws.hidden_even[..], &mut ws.hidden_odd)
            } else {
                (&ws.hidden_odd[..], &mut ws.hidden_even)
            };
            if quads::<F, T>() {
                hidden_layer::<F, T, 4>(self.net.activation, layer, input, norm.as_ref(), h);
            } else {
                hidden_layer::<F, T, 2>(self.net.activation, layer, input, norm.as_ref(), h);
            }
            norm = net.norm_eps[l].map(|eps| lane_norm::<F, T>(&h[..net.width * LANE_PACKS], eps, net.inv_width));
        }
        let y = if net.hidden.len() % 2 == 1 { &ws.hidden_even } else { &ws.hidden_odd };
        if quads::<F, T>() {
            output_layer::<F, T, 4>(&net.output, y, norm.as_ref(), &mut ws.net_output);
        } else {
            output_layer::<F, T, 2>(&net.output, y, norm.as_ref(), &mut ws.net_output);
        }
    }

    /// Envelope exits of step `k`, checked per lane only where some value left it.
    #[inline(always)]
    fn check_envelope_lanes(
        &self,
        ws: &mut BatchWorkspace<T>,
        block: &Block,
        inputs: &[Input],
        k: usize,
        u: &[[f64; LANES]; NU],
        dead: &[bool; LANES],
    ) {
        let x: &[[f64; LANES]; NX] = (&ws.states[..]).try_into().expect("NX components");
        let mut outside = [false; LANES];
        if self.envelope.mark_lanes(x, u, &mut outside) {
            for b in (0..block.lanes).filter(|&b| outside[b] && !dead[b]) {
                let xb = State::from_fn(|c, _| x[c][b]);
                self.envelope.check(&mut ws.envelope, k, &xb, &inputs[(block.start + b) * block.steps + k]);
            }
        }
    }
}

/// Which trajectories a block of lanes holds.
struct Block {
    /// The first trajectory.
    start: usize,
    /// Trajectories in the block (the rest of the lanes are padding).
    lanes: usize,
    /// Steps per trajectory.
    steps: usize,
}

/// Trajectories whose prediction stopped being finite: how many, and the first found
/// `(trajectory, step)`.
#[derive(Default)]
struct Divergence {
    count: usize,
    first: Option<(usize, usize)>,
}

/// Writes step `k + 1` of every live lane; a lane whose new state is not finite is marked
/// dead, its remaining states NaN, and it computes on zeros from then on.
#[inline(always)]
fn store_step(
    x: &mut [[f64; LANES]; NX],
    block: &Block,
    k: usize,
    dead: &mut [bool; LANES],
    divergence: &mut Divergence,
    out: &mut [State],
) {
    let mut finite = [true; LANES];
    for c in x.iter() {
        for (f, v) in finite.iter_mut().zip(c) {
            *f &= v.is_finite();
        }
    }
    let n = block.steps + 1;
    for b in 0..block.lanes {
        let traj = block.start + b;
        if !finite[b] && !dead[b] {
            dead[b] = true;
            divergence.count += 1;
            divergence.first.get_or_insert((traj, k));
            out[traj * n + k + 1..(traj + 1) * n].fill(State::repeat(f64::NAN));
        }
        if dead[b] {
            x.iter_mut().for_each(|c| c[b] = 0.0);
        } else {
            out[traj * n + k + 1] = State::from_fn(|c, _| x[c][b]);
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
            let r = T::ONE / (var[k][t] * inv_width + eps).sqrt();
            n.inv_std[k][t] = r;
            n.shift[k][t] = -(r * mean[k][t]);
        }
    }
    n
}
