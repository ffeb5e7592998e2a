//! The `f32` forward pass of a softplus network at most 32 units wide, written for AVX2 +
//! FMA with the hidden vector held in (at most four) registers from layer to layer.
//!
//! A single step is a chain of dependent layers, so its time is the latency of that chain.
//! The generic kernels broadcast every input unit in turn against a column of the matrix:
//! a chain of `width / 2` multiply-adds per layer behind a store and reload of the hidden
//! vector. Here each output unit is a dot product of its weight row with the registers
//! (two chains of two multiply-adds), eight rows are summed by one transposition, and nothing
//! goes through memory but the weights.
//!
//! Every function here is `unsafe` for one reason only: it must run on a CPU with AVX2 and
//! FMA. The helpers are `#[inline(always)]` (which `#[target_feature]` functions cannot be)
//! so that the vectors stay in registers across them.
#![allow(unsafe_op_in_unsafe_fn)]

use std::arch::x86_64::*;

use super::fold::Dense;
use super::kernels::{PACK, Pack, packs};
use super::network::NetOut;
use super::predictor::{Predictor, Workspace};
use crate::model::Activation;
use crate::types::{Input, NU, State};

/// Packs of the raw network input `[x_seen, u, t]` (at most 9 + 4 + 1 values).
const INPUT_PACKS: usize = 2;

/// Whether `p` can run here: `f32`, AVX2 + FMA, softplus, at most 32 hidden units.
pub(crate) fn eligible(p: &Predictor<f32>) -> bool {
    p.fused && p.activation == Activation::Softplus && p.packs <= 4 && packs(p.n_in) <= INPUT_PACKS
}

/// The network's raw output for `x`, `u` and time input `t`; with `keep`, also what the
/// reverse pass reads (activation derivatives, normalised vectors, LayerNorm scales) into
/// the workspace, as [`Predictor::network`] does.
///
/// # Safety
/// The CPU must have AVX2 and FMA, and `eligible(p)` must hold.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn network(
    p: &Predictor<f32>,
    ws: &mut Workspace<f32>,
    x: &State,
    u: &Input,
    t: f64,
    keep: bool,
) -> NetOut {
    let mut z = [0.0_f32; INPUT_PACKS * PACK];
    for (k, &i) in p.seen.iter().enumerate() {
        z[k] = x[i] as f32;
    }
    let ns = p.seen.len();
    for c in 0..NU {
        z[ns + c] = u[c] as f32;
    }
    z[ns + NU] = t as f32;
    let z = [load(&z[..PACK]), load(&z[PACK..])];
    match (p.packs, packs(p.n_in)) {
        (4, 2) => forward::<4, 2>(p, ws, &z, keep),
        (4, _) => forward::<4, 1>(p, ws, &z, keep),
        (3, 2) => forward::<3, 2>(p, ws, &z, keep),
        (3, _) => forward::<3, 1>(p, ws, &z, keep),
        (2, 2) => forward::<2, 2>(p, ws, &z, keep),
        (2, _) => forward::<2, 1>(p, ws, &z, keep),
        (_, 2) => forward::<1, 2>(p, ws, &z, keep),
        _ => forward::<1, 1>(p, ws, &z, keep),
    }
}

