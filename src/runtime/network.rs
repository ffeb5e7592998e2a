//! One evaluation of the network (forward, optionally keeping what the reverse pass
//! needs), its exact Jacobian by reverse mode, and the residual / yaw-rotation output map.

use super::activation::activate_slice;
use super::kernels::{MulAdd, accumulate, dot, sum};
use super::predictor::{OUTPUT_STRIDE, Predictor, Workspace};
use super::real::Real;
use crate::types::{Input, InputMatrix, NU, NX, State, StateMatrix};

/// Raw network output (after output scaling, widened to f64), before the residual and
/// rotation.
pub(crate) type NetOut = [f64; NX];

impl<T: Real> Predictor<T> {
    /// Forward pass. With `keep`, stores activation derivatives and LayerNorm statistics
    /// in the workspace for [`Predictor::network_jacobian`].
    #[inline(always)]
    pub(crate) fn network<F: MulAdd>(&self, ws: &mut Workspace<T>, x: &State, u: &Input, t: f64, keep: bool) -> NetOut {
        let ns = self.seen.len();
        for (k, &i) in self.seen.iter().enumerate() {
            ws.z[k] = (T::of(x[i]) - self.in_mean[k]) * self.in_inv_std[k];
        }
        for c in 0..NU {
            ws.z[ns + c] = (T::of(u[c]) - self.in_mean[ns + c]) * self.in_inv_std[ns + c];
        }
        let last = self.n_in - 1;
        ws.z[last] = (T::of(t) - self.in_mean[last]) * self.in_inv_std[last];

        let w = self.width;
        for (l, layer) in self.layers.iter().enumerate() {
            let (done, rest) = ws.y.split_at_mut(l * w);
            let input: &[T] = if l == 0 { &ws.z } else { &done[(l - 1) * w..] };
            let out = &mut rest[..w];
            out.copy_from_slice(&layer.bias);
            accumulate::<F, T>(out, input, &layer.w_col, w);
            let d = if keep { Some(&mut ws.d[l * w..(l + 1) * w]) } else { None };
            activate_slice::<F, T>(self.activation, layer.beta, layer.inv_beta, out, d);
            if let Some(norm) = &layer.norm {
                let inv_w = T::of(1.0 / w as f64);
                let mean = sum(out) * inv_w;
                let xhat = &mut ws.xhat[l * w..(l + 1) * w];
                for j in 0..w {
                    xhat[j] = out[j] - mean;
                }
                let var = dot::<F, T>(xhat, xhat) * inv_w;
                let inv_std = T::ONE / (var + norm.eps).root();
                ws.inv_std[l] = inv_std;
                for j in 0..w {
                    xhat[j] *= inv_std;
                    out[j] = F::mul_add(norm.gain[j], xhat[j], norm.bias[j]);
                }
            }
        }
        let y = &ws.y[(self.layers.len() - 1) * w..];
        let mut o = [T::ZERO; OUTPUT_STRIDE];
        o[..NX].copy_from_slice(&self.output.bias);
        accumulate::<F, T>(&mut o, y, &self.output.w_col, OUTPUT_STRIDE);
        let mut out = [0.0; NX];
        for k in 0..NX {
            out[k] = F::mul_add(o[k], self.out_std[k], self.out_mean[k]).to_f64();
        }
        out
    }

    /// Reverse pass after `network(.., keep = true)`: leaves `d out / d z_raw` (9 rows of
    /// `n_in`, row-major, with both scalings applied) in `ws.g`.
    #[inline(always)]
    pub(crate) fn network_jacobian<F: MulAdd>(&self, ws: &mut Workspace<T>) {
        let w = self.width;
        // Seed: rows of the output layer, scaled by the output de-normalisation.
        for k in 0..NX {
            for j in 0..w {
                ws.g[k * w + j] = self.output.w_row[k * w + j] * self.out_std[k];
            }
        }
        for (l, layer) in self.layers.iter().enumerate().rev() {
            let cols = layer.cols;
            let d = &ws.d[l * w..(l + 1) * w];
            if let Some(norm) = &layer.norm {
                let xhat = &ws.xhat[l * w..(l + 1) * w];
                let inv_std = ws.inv_std[l];
                for k in 0..NX {
                    let g = &mut ws.g[k * w..(k + 1) * w];
                    for j in 0..w {
                        g[j] *= norm.gain[j];
                    }
                    let inv_w = T::of(1.0 / w as f64);
                    let (m1, m2) = (sum(g) * inv_w, dot::<F, T>(g, xhat) * inv_w);
                    for j in 0..w {
                        g[j] = inv_std * (g[j] - m1 - xhat[j] * m2) * d[j];
                    }
                }
            } else {
                for k in 0..NX {
                    for (g, &d) in ws.g[k * w..(k + 1) * w].iter_mut().zip(d) {
                        *g *= d;
                    }
                }
            }
            // g2 = g W: row k of g2 accumulates g[k, j] * (row j of W).
            for k in 0..NX {
                let g2 = &mut ws.g2[k * cols..(k + 1) * cols];
                g2.fill(T::ZERO);
                accumulate::<F, T>(g2, &ws.g[k * w..(k + 1) * w], &layer.w_row, cols);
            }
            // The next (earlier) layer reads rows of length `cols` (= w, or n_in at the end).
            for k in 0..NX {
                ws.g[k * cols..(k + 1) * cols].copy_from_slice(&ws.g2[k * cols..(k + 1) * cols]);
            }
        }
        let n = self.n_in;
        for k in 0..NX {
            for i in 0..n {
                ws.g[k * n + i] *= self.in_inv_std[i];
            }
        }
    }

    /// `x_next` from `x` and the raw output: residual, rotation of the planar increments
    /// by the predicted yaw, optional renormalisation.
    #[inline(always)]
    pub(crate) fn compose(&self, x: &State, o: &NetOut) -> State {
        let mut next = if self.residual { *x } else { State::zeros() };
        let (c, s) = (next[3] + o[3], next[4] + o[4]);
        let (dx, dy) = if self.rotate { (c * o[0] - s * o[1], s * o[0] + c * o[1]) } else { (o[0], o[1]) };
        next[0] += dx;
        next[1] += dy;
        for k in 2..NX {
            next[k] += o[k];
        }
        if self.renormalise_yaw {
            let n = next[3].hypot(next[4]);
            next[3] /= n;
            next[4] /= n;
        }
        next
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
        let n = self.n_in;
        let ns = self.seen.len();
        // D = d out / d (x, u).
        let mut dx = StateMatrix::zeros();
        let mut du = InputMatrix::zeros();
        for k in 0..NX {
            let row = &ws.g[k * n..(k + 1) * n];
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
