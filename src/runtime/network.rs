//! One evaluation of the network (forward, optionally keeping what the reverse pass
//! needs), its exact Jacobian by reverse mode, and the residual / yaw-rotation output map.

use super::activation::activate;
use super::fold::Dense;
use super::kernels::{MulAdd, PACK, Pack, dot, lane_sum, matvec, matvec_rows, packs, sum};
use super::predictor::{Predictor, Workspace};
use super::real::Real;
#[cfg(target_arch = "x86_64")]
use super::registers;
use crate::types::{Input, InputMatrix, NU, NX, State, StateMatrix};
#[cfg(target_arch = "x86_64")]
use std::any::Any;

/// Raw network output (in state units, widened to f64), before the residual and rotation.
pub(crate) type NetOut = [f64; NX];

/// Statistics of a LayerNorm without gain or bias over `s`: `(mean, 1 / sqrt(var + eps))`.
/// `mask` leaves the padding units out.
#[inline(always)]
pub(crate) fn norm_stats<F: MulAdd, T: Real>(s: &[Pack<T>], eps: T, inv_width: T, mask: Option<&[Pack<T>]>) -> (T, T) {
    let mut acc = [T::ZERO; PACK];
    let mean = match mask {
        Some(m) => dot::<F, T>(s, m),
        None => sum(s),
    } * inv_width;
    // Two passes (mean, then squared deviations), as PyTorch does.
    for (p, v) in s.iter().enumerate() {
        let mut d = [T::ZERO; PACK];
        for t in 0..PACK {
            d[t] = v[t] - mean;
        }
        if let Some(m) = mask {
            for t in 0..PACK {
                d[t] *= m[p][t];
            }
        }
        for t in 0..PACK {
            acc[t] = F::mul_add(d[t], d[t], acc[t]);
        }
    }
    (mean, T::ONE / (lane_sum(acc) * inv_width + eps).root())
}

/// `(s - mean) inv_std` (0 on padding units), the normalised vector the reverse pass needs.
#[inline(always)]
fn normalised<T: Real>(s: &[Pack<T>], out: &mut [Pack<T>], (mean, inv_std): (T, T), mask: Option<&[Pack<T>]>) {
    for (p, (v, o)) in s.iter().zip(out.iter_mut()).enumerate() {
        let v = *v;
        let m = mask.map_or([T::ONE; PACK], |m| m[p]);
        *o = std::array::from_fn(|t| (v[t] - mean) * inv_std * m[t]);
    }
}

/// `acc + b`, or, after a LayerNorm with statistics `(mean, r)` on the layer's input,
/// `r acc - r mean (W 1) + b`.
#[inline(always)]
fn finish<F: MulAdd, T: Real>(acc: &mut [Pack<T>], layer: &Dense<T>, norm: Option<(T, T)>) {
    // Whole packs through locals: element by element, LLVM cannot rule out that `acc`
    // overlaps the weights and writes scalars, which the next vector load cannot be
    // forwarded from.
    match norm {
        Some((mean, r)) => {
            let shift = -(r * mean);
            for ((a, b), w1) in acc.iter_mut().zip(&layer.bias).zip(&layer.row_sum) {
                let (x, b, w1) = (*a, *b, *w1);
                *a = std::array::from_fn(|t| F::mul_add(r, x[t], F::mul_add(shift, w1[t], b[t])));
            }
        }
        None => {
            for (a, b) in acc.iter_mut().zip(&layer.bias) {
                let (x, b) = (*a, *b);
                *a = std::array::from_fn(|t| x[t] + b[t]);
            }
        }
    }
}

