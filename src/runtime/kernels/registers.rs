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
//! The intrinsics need a CPU with AVX2 and FMA: every function here takes an [`Avx2Fma`]
//! token, which only exists where the CPU has them. The helpers are `#[inline(always)]`
//! (which `#[target_feature]` functions cannot be) so that the vectors stay in registers
//! across them; each wraps its intrinsics in one `unsafe` block justified by the token.

use std::arch::x86_64::*;

use super::cpu::Avx2Fma;
use super::fold::Dense;
use super::network::{NetOut, NetScratch, Network};
use super::packs::{PACK, Pack, packs};
use crate::model::Activation;
use crate::types::{Input, NU, State};

/// Packs of the raw network input `[x_seen, u, t]` (at most 9 + 4 + 1 values).
const INPUT_PACKS: usize = 2;

/// Whether `p` can run here: softplus, at most 32 hidden units and 16 raw inputs.
pub fn eligible(p: &Network<f32>) -> bool {
    p.activation == Activation::Softplus && p.packs <= 4 && packs(p.n_in) <= INPUT_PACKS
}

/// The network's raw output for `x`, `u` and time input `t`; with `keep`, also what the
/// reverse pass reads (activation derivatives, normalised vectors, LayerNorm scales) into
/// the workspace, as [`Predictor::network`] does.
///
/// `eligible(p)` must hold (checked in debug builds).
#[inline(always)]
pub fn forward(
    cpu: Avx2Fma,
    p: &Network<f32>,
    ws: &mut NetScratch<f32>,
    x: &State,
    u: &Input,
    t: f64,
    keep: bool,
) -> NetOut {
    // The caller checked it (once per step); the loads below are bounds-checked either way.
    debug_assert!(eligible(p), "register kernel on an ineligible network");
    // SAFETY: `cpu` proves that the CPU has AVX2 and FMA.
    unsafe { network(cpu, p, ws, x, u, t, keep) }
}

/// [`forward`], compiled for AVX2 + FMA.
#[target_feature(enable = "avx2,fma")]
fn network(
    cpu: Avx2Fma,
    p: &Network<f32>,
    ws: &mut NetScratch<f32>,
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
    let z = [load(cpu, &z[..PACK]), load(cpu, &z[PACK..])];
    match (p.packs, packs(p.n_in)) {
        (4, 2) => layers::<4, 2>(cpu, p, ws, &z, keep),
        (4, _) => layers::<4, 1>(cpu, p, ws, &z, keep),
        (3, 2) => layers::<3, 2>(cpu, p, ws, &z, keep),
        (3, _) => layers::<3, 1>(cpu, p, ws, &z, keep),
        (2, 2) => layers::<2, 2>(cpu, p, ws, &z, keep),
        (2, _) => layers::<2, 1>(cpu, p, ws, &z, keep),
        (_, 2) => layers::<1, 2>(cpu, p, ws, &z, keep),
        _ => layers::<1, 1>(cpu, p, ws, &z, keep),
    }
}

