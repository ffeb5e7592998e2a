//! Builders shared by the integration tests.
#![allow(dead_code)]

use pinc::model::{
    Activation, Affine, Architecture, Envelope, HiddenLayer, LayerNormWeights, Linear, PincModel, Provenance, Weights,
};

/// A small deterministic generator (SplitMix64), so tests need no RNG crate.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [-1, 1).
    pub fn sym(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

fn linear(rng: &mut Rng, rows: usize, cols: usize) -> Linear {
    let limit = (6.0 / (rows + cols) as f64).sqrt();
    Linear {
        rows,
        cols,
        weight: (0..rows * cols).map(|_| (rng.sym() * limit) as f32).collect(),
        bias: (0..rows).map(|_| (rng.sym() * 0.1) as f32).collect(),
    }
}

/// A model with random Xavier-scaled weights for `arch`, betas cycling through
/// 1.0, -0.9, 1.7, 0.5 (negative betas occur in trained checkpoints).
pub fn random_model(arch: Architecture, seed: u64) -> PincModel {
    let mut rng = Rng(seed);
    let betas = [1.0, -0.9, 1.7, 0.5];
    let hidden = (0..arch.hidden_layers)
        .map(|l| {
            let cols = if l == 0 { arch.input_size() } else { arch.width };
            HiddenLayer {
                linear: linear(&mut rng, arch.width, cols),
                beta: betas[l % 4],
                layer_norm: arch.layer_norm[l].then(|| LayerNormWeights {
                    gain: (0..arch.width).map(|_| (1.0 + 0.1 * rng.sym()) as f32).collect(),
                    bias: (0..arch.width).map(|_| (0.1 * rng.sym()) as f32).collect(),
                    eps: 1e-5,
                }),
            }
        })
        .collect();
    // Trained networks predict small increments; small output weights keep random ones
    // from diverging over a horizon.
    let mut output = linear(&mut rng, 9, arch.width);
    output.weight.iter_mut().for_each(|w| *w *= 0.1);
    PincModel {
        dt: 0.08,
        input_scaling: None,
        output_scaling: None,
        envelope: None,
        provenance: Provenance { source: "test".into(), ..Provenance::default() },
        weights: Weights { hidden, output },
        vehicle: pinc::vehicle::VehicleParams::default(),
        hybrid: None,
        fitted: None,
        architecture: arch,
    }
}

/// `m` as a hybrid model: a vehicle other than the BlueROV2 (heavier, 20 % more damping, a
/// little buoyant) integrated in `substeps` RK4 sub-steps, corrected by `m`'s network.
pub fn hybrid(mut m: PincModel, substeps: u32) -> PincModel {
    let mut v = pinc::vehicle::VehicleParams::default().with_damping_scaled(1.2);
    v.m = 12.1;
    v.izz = 0.3;
    m.vehicle = v;
    m.hybrid = Some(pinc::model::HybridPhysics { substeps, rest_anchored: false });
    m
}

/// `m` as a hybrid anchored at rest (its network must see the body velocities only).
pub fn anchored(m: PincModel) -> PincModel {
    let mut m = hybrid(m, 8);
    m.hybrid = Some(pinc::model::HybridPhysics { substeps: 8, rest_anchored: true });
    m
}

/// The paper's 4 x 32 architecture with random weights.
pub fn paper_4x32(seed: u64) -> PincModel {
    random_model(Architecture::paper(4, 32), seed)
}

/// Scalings and an envelope, to exercise every code path.
pub fn with_extras(mut m: PincModel) -> PincModel {
    let n = m.architecture.input_size();
    m.input_scaling = Some(Affine {
        mean: (0..n).map(|i| 0.01 * i as f64).collect(),
        std: (0..n).map(|i| 0.5 + 0.1 * i as f64).collect(),
    });
    m.output_scaling = Some(Affine { mean: vec![0.001; 9], std: (0..9).map(|i| 0.05 + 0.01 * i as f64).collect() });
    m.envelope = Some(Envelope {
        state_min: [-1.0, -1.0, -1.0, -1.5, -1.5, -1.0, -1.0, -1.0, -1.0],
        state_max: [1.0, 1.0, 2.0, 1.5, 1.5, 1.0, 1.0, 1.0, 1.0],
        input_min: [-10.0, -5.0, -5.0, -1.0],
        input_max: [10.0, 5.0, 20.0, 1.0],
    });
    m
}

/// Every architecture variant the runtime supports.
pub fn variants() -> Vec<(&'static str, PincModel)> {
    let paper = Architecture::paper(4, 32);
    let mut no_res = paper.clone();
    no_res.residual = false;
    let mut no_rot = paper.clone();
    no_rot.rotate_xy = false;
    let mut tanh = Architecture::paper(3, 16);
    tanh.activation = Activation::Tanh;
    let mut no_pos = Architecture::paper(2, 24);
    no_pos.state_inputs = vec![3, 4, 5, 6, 7, 8];
    let no_pos_hybrid = no_pos.clone();
    let mut velocities = Architecture::paper(3, 16);
    velocities.state_inputs = vec![5, 6, 7, 8];
    let mut no_ln = Architecture::paper(3, 20);
    no_ln.layer_norm = vec![false; 3];
    // 13 units: the last pack of 8 is padded; LayerNorm after the negative beta of layer 2.
    let mut all_ln = Architecture::paper(3, 13);
    all_ln.layer_norm = vec![true; 3];
    vec![
        ("paper 4x32", random_model(paper, 1)),
        ("paper 4x32 scaled", with_extras(random_model(Architecture::paper(4, 32), 2))),
        ("no residual", random_model(no_res, 3)),
        ("no rotation", random_model(no_rot, 4)),
        ("tanh 3x16", random_model(tanh, 5)),
        ("position-free 2x24", with_extras(random_model(no_pos, 6))),
        ("no LayerNorm 3x20", random_model(no_ln, 7)),
        ("LayerNorm everywhere 3x13", with_extras(random_model(all_ln, 8))),
        ("hybrid 4x32", hybrid(random_model(Architecture::paper(4, 32), 9), 16)),
        ("hybrid position-free 2x24 scaled", hybrid(with_extras(random_model(no_pos_hybrid, 10)), 5)),
        ("hybrid velocities-only anchored at rest 3x16 scaled", anchored(with_extras(random_model(velocities, 11)))),
    ]
}

/// The network's output (scaled back) at `x`, `u`, `t`, written out plainly.
fn network_output(m: &PincModel, x: &[f64; 9], u: &[f64; 4], t: f64) -> Vec<f64> {
    let arch = &m.architecture;
    let mut a: Vec<f64> = arch.state_inputs.iter().map(|&i| x[i as usize]).chain(u.iter().copied()).collect();
    a.push(t);
    if let Some(s) = &m.input_scaling {
        a = a.iter().zip(s.mean.iter().zip(&s.std)).map(|(v, (mu, sd))| (v - mu) / sd).collect();
    }
    let dense = |l: &Linear, a: &[f64]| -> Vec<f64> {
        (0..l.rows)
            .map(|j| {
                f64::from(l.bias[j]) + (0..l.cols).map(|i| f64::from(l.weight[j * l.cols + i]) * a[i]).sum::<f64>()
            })
            .collect()
    };
    for h in &m.weights.hidden {
        let beta = f64::from(h.beta);
        a = dense(&h.linear, &a)
            .into_iter()
            .map(|v| match arch.activation {
                Activation::Softplus if beta * v > 20.0 => v,
                Activation::Softplus => (1.0 + (beta * v).exp()).ln() / beta,
                Activation::Tanh => (beta * v).tanh(),
            })
            .collect();
        if let Some(n) = &h.layer_norm {
            let w = a.len() as f64;
            let mean = a.iter().sum::<f64>() / w;
            let var = a.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / w;
            let sd = (var + f64::from(n.eps)).sqrt();
            a = a
                .iter()
                .enumerate()
                .map(|(j, v)| (v - mean) / sd * f64::from(n.gain[j]) + f64::from(n.bias[j]))
                .collect();
        }
    }
    let mut o = dense(&m.weights.output, &a);
    if let Some(s) = &m.output_scaling {
        o = o.iter().enumerate().map(|(k, v)| v * s.std[k] + s.mean[k]).collect();
    }
    o
}

/// One step of `m` computed the plain way, in f64, straight from the definition in docs/MODEL.md
/// (input scaling, Linear, `softplus(beta h) / beta` with torch's threshold or
/// `tanh(beta h)`, LayerNorm with gain and bias, output layer and scaling, residual, planar
/// increments rotated by the predicted yaw, then `(cos psi, sin psi)` rescaled to unit length
/// as the runtime does by default; a hybrid anchored at rest less its output at rest): the reference the runtime's folded, packed kernels are
/// checked against.
pub fn reference_step(m: &PincModel, x: &[f64; 9], u: &[f64; 4], t: f64) -> [f64; 9] {
    let arch = &m.architecture;
    let mut o = network_output(m, x, u, t);
    // Anchored at rest: the output less the output at rest over the same step.
    if m.hybrid.is_some_and(|h| h.rest_anchored) {
        let rest = network_output(m, &[0.0; 9], &m.rest_input().into(), t);
        o.iter_mut().zip(rest).for_each(|(o, r)| *o -= r);
    }
    let mut next = match (&m.hybrid, arch.residual) {
        // A hybrid's base: the vehicle's RK4 step over `t` in `substeps` equal parts.
        (Some(h), _) => {
            let f = |x: &pinc::State| pinc::vehicle::rhs(&m.vehicle, x, &pinc::Input::from(*u));
            let n = h.substeps as usize;
            pinc::vehicle::rk4(f, pinc::State::from(*x), t / n as f64, n).into()
        }
        (None, true) => *x,
        (None, false) => [0.0; 9],
    };
    let (c, s) = (next[3] + o[3], next[4] + o[4]);
    let (dx, dy) = if arch.rotate_xy { (c * o[0] - s * o[1], s * o[0] + c * o[1]) } else { (o[0], o[1]) };
    next[0] += dx;
    next[1] += dy;
    for k in 2..9 {
        next[k] += o[k];
    }
    let norm = (next[3] * next[3] + next[4] * next[4]).sqrt();
    next[3] /= norm;
    next[4] /= norm;
    next
}

/// The default MPC configuration without Clarabel's time limit: a loaded machine can stretch
/// a 1 ms solve past the 40 ms default (seen once: 41.7 ms) and turn it into a fallback.
/// Tests that expect no fallbacks are about tracking and solver failures; timing is measured
/// in `benches/mpc.rs`.
#[cfg(feature = "mpc")]
pub fn untimed() -> pinc::mpc::MpcConfig {
    pinc::mpc::MpcConfig { solver_time_limit: f64::INFINITY, ..pinc::mpc::MpcConfig::default() }
}
