//! The PINC network on burn, with the forward-mode tangent `d x_hat / d t` carried through
//! every layer as ordinary tensor ops (burn has no double backward, so reverse mode must
//! differentiate through the tangent for the physics loss).

use super::hybrid::{Hybrid, physics_step};
use super::physics::rhs;
use super::to_f32;
use crate::model::{Activation, Architecture, HiddenLayer, LayerNormWeights, Linear, PincModel, Weights};
use crate::types::{NU, NX};
use burn::module::{Module, Param};
use burn::prelude::*;
use burn::tensor::activation;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// LayerNorm epsilon, as PyTorch's default.
pub const LAYER_NORM_EPS: f64 = 1e-5;

/// The network `x_hat(t) = x + N([x_seen, u, t])` with adaptive activations, hand-written
/// LayerNorm, residual and yaw rotation (docs/MODEL.md section 3).
#[derive(Module, Debug)]
pub struct PincNet {
    /// Hidden weights, `[in, width]` (so the forward pass is `a W`).
    hidden_w: Vec<Param<Tensor<2>>>,
    hidden_b: Vec<Param<Tensor<1>>>,
    /// One learnable slope per hidden layer, shape `[1]`.
    betas: Vec<Param<Tensor<1>>>,
    /// Gains and biases of the LayerNorms, in layer order (only layers that have one).
    ln_gain: Vec<Param<Tensor<1>>>,
    ln_bias: Vec<Param<Tensor<1>>>,
    /// Output weights `[width, 9]`.
    out_w: Param<Tensor<2>>,
    out_b: Param<Tensor<1>>,
    #[module(skip)]
    arch: Architecture,
    /// A hybrid's physics: the network's output corrects its step instead of the state.
    #[module(skip)]
    hybrid: Option<Hybrid>,
}

/// A forward pass: the prediction and, if asked for, its time derivative.
pub struct Prediction {
    /// `x_hat(t)`, `[N, 9]`.
    pub state: Tensor<2>,
    /// `d x_hat / d t`, `[N, 9]`, when the tangent was propagated.
    pub rate: Option<Tensor<2>>,
}

fn param2(data: Vec<f32>, dims: [usize; 2], device: &Device) -> Param<Tensor<2>> {
    Param::from_data(TensorData::new(data, dims), device)
}

fn param1(data: Vec<f32>, device: &Device) -> Param<Tensor<1>> {
    let n = data.len();
    Param::from_data(TensorData::new(data, [n]), device)
}