/// The forward pass for `NP` packs per hidden layer and `ZQ` input packs.
#[target_feature(enable = "avx2,fma")]
fn layers<const NP: usize, const ZQ: usize>(
    cpu: Avx2Fma,
    p: &Network<f32>,
    ws: &mut NetScratch<f32>,
    z: &[__m256; INPUT_PACKS],
    keep: bool,
) -> NetOut {
    let net = &p.folded;
    let one = _mm256_set1_ps(1.0);
    let mut mask = [one; NP];
    if let Some(m) = &net.mask {
        for q in 0..NP {
            mask[q] = load(cpu, &m[q]);
        }
    }
    let mask = net.mask.as_ref().map(|_| &mask);
    let inv_width = _mm256_set1_ps(net.inv_width);
    // `(r, mean)` of the LayerNorm on the previous layer's output, applied after this
    // layer's product; `(1, 0)` without one leaves `acc + b` exact.
    let mut scale = (one, _mm256_setzero_ps());
    let input: &[__m256; ZQ] = z[..ZQ].try_into().expect("ZQ <= INPUT_PACKS");
    let mut pre: [__m256; NP] = dense::<ZQ, NP>(cpu, &net.hidden[0], input, scale);
    let mut s = [_mm256_setzero_ps(); NP];
    for (l, eps) in net.norm_eps.iter().enumerate() {
        let np = NP * l;
        for q in 0..NP {
            let (v, d) = softplus(cpu, pre[q], keep);
            s[q] = v;
            if keep {
                store(cpu, &mut ws.d[np + q], d);
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
            let mean = _mm256_mul_ps(lane_sum(cpu, tree_sum(cpu, terms)), inv_width);
            for q in 0..NP {
                dev[q] = _mm256_sub_ps(s[q], mean);
                if let Some(mask) = mask {
                    dev[q] = _mm256_mul_ps(dev[q], mask[q]);
                }
                terms[q] = _mm256_mul_ps(dev[q], dev[q]);
            }
            let var =
                _mm256_add_ps(_mm256_mul_ps(lane_sum(cpu, tree_sum(cpu, terms)), inv_width), _mm256_set1_ps(*eps));
            let r = _mm256_div_ps(one, _mm256_sqrt_ps(var));
            scale = (r, mean);
            if keep {
                ws.inv_std[l] = _mm256_cvtss_f32(r);
                for q in 0..NP {
                    store(cpu, &mut ws.xhat[np + q], _mm256_mul_ps(dev[q], r));
                }
            }
        }
        if let Some(next) = net.hidden.get(l + 1) {
            pre = dense::<NP, NP>(cpu, next, &s, scale);
        }
    }
    // Output rows 0..8 as a group, row 8 on its own (not with seven padding rows).
    let [o] = dense::<NP, 1>(cpu, &net.output, &s, scale);
    let last: &[Pack<f32>; NP] = net.output.rev[PACK * NP..(PACK + 1) * NP].try_into().expect("output row 8");
    let centred = _mm256_fnmadd_ps(scale.1, load(cpu, &net.output.row_sum[1]), lane_sum(cpu, row_dot(cpu, last, &s)));
    let o8 = _mm256_cvtss_f32(_mm256_fmadd_ps(scale.0, centred, load(cpu, &net.output.bias[1])));
    let mut out = [0.0_f32; PACK];
    store(cpu, &mut out, o);
    std::array::from_fn(|k| f64::from(if k < PACK { out[k] } else { o8 }))
}

/// `r (W v - mean (W 1)) + b` for the first `8 NO` rows of `layer` (reverse layout, `Q`
/// packs per row): the dense layer after a LayerNorm with `(r, mean)` on `v`. `r` comes
/// last (it waits on a square root and a division), so it enters the last operation.
#[inline(always)]
fn dense<const Q: usize, const NO: usize>(
    cpu: Avx2Fma,
    layer: &Dense<f32>,
    v: &[__m256; Q],
    (r, mean): (__m256, __m256),
) -> [__m256; NO] {
    // SAFETY: `cpu` proves that the CPU has AVX2 and FMA.
    unsafe {
        let rows: &[[Pack<f32>; Q]] = layer.rev.as_chunks::<Q>().0;
        let groups: &[[[Pack<f32>; Q]; PACK]] = rows.as_chunks::<PACK>().0;
        assert!(groups.len() >= NO && layer.bias.len() >= NO && layer.row_sum.len() >= NO, "layer shape");
        let mut out = [_mm256_setzero_ps(); NO];
        for g in 0..NO {
            let mut rows = [_mm256_setzero_ps(); PACK];
            for k in 0..PACK {
                rows[k] = row_dot(cpu, &groups[g][k], v);
            }
            let centred = _mm256_fnmadd_ps(mean, load(cpu, &layer.row_sum[g]), reduce8(cpu, rows));
            out[g] = _mm256_fmadd_ps(r, centred, load(cpu, &layer.bias[g]));
        }
        out
    }
}

/// Lane-wise products of one weight row with `v`, summed over packs in two chains.
#[inline(always)]
fn row_dot<const Q: usize>(cpu: Avx2Fma, w: &[Pack<f32>; Q], v: &[__m256; Q]) -> __m256 {
    // SAFETY: `cpu` proves that the CPU has AVX2 and FMA.
    unsafe {
        let mut even = _mm256_mul_ps(load(cpu, &w[0]), v[0]);
        if Q == 1 {
            return even;
        }
        let mut odd = _mm256_mul_ps(load(cpu, &w[1]), v[1]);
        for q in 2..Q {
            if q % 2 == 0 {
                even = _mm256_fmadd_ps(load(cpu, &w[q]), v[q], even);
            } else {
                odd = _mm256_fmadd_ps(load(cpu, &w[q]), v[q], odd);
            }
        }
        _mm256_add_ps(even, odd)
    }
}

/// The lane sums of eight registers, as one register: a transposition by single-uop
/// shuffles with adds in between (horizontal adds were slower per layer here).
#[inline(always)]
fn reduce8(cpu: Avx2Fma, a: [__m256; 8]) -> __m256 {
    // SAFETY: `cpu` proves that the CPU has AVX2 and FMA.
    unsafe {
        let t = [pairs(cpu, a[0], a[1]), pairs(cpu, a[2], a[3]), pairs(cpu, a[4], a[5]), pairs(cpu, a[6], a[7])];
        let (u0, u1) = (quads(cpu, t[0], t[1]), quads(cpu, t[2], t[3]));
        // The two 128-bit halves.
        _mm256_add_ps(_mm256_permute2f128_ps::<0x20>(u0, u1), _mm256_permute2f128_ps::<0x31>(u0, u1))
    }
}

/// Per 128-bit half: `[x0 + x2, y0 + y2, x1 + x3, y1 + y3]`.
#[inline(always)]
fn pairs(_cpu: Avx2Fma, x: __m256, y: __m256) -> __m256 {
    // SAFETY: the token proves that the CPU has AVX2 and FMA.
    unsafe { _mm256_add_ps(_mm256_unpacklo_ps(x, y), _mm256_unpackhi_ps(x, y)) }
}

/// Per 128-bit half, from two [`pairs`] results: the four sums of all four lanes.
#[inline(always)]
fn quads(_cpu: Avx2Fma, x: __m256, y: __m256) -> __m256 {
    // SAFETY: the token proves that the CPU has AVX2 and FMA.
    unsafe { _mm256_add_ps(_mm256_shuffle_ps::<0b01_00_01_00>(x, y), _mm256_shuffle_ps::<0b11_10_11_10>(x, y)) }
}

/// `v[0] + v[1] + ...` lane-wise, as a tree.
#[inline(always)]
fn tree_sum<const NP: usize>(_cpu: Avx2Fma, v: [__m256; NP]) -> __m256 {
    // SAFETY: the token proves that the CPU has AVX2 and FMA.
    unsafe {
        let low = if NP > 1 { _mm256_add_ps(v[0], v[1]) } else { v[0] };
        match NP {
            3 => _mm256_add_ps(low, v[2]),
            4 => _mm256_add_ps(low, _mm256_add_ps(v[2], v[3])),
            _ => low,
        }
    }
}

/// The sum of the lanes of `v` in every lane, by the tree of [`super::packs::lane_sum`]
/// (every lane adds the same pairs, so all lanes are equal).
#[inline(always)]
fn lane_sum(_cpu: Avx2Fma, v: __m256) -> __m256 {
    // SAFETY: the token proves that the CPU has AVX2 and FMA.
    unsafe {
        let v = _mm256_add_ps(v, _mm256_permute2f128_ps::<0x01>(v, v));
        let v = _mm256_add_ps(v, _mm256_permute_ps::<0b01_00_11_10>(v));
        _mm256_add_ps(v, _mm256_permute_ps::<0b10_11_00_01>(v))
    }
}

/// `ln(1 + e^y)` (`y` above PyTorch's threshold) and, with `deriv`, `sigmoid(y)` (1 above
/// it): the same operations as the generic kernels' softplus, eight lanes at a time.
#[inline(always)]
fn softplus(cpu: Avx2Fma, y: __m256, deriv: bool) -> (__m256, __m256) {
    // SAFETY: `cpu` proves that the CPU has AVX2 and FMA.
    unsafe {
        let sign = _mm256_set1_ps(-0.0);
        let abs = _mm256_andnot_ps(sign, y);
        let e = exp_nonpositive(cpu, _mm256_or_ps(sign, y));
        // max(y, 0) as (y + |y|) / 2, so that a NaN stays a NaN.
        let sp = _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(0.5), _mm256_add_ps(y, abs)), log1p_unit(cpu, e));
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
}

/// `Real::exp_nonpositive` for `f32`, lane-wise.
#[inline(always)]
fn exp_nonpositive(_cpu: Avx2Fma, x: __m256) -> __m256 {
    // SAFETY: the token proves that the CPU has AVX2 and FMA.
    unsafe {
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
}

/// `Real::log1p_unit` for `f32`, lane-wise.
#[inline(always)]
fn log1p_unit(_cpu: Avx2Fma, e: __m256) -> __m256 {
    // SAFETY: the token proves that the CPU has AVX2 and FMA.
    unsafe {
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
}

#[inline(always)]
fn load(_cpu: Avx2Fma, p: &[f32]) -> __m256 {
    assert!(p.len() >= PACK);
    // SAFETY: the token proves that the CPU has AVX2; eight floats are readable (asserted
    // above) and `loadu` has no alignment requirement.
    unsafe { _mm256_loadu_ps(p.as_ptr()) }
}

#[inline(always)]
fn store(_cpu: Avx2Fma, p: &mut Pack<f32>, v: __m256) {
    // SAFETY: the token proves that the CPU has AVX2; a pack is eight writable floats and
    // `storeu` has no alignment requirement.
    unsafe { _mm256_storeu_ps(p.as_mut_ptr(), v) }
}
