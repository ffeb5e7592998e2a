//! The kernels against plain scalar loops: every block width and remainder branch of the
//! matrix products, the reductions, the activations and the folded network.

use super::activation::activate;
use super::packs::{Fused, MulAdd, PACK, Pack, Portable, dot, lane_sum, matvec, matvec_rows, sum};
use super::{Avx2Fma, NetScratch, Network, Real};
use crate::model::{
    Activation, Affine, Architecture, HiddenLayer, LayerNormWeights, Linear, PincModel, Provenance, Weights,
};
use crate::types::{Input, State};

/// Deterministic values in [-1, 1) (SplitMix64), so the tests need no RNG crate.
struct Values(u64);
impl Values {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
    fn packs<T: Real>(&mut self, n: usize) -> Vec<Pack<T>> {
        (0..n).map(|_| std::array::from_fn(|_| T::from_f64(self.next()))).collect()
    }
}

/// `sum_i coef[i] mat[i][p]` per output pack, in f64, one multiply-add at a time.
fn scalar_matvec<T: Real>(coef: &[T], mat: &[Pack<T>], stride: usize, out_packs: usize) -> Vec<f64> {
    (0..out_packs * PACK)
        .map(|j| (0..coef.len()).map(|i| coef[i].to_f64() * mat[i * stride + j / PACK][j % PACK].to_f64()).sum::<f64>())
        .collect()
}

fn close(found: f64, expected: f64, tol: f64, what: &str) {
    assert!((found - expected).abs() <= tol * (1.0 + expected.abs()), "{what}: {found} vs {expected}");
}

/// Every output-pack count from 1 to 9 (blocks of 4, 2 and 1 and their remainders), even
/// and odd coefficient counts (the unpaired last coefficient), and a stride wider than the
/// output.
fn check_matvec<F: MulAdd, T: Real>(tol: f64) {
    let mut v = Values(1);
    for out_packs in 1..=9 {
        for n_coef in [1, 2, 7, 8, 13] {
            let stride = out_packs + 1;
            let mat = v.packs::<T>(n_coef * stride);
            let coef: Vec<T> = (0..n_coef).map(|_| T::from_f64(v.next())).collect();
            let mut out = vec![[T::ZERO; PACK]; out_packs];
            matvec::<F, T>(&mut out, &coef, &mat, stride);
            let expected = scalar_matvec(&coef, &mat, stride, out_packs);
            for (j, e) in expected.iter().enumerate() {
                close(out[j / PACK][j % PACK].to_f64(), *e, tol, &format!("matvec {out_packs}x{n_coef} unit {j}"));
            }
        }
    }
}

fn check_matvec_rows<F: MulAdd, T: Real, const R: usize>(tol: f64) {
    let mut v = Values(2);
    for out_packs in 1..=9 {
        let n_coef = 11;
        let mat = v.packs::<T>(n_coef * out_packs);
        let coefs: Vec<Vec<T>> = (0..R).map(|_| (0..n_coef).map(|_| T::from_f64(v.next())).collect()).collect();
        let mut outs: Vec<Vec<Pack<T>>> = (0..R).map(|_| vec![[T::ZERO; PACK]; out_packs]).collect();
        let mut refs = outs.iter_mut();
        let out: [&mut [Pack<T>]; R] = std::array::from_fn(|_| &mut refs.next().unwrap()[..]);
        matvec_rows::<F, T, R>(out, std::array::from_fn(|r| &coefs[r][..]), &mat, out_packs);
        for r in 0..R {
            let expected = scalar_matvec(&coefs[r], &mat, out_packs, out_packs);
            for (j, e) in expected.iter().enumerate() {
                close(outs[r][j / PACK][j % PACK].to_f64(), *e, tol, &format!("matvec_rows<{R}> {out_packs} row {r}"));
            }
        }
    }
}

#[test]
fn matrix_products_equal_a_scalar_loop_for_every_block_and_remainder() {
    check_matvec::<Portable, f64>(1e-14);
    check_matvec::<Fused, f64>(1e-14);
    check_matvec::<Portable, f32>(1e-5);
    check_matvec::<Fused, f32>(1e-5);
    check_matvec_rows::<Portable, f64, 1>(1e-14);
    check_matvec_rows::<Fused, f64, 2>(1e-14);
    check_matvec_rows::<Portable, f32, 2>(1e-5);
    check_matvec_rows::<Fused, f32, 4>(1e-5);
}

#[test]
fn reductions_equal_a_scalar_loop() {
    let mut v = Values(3);
    for n in 1..6 {
        let a = v.packs::<f64>(n);
        let b = v.packs::<f64>(n);
        let flat = |p: &[Pack<f64>]| p.as_flattened().to_vec();
        close(sum(&a), flat(&a).iter().sum(), 1e-14, "sum");
        let d: f64 = flat(&a).iter().zip(flat(&b)).map(|(x, y)| x * y).sum();
        close(dot::<Portable, f64>(&a, &b), d, 1e-14, "dot");
        close(dot::<Fused, f64>(&a, &b), d, 1e-14, "dot (fused)");
        close(lane_sum(a[0]), a[0].iter().sum(), 1e-14, "lane_sum");
    }
}

