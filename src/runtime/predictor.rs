//! The frozen PINC as an immutable [`Predictor`] (weights in both memory layouts the
//! kernels want) and the per-thread [`Workspace`] it computes in.

use super::RuntimeError;
use super::envelope::{EnvelopeCheck, EnvelopeStatus};
use super::error::{check_input, check_state};
use super::fold::Folded;
use super::kernels::{PACK, Pack, fused_available, packs};
use super::real::Real;
use crate::model::{Activation, Envelope, PincModel};
use crate::types::{Input, NX, State};

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
    pub(crate) net: Folded<T>,
    pub(crate) activation: Activation,
    pub(crate) seen: Vec<usize>,
    pub(crate) n_in: usize,
    /// Packs per hidden layer.
    pub(crate) packs: usize,
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
    /// Allocates the weights twice (two layouts, padded to whole packs of 8 units),
    /// about `2 * size_of::<T>() * parameters` bytes.
    pub fn with_precision(model: &PincModel) -> Self {
        let a = &model.architecture;
        let seen: Vec<usize> = a.state_inputs.iter().map(|&i| i as usize).collect();
        Self {
            net: Folded::new(model),
            activation: a.activation,
            envelope: EnvelopeCheck::new(model.envelope.clone(), &seen),
            seen,
            n_in: a.input_size(),
            packs: packs(a.width),
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
        check_state(step, x)?;
        check_input(step, u)?;
        self.envelope.check(&mut ws.envelope, step, x, u);
        Ok(())
    }
}

/// Scratch memory for one thread's calls into a [`Predictor`].
///
/// # Memory allocation
/// `Workspace::new` allocates about `(3 L + 1 + 2 * 9) * width + inputs + L` floats for `L`
/// hidden layers (widths rounded up to packs of 8); no call that takes a workspace
/// allocates afterwards.
#[derive(Debug, Clone)]
pub struct Workspace<T: Real = f32> {
    /// Raw network input `[x_seen, u, t]`.
    pub(crate) z: Vec<T>,
    /// Pre-activations of the current layer.
    pub(crate) pre: Vec<Pack<T>>,
    /// Activation output of every hidden layer (LayerNorm is applied inside the next
    /// layer's product), `L * packs`.
    pub(crate) y: Vec<Pack<T>>,
    /// Activation derivative of every hidden unit, `L * packs`.
    pub(crate) d: Vec<Pack<T>>,
    /// Normalised outputs of LayerNorm layers, `L * packs` (linearisation only).
    pub(crate) xhat: Vec<Pack<T>>,
    /// `1 / sqrt(var + eps)` of each LayerNorm layer.
    pub(crate) inv_std: Vec<T>,
    /// Reverse-mode rows (9 of them), `9 * max(packs, input packs)` packs each.
    pub(crate) g: Vec<Pack<T>>,
    pub(crate) g2: Vec<Pack<T>>,
    /// Envelope exits of the last call.
    pub(crate) envelope: EnvelopeStatus,
}

impl<T: Real> Workspace<T> {
    /// Sizes every buffer for `p`.
    pub fn new(p: &Predictor<T>) -> Self {
        let l = p.net.hidden.len();
        let rows = p.packs.max(packs(p.n_in));
        Self {
            z: vec![T::ZERO; p.n_in],
            pre: vec![[T::ZERO; PACK]; p.packs],
            y: vec![[T::ZERO; PACK]; l * p.packs],
            d: vec![[T::ZERO; PACK]; l * p.packs],
            xhat: vec![[T::ZERO; PACK]; l * p.packs],
            inv_std: vec![T::ZERO; l],
            g: vec![[T::ZERO; PACK]; NX * rows],
            g2: vec![[T::ZERO; PACK]; NX * rows],
            envelope: EnvelopeStatus::default(),
        }
    }

    /// Envelope exits seen during the last `step`, `rollout` or linearisation call.
    pub fn envelope_status(&self) -> EnvelopeStatus {
        self.envelope
    }
}
