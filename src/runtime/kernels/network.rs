//! The network as the kernels run it (folded layers, activation, which state components it
//! reads) and the scratch memory of one evaluation.

use super::fold::Folded;
use super::packs::{PACK, Pack, packs};
use super::real::Real;
use crate::model::{Activation, PincModel};
use crate::types::NX;

/// Raw network output (in state units, widened to f64), before the residual and rotation.
pub type NetOut = [f64; NX];

/// The network as the kernels run it: the folded layers, the activation, and which state
/// components it reads.
#[derive(Debug, Clone)]
pub struct Network<T> {
    /// Layers with every per-unit affine map folded in.
    pub folded: Folded<T>,
    /// Hidden-layer activation.
    pub activation: Activation,
    /// Indices of the 9-state components in the network input.
    pub seen: Vec<usize>,
    /// Length of the raw input `[x_seen, u, t]`.
    pub n_in: usize,
    /// Packs per hidden layer.
    pub packs: usize,
}

/// The buffer sizes a [`NetScratch`] was made for: a scratch made for another network
/// would be read out of bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shape {
    /// Raw inputs.
    pub inputs: usize,
    /// Hidden layers.
    pub layers: usize,
    /// Packs per hidden layer.
    pub packs: usize,
}

impl<T: Real> Network<T> {
    /// From a validated model.
    pub fn new(model: &PincModel) -> Self {
        let a = &model.architecture;
        Self {
            folded: Folded::new(model),
            activation: a.activation,
            seen: a.state_inputs.iter().map(|&i| i as usize).collect(),
            n_in: a.input_size(),
            packs: packs(a.width),
        }
    }

    /// What a scratch for this network must be sized for.
    pub fn shape(&self) -> Shape {
        Shape { inputs: self.n_in, layers: self.folded.hidden.len(), packs: self.packs }
    }
}

/// Scratch memory of one network evaluation and its reverse pass.
#[derive(Debug, Clone)]
pub struct NetScratch<T> {
    /// The shape the buffers were sized for.
    pub shape: Shape,
    /// Raw network input `[x_seen, u, t]`.
    pub input: Vec<T>,
    /// Pre-activations of the current layer.
    pub pre: Vec<Pack<T>>,
    /// Activation output of every hidden layer (LayerNorm is applied inside the next
    /// layer's product), `L * packs`.
    pub y: Vec<Pack<T>>,
    /// Activation derivative of every hidden unit, `L * packs`.
    pub d: Vec<Pack<T>>,
    /// Normalised outputs of LayerNorm layers, `L * packs` (linearisation only).
    pub xhat: Vec<Pack<T>>,
    /// `1 / sqrt(var + eps)` of each LayerNorm layer.
    pub inv_std: Vec<T>,
    /// Reverse mode: the 9 rows of `d out / d (layer input)` at the current layer, each
    /// `max(packs, input packs)` packs.
    pub rows: Vec<Pack<T>>,
    /// The rows one layer further back, being computed from `rows` (the two swap).
    pub rows_next: Vec<Pack<T>>,
}

impl<T: Real> NetScratch<T> {
    /// Every buffer sized for `net`.
    pub fn new(net: &Network<T>) -> Self {
        let shape = net.shape();
        let (l, np) = (shape.layers, shape.packs);
        let rows = np.max(packs(net.n_in));
        let zero = [T::ZERO; PACK];
        Self {
            shape,
            input: vec![T::ZERO; net.n_in],
            pre: vec![zero; np],
            y: vec![zero; l * np],
            d: vec![zero; l * np],
            xhat: vec![zero; l * np],
            inv_std: vec![T::ZERO; l],
            rows: vec![zero; NX * rows],
            rows_next: vec![zero; NX * rows],
        }
    }
}
