//! The frozen PINC as an immutable [`Predictor`] (weights in both memory layouts the
//! kernels want) and the per-thread [`Workspace`] it computes in.

use super::RuntimeError;
use super::envelope::{EnvelopeCheck, EnvelopeStatus};
use super::kernels::fused_available;
use super::real::Real;
use crate::model::{Activation, Envelope, Linear, PincModel};
use crate::types::{Input, NX, State};

/// One dense layer, stored twice: column-major for the forward pass (a matrix-vector
/// product over inputs) and row-major for the reverse pass.
#[derive(Debug, Clone)]
pub(crate) struct Layer<T> {
    pub cols: usize,
    /// `w_col[i * rows + j] = W[j][i]`.
    pub w_col: Vec<T>,
    /// `w_row[j * cols + i] = W[j][i]`.
    pub w_row: Vec<T>,
    pub bias: Vec<T>,
    pub beta: T,
    pub inv_beta: T,
    pub norm: Option<Norm<T>>,
}

#[derive(Debug, Clone)]
pub(crate) struct Norm<T> {
    pub gain: Vec<T>,
    pub bias: Vec<T>,
    pub eps: T,
}

fn convert<T: Real>(v: &[f32]) -> Vec<T> {
    v.iter().map(|&x| T::of(f64::from(x))).collect()
}

/// Rows of the output layer as stored column-major: 9 padded to 16 so the forward pass
/// runs one 16-wide register block instead of an 8-wide and a scalar one.
pub(crate) const OUTPUT_STRIDE: usize = 16;

impl<T: Real> Layer<T> {
    fn new(l: &Linear, beta: f32, norm: Option<Norm<T>>) -> Self {
        Self::with_column_stride(l, beta, norm, l.rows)
    }

    /// `w_col` with `stride >= rows` entries per column, the padding zero.
    fn with_column_stride(l: &Linear, beta: f32, norm: Option<Norm<T>>, stride: usize) -> Self {
        let (rows, cols) = (l.rows, l.cols);
        let w_row: Vec<T> = convert(&l.weight);
        let mut w_col = vec![T::ZERO; stride * cols];
        for j in 0..rows {
            for i in 0..cols {
                w_col[i * stride + j] = w_row[j * cols + i];
            }
        }
        let beta = f64::from(beta);
        Self { cols, w_col, w_row, bias: convert(&l.bias), beta: T::of(beta), inv_beta: T::of(1.0 / beta), norm }
    }
}

/// A frozen PINC ready to run: `x_hat(t) = x + N([x_seen, u, t])` with the planar
/// increments rotated by the predicted yaw (SPEC section 3).
///
/// Immutable after construction; every call takes a [`Workspace`] so that one predictor
/// can serve many threads.
///
/// `T` is the precision of the network arithmetic: `f32` (the default, [`Predictor::new`])
/// is the fast path and the precision the network was trained in; `f64`
/// (`Predictor::<f64>::with_precision`) is the reference whose Jacobians are checked against
/// finite differences. States, inputs and Jacobians are `f64` either way, and the residual
/// and rotation are applied in `f64`.
#[derive(Debug, Clone)]
pub struct Predictor<T: Real = f32> {
    pub(crate) layers: Vec<Layer<T>>,
    pub(crate) output: Layer<T>,
    pub(crate) activation: Activation,
    pub(crate) seen: Vec<usize>,
    pub(crate) n_in: usize,
    pub(crate) width: usize,
    pub(crate) in_mean: Vec<T>,
    pub(crate) in_inv_std: Vec<T>,
    pub(crate) out_mean: [T; NX],
    pub(crate) out_std: [T; NX],
    pub(crate) residual: bool,
    pub(crate) rotate: bool,
    pub(crate) renormalise_yaw: bool,
    pub(crate) dt: f64,
    pub(crate) envelope: EnvelopeCheck,
    pub(crate) fused: bool,
}