/// The forward pass for `NP` packs per hidden layer and `ZQ` input packs.
#[target_feature(enable = "avx2,fma")]
unsafe fn forward<const NP: usize, const ZQ: usize>(
    p: &Predictor<f32>,
    ws: &mut Workspace<f32>,
    z: &[__m256; INPUT_PACKS],
    keep: bool,
) -> NetOut {
    let net = &p.net;
    let one = _mm256_set1_ps(1.0);
    let mut mask = [one; NP];
    if let Some(m) = &net.mask {
        for q in 0..NP {
            mask[q] = load(&m[q]);
        }
    }
    let mask = net.mask.as_ref().map(|_| &mask);
    let inv_width = _mm256_set1_ps(net.inv_width);
    // `(r, mean)` of the LayerNorm on the previous layer's output, applied after this
    // layer's product; `(1, 0)` without one leaves `acc + b` exact.
    let mut scale = (one, _mm256_setzero_ps());
    let input: &[__m256; ZQ] = z[..ZQ].try_into().expect("ZQ <= INPUT_PACKS");
    let mut pre: [__m256; NP] = dense::<ZQ, NP>(&net.hidden[0], input, scale);
    let mut s = [_mm256_setzero_ps(); NP];
    for (l, eps) in net.norm_eps.iter().enumerate() {
        let np = NP * l;
        for q in 0..NP {
            let (v, d) = softplus(pre[q], keep);
            s[q] = v;
            if keep {
                store(&mut ws.d[np + q], d);
            }
        }
        scale = (one, _mm256_setzero_ps());
        if let Some(eps) = eps {
            // Two passes (mean, then squared deviations), as PyTorch does; sums as trees,
            // since this chain runs beside the next layer's product and may outlast it.
            // `terms` holds the summands of each pass (padding units masked out).
            let mut terms = s;
            let mut dev = s;
            if let Some(mask) = mask {
                for q in 0..NP {
                    terms[q] = _mm256_mul_ps(s[q], mask[q]);
                }
            }
            let mean = _mm256_mul_ps(lane_sum(tree_sum(terms)), inv_width);
            for q in 0..NP {
                dev[q] = _mm256_sub_ps(s[q], mean);
                if let Some(mask) = mask {
                    dev[q] = _mm256_mul_ps(dev[q], mask[q]);
                }
                terms[q] = _mm256_mul_ps(dev[q], dev[q]);
            }
            let var = _mm256_add_ps(_mm256_mul_ps(lane_sum(tree_sum(terms)), inv_width), _mm256_set1_ps(*eps));
            let r = _mm256_div_ps(one, _mm256_sqrt_ps(var));
            scale = (r, mean);
            if keep {
                ws.inv_std[l] = _mm256_cvtss_f32(r);
                for q in 0..NP {
                    store(&mut ws.xhat[np + q], _mm256_mul_ps(dev[q], r));
                }
            }
        }
        if let Some(next) = net.hidden.get(l + 1) {
            pre = dense::<NP, NP>(next, &s, scale);
        }
    }
    // Output rows 0..8 as a group, row 8 on its own (not with seven padding rows).
    let [o] = dense::<NP, 1>(&net.output, &s, scale);
    let last: &[Pack<f32>; NP] = net.output.rev[PACK * NP..(PACK + 1) * NP].try_into().expect("output row 8");
    let centred = _mm256_fnmadd_ps(scale.1, load(&net.output.row_sum[1]), lane_sum(row_dot(last, &s)));
    let o8 = _mm256_cvtss_f32(_mm256_fmadd_ps(scale.0, centred, load(&net.output.bias[1])));
    let mut out = [0.0_f32; PACK];
    store(&mut out, o);
    std::array::from_fn(|k| f64::from(if k < PACK { out[k] } else { o8 }))
}

/// `r (W v - mean (W 1)) + b` for the first `8 NO` rows of `layer` (reverse layout, `Q`
/// packs per row): the dense layer after a LayerNorm with `(r, mean)` on `v`. `r` comes
/// last (it waits on a square root and a division), so it enters the last operation.
#[inline(always)]
unsafe fn dense<const Q: usize, const NO: usize>(
    layer: &Dense<f32>,
    v: &[__m256; Q],
    (r, mean): (__m256, __m256),
) -> [__m256; NO] {
    let rows: &[[Pack<f32>; Q]] = layer.rev.as_chunks::<Q>().0;
    let groups: &[[[Pack<f32>; Q]; PACK]] = rows.as_chunks::<PACK>().0;
    assert!(groups.len() >= NO && layer.bias.len() >= NO && layer.row_sum.len() >= NO, "layer shape");
    let mut out = [_mm256_setzero_ps(); NO];
    for g in 0..NO {
        let mut rows = [_mm256_setzero_ps(); PACK];
        for k in 0..PACK {
            rows[k] = row_dot(&groups[g][k], v);
        }
        let centred = _mm256_fnmadd_ps(mean, load(&layer.row_sum[g]), reduce8(rows));
        out[g] = _mm256_fmadd_ps(r, centred, load(&layer.bias[g]));
    }
    out
}