impl PincNet {
    /// A freshly initialised network: Xavier-uniform weights drawn from a ChaCha8 stream
    /// seeded with `seed` (reproducible on every backend), zero biases, betas 1, LayerNorm
    /// gains 1 and biases 0.
    pub fn init(arch: &Architecture, seed: u64, device: &Device) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut xavier = |fan_in: usize, fan_out: usize| -> Vec<f32> {
            let limit = (6.0 / (fan_in + fan_out) as f64).sqrt();
            (0..fan_in * fan_out).map(|_| rng.random_range(-limit..limit) as f32).collect()
        };
        let w = arch.width;
        let mut hidden_w = Vec::new();
        let mut hidden_b = Vec::new();
        for l in 0..arch.hidden_layers {
            let fan_in = if l == 0 { arch.input_size() } else { w };
            hidden_w.push(param2(xavier(fan_in, w), [fan_in, w], device));
            hidden_b.push(param1(vec![0.0; w], device));
        }
        let n_ln = arch.layer_norm.iter().filter(|b| **b).count();
        Self {
            hidden_w,
            hidden_b,
            betas: (0..arch.hidden_layers).map(|_| param1(vec![1.0], device)).collect(),
            ln_gain: (0..n_ln).map(|_| param1(vec![1.0; w], device)).collect(),
            ln_bias: (0..n_ln).map(|_| param1(vec![0.0; w], device)).collect(),
            out_w: param2(xavier(w, NX), [w, NX], device),
            out_b: param1(vec![0.0; NX], device),
            arch: arch.clone(),
            hybrid: None,
        }
    }

    /// This network as the correction of a hybrid model on `physics`: its output layer set to
    /// zero, so that the model starts as the physics exactly (docs/MODEL.md section 13).
    ///
    /// # Panics
    /// If the architecture is not residual (a hybrid's correction adds to the physics' step),
    /// or a correction anchored at rest would see the position or heading.
    #[must_use]
    pub fn into_hybrid(mut self, physics: Hybrid) -> Self {
        assert!(self.arch.residual, "a hybrid network is residual");
        assert!(
            !physics.physics.rest_anchored || self.arch.state_inputs.iter().all(|&i| i >= 5),
            "a correction anchored at rest sees the body velocities only"
        );
        let device = self.out_b.val().device();
        let w = self.arch.width;
        self.out_w = param2(vec![0.0; w * NX], [w, NX], &device);
        self.out_b = param1(vec![0.0; NX], &device);
        self.hybrid = Some(physics);
        self
    }

    /// The hybrid's physics, if this network corrects one.
    pub fn hybrid(&self) -> Option<&Hybrid> {
        self.hybrid.as_ref()
    }

    /// The network of a frozen model (its scalings must be absent: the trainer uses none).
    ///
    /// # Panics
    /// If the model has input or output scaling.
    pub fn from_model(m: &PincModel, device: &Device) -> Self {
        assert!(m.input_scaling.is_none() && m.output_scaling.is_none(), "scaled models are not trainable here");
        let transpose = |l: &Linear| -> Vec<f32> {
            let mut t = vec![0.0; l.rows * l.cols];
            for j in 0..l.rows {
                for i in 0..l.cols {
                    t[i * l.rows + j] = l.weight[j * l.cols + i];
                }
            }
            t
        };
        let h = &m.weights.hidden;
        Self {
            hidden_w: h.iter().map(|h| param2(transpose(&h.linear), [h.linear.cols, h.linear.rows], device)).collect(),
            hidden_b: h.iter().map(|h| param1(h.linear.bias.clone(), device)).collect(),
            betas: h.iter().map(|h| param1(vec![h.beta], device)).collect(),
            ln_gain: h.iter().filter_map(|h| h.layer_norm.as_ref()).map(|n| param1(n.gain.clone(), device)).collect(),
            ln_bias: h.iter().filter_map(|h| h.layer_norm.as_ref()).map(|n| param1(n.bias.clone(), device)).collect(),
            out_w: param2(transpose(&m.weights.output), [m.weights.output.cols, NX], device),
            out_b: param1(m.weights.output.bias.clone(), device),
            arch: m.architecture.clone(),
            hybrid: m.hybrid.map(|physics| Hybrid { vehicle: m.vehicle, physics }),
        }
    }

    /// The architecture this network was built for.
    pub fn architecture(&self) -> &Architecture {
        &self.arch
    }

    /// The learned weights in the frozen file's layout (PyTorch's `[out, in]` row-major).
    pub fn weights(&self) -> Weights {
        let linear = |w: &Param<Tensor<2>>, b: &Param<Tensor<1>>| {
            let [cols, rows] = w.dims();
            let wt = to_f32(w.val());
            let mut weight = vec![0.0; rows * cols];
            for i in 0..cols {
                for j in 0..rows {
                    weight[j * cols + i] = wt[i * rows + j];
                }
            }
            Linear { rows, cols, weight, bias: to_f32(b.val()) }
        };
        let mut ln = 0;
        let hidden = (0..self.arch.hidden_layers)
            .map(|l| {
                let layer_norm = self.arch.layer_norm[l].then(|| {
                    let n = LayerNormWeights {
                        gain: to_f32(self.ln_gain[ln].val()),
                        bias: to_f32(self.ln_bias[ln].val()),
                        eps: LAYER_NORM_EPS as f32,
                    };
                    ln += 1;
                    n
                });
                HiddenLayer {
                    linear: linear(&self.hidden_w[l], &self.hidden_b[l]),
                    beta: to_f32(self.betas[l].val())[0],
                    layer_norm,
                }
            })
            .collect();
        Weights { hidden, output: linear(&self.out_w, &self.out_b) }
    }

    /// Forward pass from states `x [N, 9]`, held inputs `u [N, 4]` and times `t [N, 1]`;
    /// with `tangent`, also `d x_hat / d t`. `x` is data (not a prediction).
    ///
    /// # Shapes
    /// - `x`: `[N, 9]`, `u`: `[N, 4]`, `t`: `[N, 1]`
    /// - returns `state` `[N, 9]` and `rate` `[N, 9]`
    pub fn forward(&self, x: Tensor<2>, u: Tensor<2>, t: Tensor<2>, tangent: bool) -> Prediction {
        self.forward_from(x, u, t, tangent, false)
    }

    /// [`PincNet::forward`] from a state that may be a prediction (`tracked`: a rollout's
    /// later steps), whose gradient must then flow through a hybrid's physics too.
    pub fn forward_from(&self, x: Tensor<2>, u: Tensor<2>, t: Tensor<2>, tangent: bool, tracked: bool) -> Prediction {
        // A hybrid's base: the physics over `t` and, for the tangent, its rate f(Phi_t, u).
        let base = self.hybrid.as_ref().map(|h| {
            let phi = physics_step(h, x.clone(), u.clone(), t.clone(), tracked);
            let rate = tangent.then(|| rhs(&h.vehicle, phi.clone(), u.clone()));
            (phi, rate)
        });
        let (mut o, mut d_o) = self.mlp(&x, u.clone(), t.clone(), tangent);
        if self.hybrid.is_some_and(|h| h.physics.rest_anchored) {
            // The correction less its value at rest (no velocity, the input that holds the
            // physics still) over the same step: zero there.
            let rest = h_rest_input(self.hybrid.as_ref().expect("anchored hybrid"));
            let [n, _] = u.dims();
            let u_rest = Tensor::<1>::from_data(TensorData::new(rest.to_vec(), [NU]), &u.device())
                .unsqueeze::<2>()
                .repeat_dim(0, n);
            let (rest_o, rest_d) = self.mlp(&x.zeros_like(), u_rest, t, tangent);
            o = o - rest_o;
            d_o = d_o.zip(rest_d).map(|(d, r)| d - r);
        }
        match base {
            Some((phi, rate)) => self.compose(Some(phi), rate, o, d_o),
            None => self.compose(self.arch.residual.then_some(x), None, o, d_o),
        }
    }

    /// The network's raw output `N([x_seen, u, t])` and, with `tangent`, its time derivative.
    fn mlp(&self, x: &Tensor<2>, u: Tensor<2>, t: Tensor<2>, tangent: bool) -> (Tensor<2>, Option<Tensor<2>>) {
        let device = x.device();
        let [n, _] = x.dims();
        let seen: Vec<i64> = self.arch.state_inputs.iter().map(|&i| i64::from(i)).collect();
        let xs = if seen.len() == NX {
            x.clone()
        } else {
            x.clone().select(1, Tensor::<1, Int>::from_data(TensorData::new(seen.clone(), [seen.len()]), &device))
        };
        let mut a = Tensor::cat(vec![xs, u, t], 1); // [N, n_in]
        // d a / d t: only the last input column (the time) moves.
        let mut da: Option<Tensor<2>> = None;
        let mut ln = 0;
        for l in 0..self.arch.hidden_layers {
            let w = self.hidden_w[l].val();
            let h = a.matmul(w.clone()) + self.hidden_b[l].val().unsqueeze::<2>();
            let dh = if tangent {
                Some(match da {
                    // The first layer's tangent is the time row of W, the same for every sample.
                    None => {
                        let k = self.arch.input_size() - 1;
                        w.narrow(0, k, 1).repeat_dim(0, n)
                    }
                    Some(d) => d.matmul(w),
                })
            } else {
                None
            };
            let beta = self.betas[l].val().unsqueeze::<2>(); // [1, 1]
            let y = h.clone() * beta.clone();
            let (act, dact) = match self.arch.activation {
                Activation::Softplus => {
                    // softplus(y) / beta in the overflow-free form relu(y) + log1p(exp(-|y|)).
                    let sp = (activation::relu(y.clone()) + y.clone().abs().neg().exp().log1p()) / beta;
                    (sp, dh.map(|d| activation::sigmoid(y) * d))
                }
                Activation::Tanh => {
                    let th = y.tanh();
                    let slope = (th.clone().powi_scalar(2).neg() + 1.0) * beta;
                    (th, dh.map(|d| slope * d))
                }
            };
            let (out, dout) = if self.arch.layer_norm[l] {
                let r = layer_norm(act, dact, self.ln_gain[ln].val(), self.ln_bias[ln].val());
                ln += 1;
                r
            } else {
                (act, dact)
            };
            a = out;
            da = dout;
        }
        let o = a.matmul(self.out_w.val()) + self.out_b.val().unsqueeze::<2>();
        (o, da.map(|d| d.matmul(self.out_w.val())))
    }

    /// Residual and rotation of the planar increments by the predicted yaw, with tangents.
    /// `base` is what the output is added to (the state, a hybrid's physics step, or nothing)
    /// and `base_rate` its time derivative (a hybrid's; a state's is zero).
    fn compose(
        &self,
        base: Option<Tensor<2>>,
        base_rate: Option<Tensor<2>>,
        o: Tensor<2>,
        d_o: Option<Tensor<2>>,
    ) -> Prediction {
        let col = |t: &Tensor<2>, k: usize| t.clone().narrow(1, k, 1);
        let plus = |k: usize| match &base {
            Some(x) => col(x, k) + col(&o, k),
            None => col(&o, k),
        };
        let (c, s) = (plus(3), plus(4));
        let (o0, o1) = (col(&o, 0), col(&o, 1));
        let (dx, dy) = if self.arch.rotate_xy {
            (c.clone() * o0.clone() - s.clone() * o1.clone(), s.clone() * o0.clone() + c.clone() * o1.clone())
        } else {
            (o0.clone(), o1.clone())
        };
        let increment = Tensor::cat(vec![dx, dy, o.clone().narrow(1, 2, NX - 2)], 1);
        let state = match &base {
            Some(x) => x.clone() + increment,
            None => increment,
        };
        let rate = d_o.map(|d| {
            // d c / d t and d s / d t include the base's own motion.
            let (d0, d1) = (col(&d, 0), col(&d, 1));
            let (d3, d4) = match &base_rate {
                Some(r) => (col(r, 3) + col(&d, 3), col(r, 4) + col(&d, 4)),
                None => (col(&d, 3), col(&d, 4)),
            };
            let (ddx, ddy) = if self.arch.rotate_xy {
                (
                    d3.clone() * o0.clone() + c.clone() * d0.clone() - d4.clone() * o1.clone() - s.clone() * d1.clone(),
                    d4 * o0 + s * d0 + d3 * o1 + c * d1,
                )
            } else {
                (d0, d1)
            };
            let increment = Tensor::cat(vec![ddx, ddy, d.narrow(1, 2, NX - 2)], 1);
            match &base_rate {
                Some(r) => r.clone() + increment,
                None => increment,
            }
        });
        Prediction { state, rate }
    }
}

