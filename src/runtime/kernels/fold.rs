//! The model's network rewritten for inference: every per-unit affine map folded into the
//! dense layers, which are laid out in packs for the kernels.
//!
//! A PINC layer computes `act(beta (W a + b))` where `a`, the layer's input, is an affine
//! function of what the previous stage stored: the raw network input (input scaling), the
//! activation output times `1 / beta` (softplus), or a normalised vector times the LayerNorm
//! gain plus its bias. All of those are per-unit affine maps `a = alpha . v + c`, so
//! `beta W diag(alpha)` and `beta (W c + b)` replace `W` and `b`, and the output scaling is
//! folded into the output layer the same way. What is left to run is matrix-vector
//! products, the bare activation and LayerNorm without gain or bias. The fold is exact
//! in real arithmetic (done in f64); it changes the rounding of an f32 network by a few ulps.

use super::packs::{PACK, Pack, packs};
use super::real::Real;
use crate::model::{Activation, Linear, PincModel};
use crate::types::NX;

/// A dense layer `y = W v + b` with `rows` outputs and `cols` inputs, in two layouts.
#[derive(Debug, Clone)]
pub(crate) struct Dense<T> {
    /// Number of inputs.
    pub cols: usize,
    /// Forward layout, one row of `packs(rows)` packs per input: `fwd[i * P + j / 8][j % 8]`
    /// is `W[j][i]`.
    pub fwd: Vec<Pack<T>>,
    /// Reverse layout, one row of `packs(cols)` packs per output (padded to whole packs,
    /// padding zero): `rev[j * Q + i / 8][i % 8]` is `W[j][i]`.
    pub rev: Vec<Pack<T>>,
    /// `b`, padded to whole packs with zeros.
    pub bias: Vec<Pack<T>>,
    /// `sum_i W[j][i]` per output: `W (s - mu) r = r (W s) - r mu (W 1)` lets a LayerNorm
    /// before this layer be applied after its matrix-vector product.
    pub row_sum: Vec<Pack<T>>,
}

impl<T: Real> Dense<T> {
    /// From a row-major `rows x cols` matrix in f64.
    fn new(rows: usize, cols: usize, w: &[f64], b: &[f64]) -> Self {
        let (p, q) = (packs(rows), packs(cols));
        let mut fwd = vec![[T::ZERO; PACK]; cols * p];
        let mut rev = vec![[T::ZERO; PACK]; packs(rows) * PACK * q];
        let mut bias = vec![[T::ZERO; PACK]; p];
        let mut row_sum = vec![[T::ZERO; PACK]; p];
        for j in 0..rows {
            row_sum[j / PACK][j % PACK] = T::from_f64(w[j * cols..(j + 1) * cols].iter().sum());
            for i in 0..cols {
                let v = T::from_f64(w[j * cols + i]);
                fwd[i * p + j / PACK][j % PACK] = v;
                rev[j * q + i / PACK][i % PACK] = v;
            }
            bias[j / PACK][j % PACK] = T::from_f64(b[j]);
        }
        Self { cols, fwd, rev, bias, row_sum }
    }

    /// Packs of a reverse-layout row (input gradients).
    pub fn in_packs(&self) -> usize {
        packs(self.cols)
    }
}

/// The folded network.
#[derive(Debug, Clone)]
pub(crate) struct Folded<T> {
    pub hidden: Vec<Dense<T>>,
    /// Per hidden layer: the LayerNorm epsilon on the bare activation (`eps beta^2` for
    /// softplus), if the layer has one.
    pub norm_eps: Vec<Option<T>>,
    /// Output layer: rows are the 9 state increments in state units.
    pub output: Dense<T>,
    /// 1 for real units, 0 for the padding of the last pack; `None` when the width is a
    /// whole number of packs. LayerNorm statistics are taken over real units only.
    pub mask: Option<Vec<Pack<T>>>,
    /// Hidden units per layer, and its inverse.
    pub width: usize,
    pub inv_width: T,
}

/// `W diag(alpha)` and `W c + b` for row-major `W` (`rows x alpha.len()`).
fn fold_input(l: &Linear, alpha: &[f64], c: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let mut w = vec![0.0; l.rows * l.cols];
    let mut b = vec![0.0; l.rows];
    for j in 0..l.rows {
        let mut acc = f64::from(l.bias[j]);
        for i in 0..l.cols {
            let wji = f64::from(l.weight[j * l.cols + i]);
            w[j * l.cols + i] = wji * alpha[i];
            acc += wji * c[i];
        }
        b[j] = acc;
    }
    (w, b)
}

impl<T: Real> Folded<T> {
    pub fn new(model: &PincModel) -> Self {
        let arch = &model.architecture;
        let n_in = arch.input_size();
        // How the first layer's input follows from the raw [x_seen, u, t].
        let (mut alpha, mut c) = match &model.input_scaling {
            Some(s) => {
                (s.std.iter().map(|v| 1.0 / v).collect(), s.mean.iter().zip(&s.std).map(|(m, v)| -m / v).collect())
            }
            None => (vec![1.0; n_in], vec![0.0; n_in]),
        };
        let mut hidden = Vec::with_capacity(model.weights.hidden.len());
        let mut norm_eps = Vec::with_capacity(model.weights.hidden.len());
        for h in &model.weights.hidden {
            let beta = f64::from(h.beta);
            let (mut w, mut b) = fold_input(&h.linear, &alpha, &c);
            w.iter_mut().chain(b.iter_mut()).for_each(|v| *v *= beta);
            hidden.push(Dense::new(h.linear.rows, h.linear.cols, &w, &b));
            // What the next layer reads, as a function of the bare activation output.
            let post = match arch.activation {
                Activation::Softplus => 1.0 / beta,
                Activation::Tanh => 1.0,
            };
            match &h.layer_norm {
                Some(n) => {
                    // LN(post s) = sign(post) (s - mean s) / sqrt(var s + eps / post^2).
                    norm_eps.push(Some(T::from_f64(f64::from(n.eps) / (post * post))));
                    alpha = n.gain.iter().map(|&g| f64::from(g) * post.signum()).collect();
                    c = n.bias.iter().map(|&v| f64::from(v)).collect();
                }
                None => {
                    norm_eps.push(None);
                    alpha = vec![post; h.linear.rows];
                    c = vec![0.0; h.linear.rows];
                }
            }
        }
        let o = &model.weights.output;
        let (mut w, mut b) = fold_input(o, &alpha, &c);
        if let Some(s) = &model.output_scaling {
            for k in 0..NX {
                w[k * o.cols..(k + 1) * o.cols].iter_mut().for_each(|v| *v *= s.std[k]);
                b[k] = b[k] * s.std[k] + s.mean[k];
            }
        }
        let width = arch.width;
        let mask = (!width.is_multiple_of(PACK)).then(|| {
            (0..packs(width))
                .map(|p| std::array::from_fn(|t| if p * PACK + t < width { T::ONE } else { T::ZERO }))
                .collect()
        });
        Self {
            hidden,
            norm_eps,
            output: Dense::new(NX, o.cols, &w, &b),
            mask,
            width,
            inv_width: T::from_f64(1.0 / width as f64),
        }
    }
}