impl<T: Real> Predictor<T> {
    /// Forward pass. With `keep`, stores activation derivatives and LayerNorm statistics
    /// in the workspace for [`Predictor::network_jacobian`].
    #[inline(always)]
    pub(crate) fn network<F: MulAdd>(&self, ws: &mut Workspace<T>, x: &State, u: &Input, t: f64, keep: bool) -> NetOut {
        #[cfg(target_arch = "x86_64")]
        if F::WIDE_REGISTERS
            && let Some(p) = (self as &dyn Any).downcast_ref::<Predictor<f32>>()
            && let Some(ws) = (ws as &mut dyn Any).downcast_mut::<Workspace<f32>>()
            && registers::eligible(p)
        {
            // SAFETY: `eligible` holds, and `WIDE_REGISTERS` kernels only run inside functions
            // compiled for AVX2 + FMA, which are only called where the CPU has them.
            return unsafe { registers::network(p, ws, x, u, t, keep) };
        }
        let ns = self.seen.len();
        for (k, &i) in self.seen.iter().enumerate() {
            ws.z[k] = T::of(x[i]);
        }
        for c in 0..NU {
            ws.z[ns + c] = T::of(u[c]);
        }
        ws.z[ns + NU] = T::of(t);

        let np = self.packs;
        let net = &self.net;
        let mask = net.mask.as_deref();
        // LayerNorm statistics of the previous layer, applied after this layer's product so
        // that the product need not wait for them.
        let mut norm: Option<(T, T)> = None;
        for (l, layer) in net.hidden.iter().enumerate() {
            let (done, rest) = ws.y.split_at_mut(l * np);
            let input: &[T] = if l == 0 { &ws.z } else { &done[(l - 1) * np..].as_flattened()[..layer.cols] };
            let out = &mut rest[..np];
            let pre = &mut ws.pre[..np];
            matvec::<F, T>(pre, input, &layer.fwd, np);
            finish::<F, T>(pre, layer, norm);
            let d = if keep { Some(&mut ws.d[l * np..(l + 1) * np]) } else { None };
            activate::<F, T>(self.activation, pre, out, d);
            norm = net.norm_eps[l].map(|eps| norm_stats::<F, T>(out, eps, net.inv_width, mask));
            if let (true, Some(stats)) = (keep, norm) {
                ws.inv_std[l] = stats.1;
                normalised(out, &mut ws.xhat[l * np..(l + 1) * np], stats, mask);
            }
        }
        let y = &ws.y[(net.hidden.len() - 1) * np..].as_flattened()[..net.output.cols];
        let mut o = [[T::ZERO; PACK]; packs(NX)];
        matvec::<F, T>(&mut o, y, &net.output.fwd, packs(NX));
        finish::<F, T>(&mut o, &net.output, norm);
        std::array::from_fn(|k| o.as_flattened()[k].to_f64())
    }

    /// Reverse pass after `network(.., keep = true)`: leaves `d out / d z` (9 rows of
    /// input packs, `z` the raw `[x_seen, u, t]`) in `ws.g`.
    #[inline(always)]
    pub(crate) fn network_jacobian<F: MulAdd>(&self, ws: &mut Workspace<T>) {
        let np = self.packs;
        let net = &self.net;
        // Seed: the output layer's rows.
        ws.g[..NX * np].copy_from_slice(&net.output.rev[..NX * np]);
        for (l, layer) in net.hidden.iter().enumerate().rev() {
            let d = &ws.d[l * np..(l + 1) * np];
            let xhat = &ws.xhat[l * np..(l + 1) * np];
            for k in 0..NX {
                let g = &mut ws.g[k * np..(k + 1) * np];
                if net.norm_eps[l].is_some() {
                    // Through v = (s - mean s) r: r (g - mean g - v mean(g v)).
                    let inv_std = ws.inv_std[l];
                    let (m1, m2) = (sum(g) * net.inv_width, dot::<F, T>(g, xhat) * net.inv_width);
                    for (g, (v, d)) in g.iter_mut().zip(xhat.iter().zip(d)) {
                        let (x, v, d) = (*g, *v, *d);
                        *g = std::array::from_fn(|t| inv_std * (x[t] - m1 - v[t] * m2) * d[t]);
                    }
                } else {
                    for (g, d) in g.iter_mut().zip(d) {
                        let (x, d) = (*g, *d);
                        *g = std::array::from_fn(|t| x[t] * d[t]);
                    }
                }
            }
            // Row k of the next g is row k of g times W (rows of `W` in the reverse layout).
            // Rows two at a time, sharing the loads of W.
            let q = layer.in_packs();
            let (g, g2) = (&ws.g, &mut ws.g2);
            let row = |k: usize| g[k * np..(k + 1) * np].as_flattened();
            for k in (0..NX - 1).step_by(2) {
                let (a, b) = g2[k * q..(k + 2) * q].split_at_mut(q);
                matvec_rows::<F, T, 2>([a, b], [row(k), row(k + 1)], &layer.rev, q);
            }
            matvec::<F, T>(&mut g2[(NX - 1) * q..NX * q], row(NX - 1), &layer.rev, q);
            std::mem::swap(&mut ws.g, &mut ws.g2);
        }
    }

    /// `x_next` from `x` and the raw output: residual, rotation of the planar increments
    /// by the predicted yaw, optional renormalisation.
    #[inline(always)]
    pub(crate) fn compose(&self, x: &State, o: &NetOut) -> State {
        let mut lanes: [[f64; 1]; NX] = std::array::from_fn(|c| [x[c]]);
        self.compose_lanes(&mut lanes, &std::array::from_fn(|c| [o[c]]));
        State::from_fn(|c, _| lanes[c][0])
    }

    /// [`Predictor::compose`] for `L` lanes at once, component-major, in place: the batch
    /// rollout's arithmetic is the single step's, lane by lane, and vectorises.
    #[inline(always)]
    pub(crate) fn compose_lanes<const L: usize>(&self, x: &mut [[f64; L]; NX], o: &[[f64; L]; NX]) {
        for b in 0..L {
            let before: [f64; NX] = std::array::from_fn(|c| x[c][b]);
            let base = |c: usize| if self.residual { before[c] } else { 0.0 };
            let (c, s) = (base(3) + o[3][b], base(4) + o[4][b]);
            let (dx, dy) =
                if self.rotate { (c * o[0][b] - s * o[1][b], s * o[0][b] + c * o[1][b]) } else { (o[0][b], o[1][b]) };
            x[0][b] = base(0) + dx;
            x[1][b] = base(1) + dy;
            for k in 2..NX {
                x[k][b] = base(k) + o[k][b];
            }
        }
        if self.renormalise_yaw {
            for b in 0..L {
                let n = x[3][b].hypot(x[4][b]);
                x[3][b] /= n;
                x[4][b] /= n;
            }
        }
    }