#[test]
fn activations_equal_their_definitions_across_the_range() {
    // Four packs and one more: the block of four and the single-pack remainder.
    let ys: Vec<f64> = (0..40).map(|i| -30.0 + 1.5 * i as f64).collect();
    let pre: Vec<Pack<f64>> = ys.chunks(PACK).map(|c| std::array::from_fn(|t| c[t])).collect();
    for act in [Activation::Softplus, Activation::Tanh] {
        let mut out = vec![[0.0; PACK]; pre.len()];
        let mut d = vec![[0.0; PACK]; pre.len()];
        activate::<Portable, f64>(act, &pre, &mut out, Some(&mut d));
        for (i, &y) in ys.iter().enumerate() {
            let (value, slope) = match act {
                // PyTorch's softplus is linear above its threshold of 20.
                Activation::Softplus if y > 20.0 => (y, 1.0),
                Activation::Softplus => ((1.0 + y.exp()).ln(), 1.0 / (1.0 + (-y).exp())),
                Activation::Tanh => (y.tanh(), 1.0 - y.tanh().powi(2)),
            };
            close(out[i / PACK][i % PACK], value, 1e-14, &format!("{act:?}({y})"));
            close(d[i / PACK][i % PACK], slope, 1e-14, &format!("{act:?}'({y})"));
        }
    }
}

/// A 3 x 13 network with input and output scalings, a negative beta and LayerNorm after
/// every layer (13 units: the last pack is padding, which the statistics must skip).
fn model() -> PincModel {
    model_with(4, &[true, false, true], 13, &[0, 1, 2, 3, 4, 5, 6, 7, 8])
}

/// A network of `norms.len()` softplus layers of `width` units, LayerNorm where `norms`
/// says, seeing the states `seen`, with input and output scalings and betas of either sign.
fn model_with(seed: u64, norms: &[bool], width: usize, seen: &[u8]) -> PincModel {
    let mut v = Values(seed);
    let layers = norms.len();
    let mut arch = Architecture::paper(layers, width);
    arch.layer_norm = norms.to_vec();
    arch.state_inputs = seen.to_vec();
    let n_in = arch.input_size();
    let linear = |v: &mut Values, rows: usize, cols: usize| Linear {
        rows,
        cols,
        weight: (0..rows * cols).map(|_| (0.5 * v.next()) as f32).collect(),
        bias: (0..rows).map(|_| (0.1 * v.next()) as f32).collect(),
    };
    let hidden = (0..layers)
        .map(|l| HiddenLayer {
            linear: linear(&mut v, width, if l == 0 { n_in } else { width }),
            beta: [1.3, -0.8, 0.6, 2.1][l % 4],
            layer_norm: arch.layer_norm[l].then(|| LayerNormWeights {
                gain: (0..width).map(|_| (1.0 + 0.2 * v.next()) as f32).collect(),
                bias: (0..width).map(|_| (0.1 * v.next()) as f32).collect(),
                eps: 1e-5,
            }),
        })
        .collect();
    let output = linear(&mut v, 9, width);
    PincModel {
        dt: 0.08,
        input_scaling: Some(Affine {
            mean: (0..n_in).map(|i| 0.1 * i as f64).collect(),
            std: (0..n_in).map(|i| 0.5 + 0.2 * i as f64).collect(),
        }),
        output_scaling: Some(Affine { mean: vec![0.01; 9], std: (0..9).map(|k| 0.1 + 0.05 * k as f64).collect() }),
        envelope: None,
        provenance: Provenance::default(),
        weights: Weights { hidden, output },
        vehicle: crate::vehicle::VehicleParams::default(),
        hybrid: None,
        fitted: None,
        architecture: arch,
    }
}

/// The raw network output, unfolded, in f64: scale the input, then per layer `W a + b`,
/// `softplus(beta h) / beta`, LayerNorm with gain and bias; output layer and scaling.
fn plain_output(m: &PincModel, z: &[f64]) -> Vec<f64> {
    let s = m.input_scaling.as_ref().unwrap();
    let mut a: Vec<f64> = z.iter().zip(s.mean.iter().zip(&s.std)).map(|(v, (mu, sd))| (v - mu) / sd).collect();
    let dense = |l: &Linear, a: &[f64]| -> Vec<f64> {
        (0..l.rows)
            .map(|j| {
                f64::from(l.bias[j]) + (0..l.cols).map(|i| f64::from(l.weight[j * l.cols + i]) * a[i]).sum::<f64>()
            })
            .collect()
    };
    for h in &m.weights.hidden {
        let beta = f64::from(h.beta);
        a = dense(&h.linear, &a).iter().map(|v| (1.0 + (beta * v).exp()).ln() / beta).collect();
        if let Some(n) = &h.layer_norm {
            let w = a.len() as f64;
            let mean = a.iter().sum::<f64>() / w;
            let sd = (a.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / w + f64::from(n.eps)).sqrt();
            a = a
                .iter()
                .enumerate()
                .map(|(j, v)| (v - mean) / sd * f64::from(n.gain[j]) + f64::from(n.bias[j]))
                .collect();
        }
    }
    let o = m.output_scaling.as_ref().unwrap();
    dense(&m.weights.output, &a).iter().enumerate().map(|(k, v)| v * o.std[k] + o.mean[k]).collect()
}