/// Lane-wise products of one weight row with `v`, summed over packs in two chains.
#[inline(always)]
unsafe fn row_dot<const Q: usize>(w: &[Pack<f32>; Q], v: &[__m256; Q]) -> __m256 {
    let mut even = _mm256_mul_ps(load(&w[0]), v[0]);
    if Q == 1 {
        return even;
    }
    let mut odd = _mm256_mul_ps(load(&w[1]), v[1]);
    for q in 2..Q {
        if q % 2 == 0 {
            even = _mm256_fmadd_ps(load(&w[q]), v[q], even);
        } else {
            odd = _mm256_fmadd_ps(load(&w[q]), v[q], odd);
        }
    }
    _mm256_add_ps(even, odd)
}

/// The lane sums of eight registers, as one register: a transposition by single-uop
/// shuffles with adds in between (horizontal adds were slower per layer here).
#[inline(always)]
unsafe fn reduce8(a: [__m256; 8]) -> __m256 {
    let t = [pairs(a[0], a[1]), pairs(a[2], a[3]), pairs(a[4], a[5]), pairs(a[6], a[7])];
    let (u0, u1) = (quads(t[0], t[1]), quads(t[2], t[3]));
    // The two 128-bit halves.
    _mm256_add_ps(_mm256_permute2f128_ps::<0x20>(u0, u1), _mm256_permute2f128_ps::<0x31>(u0, u1))
}

/// Per 128-bit half: `[x0 + x2, y0 + y2, x1 + x3, y1 + y3]`.
#[inline(always)]
unsafe fn pairs(x: __m256, y: __m256) -> __m256 {
    _mm256_add_ps(_mm256_unpacklo_ps(x, y), _mm256_unpackhi_ps(x, y))
}

/// Per 128-bit half, from two [`pairs`] results: the four sums of all four lanes.
#[inline(always)]
unsafe fn quads(x: __m256, y: __m256) -> __m256 {
    _mm256_add_ps(_mm256_shuffle_ps::<0b01_00_01_00>(x, y), _mm256_shuffle_ps::<0b11_10_11_10>(x, y))
}

/// `v[0] + v[1] + ...` lane-wise, as a tree.
#[inline(always)]
unsafe fn tree_sum<const NP: usize>(v: [__m256; NP]) -> __m256 {
    let low = if NP > 1 { _mm256_add_ps(v[0], v[1]) } else { v[0] };
    match NP {
        3 => _mm256_add_ps(low, v[2]),
        4 => _mm256_add_ps(low, _mm256_add_ps(v[2], v[3])),
        _ => low,
    }
}

/// The sum of the lanes of `v` in every lane, by the tree of [`super::kernels::lane_sum`]
/// (every lane adds the same pairs, so all lanes are equal).
#[inline(always)]
unsafe fn lane_sum(v: __m256) -> __m256 {
    let v = _mm256_add_ps(v, _mm256_permute2f128_ps::<0x01>(v, v));
    let v = _mm256_add_ps(v, _mm256_permute_ps::<0b01_00_11_10>(v));
    _mm256_add_ps(v, _mm256_permute_ps::<0b10_11_00_01>(v))
}

