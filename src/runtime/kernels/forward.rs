//! One evaluation of the network on the raw input `[x_seen, u, t]`: the forward pass
//! (optionally keeping what the reverse pass needs) and the exact Jacobian of the raw output
//! by reverse mode. What the output means (residual, yaw rotation) is the predictor's.

use super::activation::activate;
use super::cpu::Avx2Fma;
use super::fold::Dense;
use super::network::{NetOut, NetScratch, Network};
use super::packs::{MulAdd, PACK, Pack, dot, lane_sum, matvec, matvec_rows, packs, sum};
#[cfg(target_arch = "x86_64")]
use super::real::Family;
use super::real::Real;
#[cfg(target_arch = "x86_64")]
use super::registers;
use crate::types::{Input, NU, NX, State};

/// The `f32` member of "a network and its scratch": what the register kernel takes.
#[cfg(target_arch = "x86_64")]
struct Parts;
#[cfg(target_arch = "x86_64")]
impl Family for Parts {
    type Of<'a, T: Real> = (&'a Network<T>, &'a mut NetScratch<T>);
}

/// Statistics of a LayerNorm without gain or bias over `s`: `(mean, 1 / sqrt(var + eps))`.
/// `mask` leaves the padding units out.
#[inline(always)]
pub fn norm_stats<F: MulAdd, T: Real>(s: &[Pack<T>], eps: T, inv_width: T, mask: Option<&[Pack<T>]>) -> (T, T) {
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
    (mean, T::ONE / (lane_sum(acc) * inv_width + eps).sqrt())
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

impl<T: Real> Network<T> {
    /// Forward pass of `x`, `u` and time input `t`. With `keep`, stores activation
    /// derivatives and LayerNorm statistics in `ws` for [`Network::reverse`]. `cpu` lets an
    /// `f32` softplus network up to 32 wide run in registers (AVX2 + FMA).
    #[inline(always)]
    pub fn forward<F: MulAdd>(
        &self,
        cpu: Option<Avx2Fma>,
        ws: &mut NetScratch<T>,
        x: &State,
        u: &Input,
        t: f64,
        keep: bool,
    ) -> NetOut {
        #[cfg(target_arch = "x86_64")]
        if F::WIDE_REGISTERS
            && let Some(cpu) = cpu
            && let Some((net, ws)) = T::as_f32::<Parts>((self, &mut *ws))
            && registers::eligible(net)
        {
            return registers::forward(cpu, net, ws, x, u, t, keep);
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = cpu;
        let ns = self.seen.len();
        for (k, &i) in self.seen.iter().enumerate() {
            ws.input[k] = T::from_f64(x[i]);
        }
        for c in 0..NU {
            ws.input[ns + c] = T::from_f64(u[c]);
        }
        ws.input[ns + NU] = T::from_f64(t);

        let np = self.packs;
        let net = &self.folded;
        let mask = net.mask.as_deref();
        // LayerNorm statistics of the previous layer, applied after this layer's product so
        // that the product need not wait for them.
        let mut norm: Option<(T, T)> = None;
        for (l, layer) in net.hidden.iter().enumerate() {
            let (done, rest) = ws.y.split_at_mut(l * np);
            let input: &[T] = if l == 0 { &ws.input } else { &done[(l - 1) * np..].as_flattened()[..layer.cols] };
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

    /// Reverse pass after `forward(.., keep = true)`: leaves `d out / d input` (9 rows of
    /// input packs, the input being the raw `[x_seen, u, t]`) in `ws.rows`.
    #[inline(always)]
    pub fn reverse<F: MulAdd>(&self, ws: &mut NetScratch<T>) {
        let np = self.packs;
        let net = &self.folded;
        // Seed: the output layer's rows.
        ws.rows[..NX * np].copy_from_slice(&net.output.rev[..NX * np]);
        for (l, layer) in net.hidden.iter().enumerate().rev() {
            let d = &ws.d[l * np..(l + 1) * np];
            let xhat = &ws.xhat[l * np..(l + 1) * np];
            for k in 0..NX {
                let g = &mut ws.rows[k * np..(k + 1) * np];
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
            // Row k one layer back is row k here times W (rows of `W` in the reverse layout).
            // Rows two at a time, sharing the loads of W.
            let q = layer.in_packs();
            let (rows, next) = (&ws.rows, &mut ws.rows_next);
            let row = |k: usize| rows[k * np..(k + 1) * np].as_flattened();
            for k in (0..NX - 1).step_by(2) {
                let (a, b) = next[k * q..(k + 2) * q].split_at_mut(q);
                matvec_rows::<F, T, 2>([a, b], [row(k), row(k + 1)], &layer.rev, q);
            }
            matvec::<F, T>(&mut next[(NX - 1) * q..NX * q], row(NX - 1), &layer.rev, q);
            std::mem::swap(&mut ws.rows, &mut ws.rows_next);
        }
    }
}