/// LayerNorm over the last dimension with its tangent:
/// `y = g (a - mean) / sqrt(var + eps) + b`.
fn layer_norm(a: Tensor<2>, da: Option<Tensor<2>>, gain: Tensor<1>, bias: Tensor<1>) -> (Tensor<2>, Option<Tensor<2>>) {
    let c = a.clone() - a.mean_dim(1);
    let var = c.clone().powi_scalar(2).mean_dim(1);
    let inv = (var + LAYER_NORM_EPS).sqrt().recip(); // [N, 1]
    let xhat = c.clone() * inv.clone();
    let g = gain.unsqueeze::<2>();
    let y = xhat.clone() * g.clone() + bias.unsqueeze::<2>();
    let dy = da.map(|da| {
        // c' = a' - mean(a'); xhat' = inv (c' - xhat mean(xhat c')).
        let dc = da.clone() - da.mean_dim(1);
        let proj = (xhat.clone() * dc.clone()).mean_dim(1);
        (dc - xhat * proj) * inv * g
    });
    (y, dy)
}

/// The input at which a hybrid anchored at rest is anchored: the heave force that cancels its
/// vehicle's net buoyancy (as [`PincModel::rest_input`]).
fn h_rest_input(h: &Hybrid) -> [f32; NU] {
    [0.0, 0.0, -h.vehicle.net_buoyancy() as f32, 0.0]
}
