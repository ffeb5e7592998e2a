//! The frozen PINC as an immutable [`Predictor`] (weights in both memory layouts the
//! kernels want) and the per-thread [`Workspace`] it computes in.

use super::RuntimeError;
use super::envelope::{EnvelopeCheck, EnvelopeStatus};
use super::kernels::fused_available;
use crate::model::{Activation, Envelope, Linear, PincModel};
use crate::types::{Input, NX, State};

/// One dense layer in f64, stored twice: column-major for the forward pass (an axpy per
/// input) and row-major for the reverse pass (an axpy per output).
#[derive(Debug, Clone)]
pub(crate) struct Layer {
    pub cols: usize,
    /// `w_col[i * rows + j] = W[j][i]`.
    pub w_col: Vec<f64>,
    /// `w_row[j * cols + i] = W[j][i]`.
    pub w_row: Vec<f64>,
    pub bias: Vec<f64>,
    pub beta: f64,
    pub inv_beta: f64,
    pub norm: Option<Norm>,
}

#[derive(Debug, Clone)]
pub(crate) struct Norm {
    pub gain: Vec<f64>,
    pub bias: Vec<f64>,
    pub eps: f64,
}

impl Layer {
    fn new(l: &Linear, beta: f32, norm: Option<Norm>) -> Self {
        let (rows, cols) = (l.rows, l.cols);
        let w_row: Vec<f64> = l.weight.iter().map(|&w| f64::from(w)).collect();
        let mut w_col = vec![0.0; rows * cols];
        for j in 0..rows {
            for i in 0..cols {
                w_col[i * rows + j] = w_row[j * cols + i];
            }
        }
        let beta = f64::from(beta);
        Self {
            cols,
            w_col,
            w_row,
            bias: l.bias.iter().map(|&b| f64::from(b)).collect(),
            beta,
            inv_beta: 1.0 / beta,
            norm,
        }
    }
}

/// A frozen PINC ready to run: `x_hat(t) = x + N([x_seen, u, t])` with the planar
/// increments rotated by the predicted yaw (SPEC section 3).
///
/// Immutable after construction; every call takes a [`Workspace`] so that one predictor
/// can serve many threads.
#[derive(Debug, Clone)]
pub struct Predictor {
    pub(crate) layers: Vec<Layer>,
    pub(crate) output: Layer,
    pub(crate) activation: Activation,
    pub(crate) seen: Vec<usize>,
    pub(crate) n_in: usize,
    pub(crate) width: usize,
    pub(crate) in_mean: Vec<f64>,
    pub(crate) in_inv_std: Vec<f64>,
    pub(crate) out_mean: [f64; NX],
    pub(crate) out_std: [f64; NX],
    pub(crate) residual: bool,
    pub(crate) rotate: bool,
    pub(crate) renormalise_yaw: bool,
    pub(crate) dt: f64,
    pub(crate) envelope: EnvelopeCheck,
    pub(crate) fused: bool,
}

impl Predictor {
    /// Builds a predictor from a validated model (weights widened to f64).
    ///
    /// # Memory allocation
    /// Allocates the weights twice (two layouts), about `16 * parameters` bytes.
    pub fn new(model: &PincModel) -> Self {
        let a = &model.architecture;
        let layers = model
            .weights
            .hidden
            .iter()
            .map(|h| {
                let norm = h.layer_norm.as_ref().map(|n| Norm {
                    gain: n.gain.iter().map(|&v| f64::from(v)).collect(),
                    bias: n.bias.iter().map(|&v| f64::from(v)).collect(),
                    eps: f64::from(n.eps),
                });
                Layer::new(&h.linear, h.beta, norm)
            })
            .collect();
        let n_in = a.input_size();
        let (in_mean, in_inv_std) = match &model.input_scaling {
            Some(s) => (s.mean.clone(), s.std.iter().map(|v| 1.0 / v).collect()),
            None => (vec![0.0; n_in], vec![1.0; n_in]),
        };
        let (mut out_mean, mut out_std) = ([0.0; NX], [1.0; NX]);
        if let Some(s) = &model.output_scaling {
            out_mean.copy_from_slice(&s.mean);
            out_std.copy_from_slice(&s.std);
        }
        let seen: Vec<usize> = a.state_inputs.iter().map(|&i| i as usize).collect();
        Self {
            layers,
            output: Layer::new(&model.weights.output, 1.0, None),
            activation: a.activation,
            envelope: EnvelopeCheck::new(model.envelope.clone(), &seen),
            seen,
            n_in,
            width: a.width,
            in_mean,
            in_inv_std,
            out_mean,
            out_std,
            residual: a.residual,
            rotate: a.rotate_xy,
            renormalise_yaw: false,
            dt: model.dt,
            fused: fused_available(),
        }
    }