/// `ln(1 + e^y)` (`y` above PyTorch's threshold) and, with `deriv`, `sigmoid(y)` (1 above
/// it): the same operations as the generic kernels' softplus, eight lanes at a time.
#[inline(always)]
unsafe fn softplus(y: __m256, deriv: bool) -> (__m256, __m256) {
    let sign = _mm256_set1_ps(-0.0);
    let abs = _mm256_andnot_ps(sign, y);
    let e = exp_nonpositive(_mm256_or_ps(sign, y));
    // max(y, 0) as (y + |y|) / 2, so that a NaN stays a NaN.
    let sp = _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(0.5), _mm256_add_ps(y, abs)), log1p_unit(e));
    let linear = _mm256_cmp_ps::<_CMP_GT_OQ>(y, _mm256_set1_ps(super::activation::SOFTPLUS_THRESHOLD as f32));
    let value = _mm256_blendv_ps(sp, y, linear);
    if !deriv {
        return (value, value);
    }
    let one = _mm256_set1_ps(1.0);
    let numerator = _mm256_blendv_ps(e, one, _mm256_cmp_ps::<_CMP_GE_OQ>(y, _mm256_setzero_ps()));
    let sigmoid = _mm256_div_ps(numerator, _mm256_add_ps(one, e));
    (value, _mm256_blendv_ps(sigmoid, one, linear))
}

/// `Real::exp_nonpositive` for `f32`, lane-wise.
#[inline(always)]
unsafe fn exp_nonpositive(x: __m256) -> __m256 {
    const MAGIC: f32 = 1.5 * (1u32 << 23) as f32;
    let c = super::real::F32_EXP;
    let x = _mm256_max_ps(x, _mm256_set1_ps(super::real::F32_EXP_MIN));
    let t = _mm256_fmadd_ps(x, _mm256_set1_ps(std::f32::consts::LOG2_E), _mm256_set1_ps(MAGIC));
    let k = _mm256_sub_ps(t, _mm256_set1_ps(MAGIC));
    let r = _mm256_fnmadd_ps(k, _mm256_set1_ps(super::real::F32_LN2.0), x);
    let r = _mm256_fnmadd_ps(k, _mm256_set1_ps(super::real::F32_LN2.1), r);
    let r2 = _mm256_mul_ps(r, r);
    let r4 = _mm256_mul_ps(r2, r2);
    let ps = _mm256_set1_ps;
    let lo = _mm256_fmadd_ps(_mm256_fmadd_ps(ps(c[3]), r, ps(c[2])), r2, _mm256_add_ps(r, ps(c[0])));
    let hi = _mm256_fmadd_ps(ps(c[6]), r2, _mm256_fmadd_ps(ps(c[5]), r, ps(c[4])));
    let poly = _mm256_fmadd_ps(hi, r4, lo);
    // 2^k from the low bits of t.
    let bits = _mm256_sub_epi32(_mm256_castps_si256(t), _mm256_set1_epi32(MAGIC.to_bits() as i32 - 127));
    _mm256_mul_ps(poly, _mm256_castsi256_ps(_mm256_slli_epi32::<23>(bits)))
}

/// `Real::log1p_unit` for `f32`, lane-wise.
#[inline(always)]
unsafe fn log1p_unit(e: __m256) -> __m256 {
    let c = super::real::F32_LOG1P;
    let ps = _mm256_set1_ps;
    let e2 = _mm256_mul_ps(e, e);
    let e4 = _mm256_mul_ps(e2, e2);
    let q0 = _mm256_fmadd_ps(ps(c[1]), e, ps(c[0]));
    let q1 = _mm256_fmadd_ps(ps(c[3]), e, ps(c[2]));
    let q2 = _mm256_fmadd_ps(ps(c[5]), e, ps(c[4]));
    let q3 = _mm256_fmadd_ps(ps(c[7]), e, ps(c[6]));
    let r0 = _mm256_fmadd_ps(q1, e2, q0);
    let r1 = _mm256_fmadd_ps(q3, e2, q2);
    let r1 = _mm256_fmadd_ps(ps(c[8]), e4, r1);
    _mm256_mul_ps(e, _mm256_fmadd_ps(r1, e4, r0))
}

#[inline(always)]
unsafe fn load(p: &[f32]) -> __m256 {
    assert!(p.len() >= PACK);
    // Eight readable floats (checked above); `loadu` has no alignment requirement.
    _mm256_loadu_ps(p.as_ptr())
}

#[inline(always)]
unsafe fn store(p: &mut Pack<f32>, v: __m256) {
    // A pack is eight writable floats; `storeu` has no alignment requirement.
    _mm256_storeu_ps(p.as_mut_ptr(), v)
}