#[test]
fn the_folded_network_computes_the_unfolded_one() {
    let m = model();
    let x = State::from([0.3, -0.2, 1.1, 0.8, 0.6, 0.4, -0.1, 0.2, 0.05]);
    let u = Input::new(3.0, -1.0, 6.0, 0.3);
    let z: Vec<f64> = x.iter().chain(u.iter()).copied().chain([0.08]).collect();
    let expected = plain_output(&m, &z);
    let net64 = Network::<f64>::new(&m);
    let mut ws64 = NetScratch::new(&net64);
    let net32 = Network::<f32>::new(&m);
    let mut ws32 = NetScratch::new(&net32);
    for (k, e) in expected.iter().enumerate() {
        let o = net64.forward::<Portable>(None, &mut ws64, &x, &u, 0.08, false);
        close(o[k], *e, 1e-12, &format!("f64 output {k}"));
        // The register kernel where this CPU has one, the generic f32 kernel otherwise.
        let o = net32.forward::<Fused>(Avx2Fma::detect(), &mut ws32, &x, &u, 0.08, false);
        close(o[k], *e, 1e-5, &format!("f32 output {k}"));
    }
}

/// The register kernel's networks: every width in packs (1 to 4, with and without padding),
/// one and two input packs, LayerNorm after none, some and every layer.
fn register_networks() -> Vec<PincModel> {
    let all: &[u8] = &[0, 1, 2, 3, 4, 5, 6, 7, 8];
    vec![
        model_with(11, &[false, true, false, true], 32, &[3, 4, 5, 6, 7, 8]),
        model_with(12, &[true, true, true, true], 32, all),
        model_with(13, &[false, false, false], 32, &[5, 6, 7]),
        model_with(14, &[true, false, true], 13, all),
        model_with(15, &[true, true], 24, &[7, 8]),
        model_with(16, &[false, true], 16, all),
        model_with(17, &[true], 8, &[3, 4, 5]),
        model_with(18, &[false, true, true, false], 29, all),
    ]
}

/// What an `f32` forward pass with `keep` leaves for the reverse pass and returns, as bits
/// per network and input: the 9 outputs and a hash (FNV-1a) of the kept buffers.
fn forward_bits() -> String {
    let mut v = Values(19);
    let mut text = String::new();
    for (n, m) in register_networks().iter().enumerate() {
        let net = Network::<f32>::new(m);
        let mut ws = NetScratch::new(&net);
        for _ in 0..6 {
            let x = State::from_fn(|_, _| 2.0 * v.next());
            let u = Input::from_fn(|_, _| 8.0 * v.next());
            let t = 0.08 * (1.0 + v.next());
            let o = net.forward::<Fused>(Avx2Fma::detect(), &mut ws, &x, &u, t, true);
            let kept = ws.d.iter().chain(&ws.xhat).flatten().chain(&ws.inv_std);
            let hash =
                kept.fold(0xcbf2_9ce4_8422_2325_u64, |h, v| (h ^ u64::from(v.to_bits())).wrapping_mul(0x100_0000_01b3));
            let outs: Vec<String> = o.iter().map(|v| format!("{:016x}", v.to_bits())).collect();
            text += &format!("{n} {} {hash:016x}\n", outs.join(" "));
        }
    }
    text
}

/// The register kernel gives, bit for bit, what the kernel of 01013ca gave
/// (`tests/fixtures/register_kernel_bits.txt`, written with `PINC_WRITE_KERNEL_BITS=1`): a
/// faster schedule of the same arithmetic must not change a prediction. On a CPU without
/// AVX2 + FMA the generic kernels run, which round differently: nothing to compare.
#[test]
fn the_register_kernel_keeps_its_bits() {
    if Avx2Fma::detect().is_none() {
        return;
    }
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/register_kernel_bits.txt");
    let found = forward_bits();
    if std::env::var_os("PINC_WRITE_KERNEL_BITS").is_some() {
        std::fs::write(path, &found).unwrap();
    }
    let expected = std::fs::read_to_string(path).unwrap();
    for (k, (f, e)) in found.lines().zip(expected.lines()).enumerate() {
        assert_eq!(f, e, "network and input {k}: outputs and kept buffers' hash");
    }
    assert_eq!(found.lines().count(), expected.lines().count());
}