    /// Renormalise `(cos psi, sin psi)` to unit length after every step. Default: off (the
    /// trained network's semantics, and what PyTorch computes).
    #[must_use]
    pub fn with_yaw_renormalisation(mut self, on: bool) -> Self {
        self.renormalise_yaw = on;
        self
    }

    /// Use the portable kernels even where AVX2 + FMA are available (for comparison).
    #[must_use]
    pub fn with_portable_kernels(mut self) -> Self {
        self.fused = false;
        self
    }

    /// Whether the AVX2 + FMA kernels are in use.
    pub fn uses_fused_kernels(&self) -> bool {
        self.fused
    }

    /// The sample period the model was trained for (s).
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// The training envelope, if the model file has one.
    pub fn envelope(&self) -> Option<&Envelope> {
        self.envelope.envelope()
    }

    /// Indices of the 9-state components the network sees.
    pub fn state_inputs(&self) -> &[usize] {
        &self.seen
    }

    /// A workspace sized for this predictor.
    pub fn workspace(&self) -> Workspace {
        Workspace::new(self)
    }

    /// Refuses non-finite arguments; records envelope exits.
    pub(crate) fn check_args(&self, ws: &mut Workspace, step: usize, x: &State, u: &Input) -> Result<(), RuntimeError> {
        if let Some(index) = x.iter().position(|v| !v.is_finite()) {
            return Err(RuntimeError::NonFiniteState { step, index, value: x[index] });
        }
        if let Some(index) = u.iter().position(|v| !v.is_finite()) {
            return Err(RuntimeError::NonFiniteInput { step, index, value: u[index] });
        }
        self.envelope.check(&mut ws.envelope, step, x, u);
        Ok(())
    }
}

/// Scratch memory for one thread's calls into a [`Predictor`].
///
/// # Memory allocation
/// `Workspace::new` allocates `(4 L + 2 * 9) * width + 10 * inputs + L` floats for `L`
/// hidden layers; no call that takes a workspace allocates afterwards.
#[derive(Debug, Clone)]
pub struct Workspace {
    /// Network input (after scaling).
    pub(crate) z: Vec<f64>,
    /// Output of every hidden layer (after activation and LayerNorm), `L * width`.
    pub(crate) y: Vec<f64>,
    /// Activation derivative of every hidden unit, `L * width`.
    pub(crate) d: Vec<f64>,
    /// Normalised activations of LayerNorm layers, `L * width`.
    pub(crate) xhat: Vec<f64>,
    /// `1 / sqrt(var + eps)` of each LayerNorm layer.
    pub(crate) inv_std: Vec<f64>,
    /// Reverse-mode row buffers, `9 * max(width, inputs)` each.
    pub(crate) g: Vec<f64>,
    pub(crate) g2: Vec<f64>,
    /// Envelope exits of the last call.
    pub(crate) envelope: EnvelopeStatus,
}

impl Workspace {
    /// Sizes every buffer for `p`.
    pub fn new(p: &Predictor) -> Self {
        let l = p.layers.len();
        let w = p.width;
        let rows = w.max(p.n_in);
        Self {
            z: vec![0.0; p.n_in],
            y: vec![0.0; l * w],
            d: vec![0.0; l * w],
            xhat: vec![0.0; l * w],
            inv_std: vec![0.0; l],
            g: vec![0.0; NX * rows],
            g2: vec![0.0; NX * rows],
            envelope: EnvelopeStatus::default(),
        }
    }

    /// Envelope exits seen during the last `step`, `rollout` or linearisation call.
    pub fn envelope_status(&self) -> EnvelopeStatus {
        self.envelope
    }
}