impl Predictor {
    /// Builds the default (`f32`) predictor from a validated model.
    ///
    /// # Memory allocation
    /// Allocates the weights twice (two layouts), about `8 * parameters` bytes.
    pub fn new(model: &PincModel) -> Self {
        Self::with_precision(model)
    }
}

impl<T: Real> Predictor<T> {
    /// Builds a predictor computing in `T` from a validated model.
    ///
    /// # Memory allocation
    /// Allocates the weights twice (two layouts), `2 * size_of::<T>() * parameters` bytes.
    pub fn with_precision(model: &PincModel) -> Self {
        let a = &model.architecture;
        let layers = model
            .weights
            .hidden
            .iter()
            .map(|h| {
                let norm = h.layer_norm.as_ref().map(|n| Norm {
                    gain: convert(&n.gain),
                    bias: convert(&n.bias),
                    eps: T::of(f64::from(n.eps)),
                });
                Layer::new(&h.linear, h.beta, norm)
            })
            .collect();
        let n_in = a.input_size();
        let (in_mean, in_inv_std) = match &model.input_scaling {
            Some(s) => (s.mean.iter().map(|&v| T::of(v)).collect(), s.std.iter().map(|v| T::of(1.0 / v)).collect()),
            None => (vec![T::ZERO; n_in], vec![T::ONE; n_in]),
        };
        let (mut out_mean, mut out_std) = ([T::ZERO; NX], [T::ONE; NX]);
        if let Some(s) = &model.output_scaling {
            for k in 0..NX {
                (out_mean[k], out_std[k]) = (T::of(s.mean[k]), T::of(s.std[k]));
            }
        }
        let seen: Vec<usize> = a.state_inputs.iter().map(|&i| i as usize).collect();
        Self {
            layers,
            output: Layer::with_column_stride(&model.weights.output, 1.0, None, OUTPUT_STRIDE),
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
    pub fn workspace(&self) -> Workspace<T> {
        Workspace::new(self)
    }

    /// Refuses non-finite arguments; records envelope exits.
    pub(crate) fn check_args(
        &self,
        ws: &mut Workspace<T>,
        step: usize,
        x: &State,
        u: &Input,
    ) -> Result<(), RuntimeError> {
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
pub struct Workspace<T: Real = f32> {
    /// Network input (after scaling).
    pub(crate) z: Vec<T>,
    /// Output of every hidden layer (after activation and LayerNorm), `L * width`.
    pub(crate) y: Vec<T>,
    /// Activation derivative of every hidden unit, `L * width`.
    pub(crate) d: Vec<T>,
    /// Normalised activations of LayerNorm layers, `L * width`.
    pub(crate) xhat: Vec<T>,
    /// `1 / sqrt(var + eps)` of each LayerNorm layer.
    pub(crate) inv_std: Vec<T>,
    /// Reverse-mode row buffers, `9 * max(width, inputs)` each.
    pub(crate) g: Vec<T>,
    pub(crate) g2: Vec<T>,
    /// Envelope exits of the last call.
    pub(crate) envelope: EnvelopeStatus,
}

impl<T: Real> Workspace<T> {
    /// Sizes every buffer for `p`.
    pub fn new(p: &Predictor<T>) -> Self {
        let l = p.layers.len();
        let w = p.width;
        let rows = w.max(p.n_in);
        Self {
            z: vec![T::ZERO; p.n_in],
            y: vec![T::ZERO; l * w],
            d: vec![T::ZERO; l * w],
            xhat: vec![T::ZERO; l * w],
            inv_std: vec![T::ZERO; l],
            g: vec![T::ZERO; NX * rows],
            g2: vec![T::ZERO; NX * rows],
            envelope: EnvelopeStatus::default(),
        }
    }

    /// Envelope exits seen during the last `step`, `rollout` or linearisation call.
    pub fn envelope_status(&self) -> EnvelopeStatus {
        self.envelope
    }
}