    /// Jacobians of [`Predictor::compose`] given `d out / d z` in `ws.g`.
    #[inline(always)]
    pub(crate) fn compose_jacobians(
        &self,
        ws: &Workspace<T>,
        x: &State,
        o: &NetOut,
        a: &mut StateMatrix,
        b: &mut InputMatrix,
    ) {
        let q = packs(self.n_in);
        let ns = self.seen.len();
        // D = d out / d (x, u).
        let mut dx = StateMatrix::zeros();
        let mut du = InputMatrix::zeros();
        for k in 0..NX {
            let row = ws.g[k * q..(k + 1) * q].as_flattened();
            for (m, &i) in self.seen.iter().enumerate() {
                dx[(k, i)] = row[m].to_f64();
            }
            for c in 0..NU {
                du[(k, c)] = row[ns + c].to_f64();
            }
        }
        *a = if self.residual { StateMatrix::identity() } else { StateMatrix::zeros() };
        let base = if self.residual { *x } else { State::zeros() };
        let (c, s) = (base[3] + o[3], base[4] + o[4]);
        for k in 2..NX {
            for j in 0..NX {
                a[(k, j)] += dx[(k, j)];
            }
            for j in 0..NU {
                b[(k, j)] = du[(k, j)];
            }
        }
        if self.rotate {
            let r = if self.residual { 1.0 } else { 0.0 };
            for j in 0..NX {
                // d c / d x_j and d s / d x_j.
                let cj = if j == 3 { r } else { 0.0 } + dx[(3, j)];
                let sj = if j == 4 { r } else { 0.0 } + dx[(4, j)];
                a[(0, j)] += c * dx[(0, j)] - s * dx[(1, j)] + o[0] * cj - o[1] * sj;
                a[(1, j)] += s * dx[(0, j)] + c * dx[(1, j)] + o[0] * sj + o[1] * cj;
            }
            for j in 0..NU {
                b[(0, j)] = c * du[(0, j)] - s * du[(1, j)] + o[0] * du[(3, j)] - o[1] * du[(4, j)];
                b[(1, j)] = s * du[(0, j)] + c * du[(1, j)] + o[0] * du[(4, j)] + o[1] * du[(3, j)];
            }
        } else {
            for j in 0..NX {
                a[(0, j)] += dx[(0, j)];
                a[(1, j)] += dx[(1, j)];
            }
            for j in 0..NU {
                b[(0, j)] = du[(0, j)];
                b[(1, j)] = du[(1, j)];
            }
        }
        if self.renormalise_yaw {
            // d (v / |v|) / d v = (I - n n^T) / |v| on the (cos, sin) rows.
            let (vc, vs) = (base[3] + o[3], base[4] + o[4]);
            let norm = vc.hypot(vs);
            let (nc, ns) = (vc / norm, vs / norm);
            let p = [[(1.0 - nc * nc) / norm, -nc * ns / norm], [-nc * ns / norm, (1.0 - ns * ns) / norm]];
            for j in 0..NX {
                let (r3, r4) = (a[(3, j)], a[(4, j)]);
                a[(3, j)] = p[0][0] * r3 + p[0][1] * r4;
                a[(4, j)] = p[1][0] * r3 + p[1][1] * r4;
            }
            for j in 0..NU {
                let (r3, r4) = (b[(3, j)], b[(4, j)]);
                b[(3, j)] = p[0][0] * r3 + p[0][1] * r4;
                b[(4, j)] = p[1][0] * r3 + p[1][1] * r4;
            }
        }
    }

    /// One step, generic over the multiply-add.
    #[inline(always)]
    pub(crate) fn step_kernel<F: MulAdd>(&self, ws: &mut Workspace<T>, x: &State, u: &Input, dt: f64) -> State {
        let o = self.network::<F>(ws, x, u, dt, false);
        self.compose(x, &o)
    }

    /// One step with its Jacobians, generic over the multiply-add.
    #[inline(always)]
    pub(crate) fn linearise_kernel<F: MulAdd>(
        &self,
        ws: &mut Workspace<T>,
        x: &State,
        u: &Input,
        dt: f64,
        a: &mut StateMatrix,
        b: &mut InputMatrix,
    ) -> State {
        let o = self.network::<F>(ws, x, u, dt, true);
        self.network_jacobian::<F>(ws);
        self.compose_jacobians(ws, x, &o, a, b);
        self.compose(x, &o)
    }
}
