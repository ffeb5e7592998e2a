//! Import of PyTorch state dicts (safetensors) in the layout of the paper's public
//! implementation: an `nn.Sequential` named `layers` of Linear, adaptive activation
//! (`beta`), optional LayerNorm, ..., Linear.

use super::{
    Activation, Architecture, HiddenLayer, LayerNormWeights, Linear, MAX_WIDTH, ModelError, PincModel, Provenance,
    Weights, validate,
};
use crate::types::NX;
use safetensors::{Dtype, SafeTensors};
use std::collections::BTreeMap;

/// PyTorch's LayerNorm default epsilon.
const TORCH_LAYER_NORM_EPS: f32 = 1e-5;

fn err(message: impl Into<String>) -> ModelError {
    ModelError::Import(message.into())
}

/// One tensor, converted to f32, with its shape.
struct Tensor {
    shape: Vec<usize>,
    data: Vec<f32>,
}

/// The modules of the Sequential, by index, each a map from parameter name to tensor.
fn modules(st: &SafeTensors) -> Result<BTreeMap<usize, BTreeMap<String, Tensor>>, ModelError> {
    let mut out: BTreeMap<usize, BTreeMap<String, Tensor>> = BTreeMap::new();
    for (name, view) in st.iter() {
        let mut parts = name.split('.');
        let (Some("layers"), Some(index), Some(param), None) = (parts.next(), parts.next(), parts.next(), parts.next())
        else {
            return Err(err(format!("unexpected key {name:?}: expected layers.<i>.<weight|bias|beta>")));
        };
        let index: usize = index.parse().map_err(|_| err(format!("key {name:?}: {index:?} is not a layer index")))?;
        if !matches!(param, "weight" | "bias" | "beta") {
            return Err(err(format!("unexpected parameter {name:?}")));
        }
        let bytes = view.data();
        let data: Vec<f32> = match view.dtype() {
            Dtype::F32 => bytes.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes"))).collect(),
            Dtype::F64 => {
                bytes.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")) as f32).collect()
            }
            other => return Err(err(format!("{name}: dtype {other:?} (only F32 and F64 are read)"))),
        };
        out.entry(index).or_default().insert(param.to_string(), Tensor { shape: view.shape().to_vec(), data });
    }
    Ok(out)
}

/// Converts a safetensors state dict into a validated [`PincModel`] with sample period
/// `dt`. Depth and width are inferred from the keys; the network must see all nine states.
///
/// # Errors
/// [`ModelError::Import`] naming the key at fault for anything outside the layout, and any
/// validation failure of the result.
pub fn import_state_dict(bytes: &[u8], dt: f64, activation: Activation) -> Result<PincModel, ModelError> {
    let st = SafeTensors::deserialize(bytes).map_err(|e| err(format!("not a safetensors file: {e}")))?;
    let mut modules = modules(&st)?.into_iter().peekable();
    let mut linears: Vec<(usize, Linear)> = Vec::new();
    let mut hidden: Vec<HiddenLayer> = Vec::new();
    while let Some((i, m)) = modules.next() {
        // Linear: 2-D weight and 1-D bias.
        let (Some(w), Some(b), 2) = (m.get("weight"), m.get("bias"), m.len()) else {
            return Err(err(format!("layers.{i}: expected a Linear (weight and bias)")));
        };
        let [rows, cols] = w.shape[..] else {
            return Err(err(format!("layers.{i}.weight: shape {:?} is not 2-D", w.shape)));
        };
        if b.shape != [rows] {
            return Err(err(format!("layers.{i}.bias: shape {:?}, expected [{rows}]", b.shape)));
        }
        if rows > MAX_WIDTH || cols > MAX_WIDTH {
            return Err(err(format!("layers.{i}.weight: shape {:?} exceeds the width limit {MAX_WIDTH}", w.shape)));
        }
        let linear = Linear { rows, cols, weight: w.data.clone(), bias: b.data.clone() };
        let Some((j, act)) = modules.next() else {
            linears.push((i, linear));
            break; // the output layer
        };
        let beta = match (act.get("beta"), act.len()) {
            (Some(t), 1) if t.data.len() == 1 => t.data[0],
            _ => return Err(err(format!("layers.{j}: expected an adaptive activation with a scalar beta"))),
        };
        // Optional LayerNorm: 1-D weight and bias of the layer's width.
        let layer_norm = match modules.peek() {
            Some((k, ln)) if ln.get("weight").is_some_and(|t| t.shape.len() == 1) => {
                let g = &ln["weight"];
                let bb = ln.get("bias").ok_or_else(|| err(format!("layers.{k}: LayerNorm without bias")))?;
                if g.shape != [rows] || bb.shape != [rows] || ln.len() != 2 {
                    return Err(err(format!("layers.{k}: LayerNorm of shape {:?}, expected [{rows}]", g.shape)));
                }
                let n = LayerNormWeights { gain: g.data.clone(), bias: bb.data.clone(), eps: TORCH_LAYER_NORM_EPS };
                modules.next();
                Some(n)
            }
            _ => None,
        };
        hidden.push(HiddenLayer { linear, beta, layer_norm });
    }
    let Some((out_index, output)) = linears.pop() else { return Err(err("no output Linear layer")) };
    if hidden.is_empty() {
        return Err(err("no hidden layers"));
    }
    if output.rows != NX {
        return Err(err(format!("layers.{out_index}: output size {} (expected the 9-state)", output.rows)));
    }
    let width = hidden[0].linear.rows;
    let input = hidden[0].linear.cols;
    if input != NX + 5 {
        return Err(err(format!("layers.0: input size {input}; the paper's network takes 14 (9 states, 4 inputs, t)")));
    }
    let architecture = Architecture {
        state_inputs: (0..NX as u8).collect(),
        hidden_layers: hidden.len(),
        width,
        activation,
        layer_norm: hidden.iter().map(|h| h.layer_norm.is_some()).collect(),
        residual: true,
        rotate_xy: true,
    };
    let model = PincModel {
        architecture,
        dt,
        input_scaling: None,
        output_scaling: None,
        envelope: None,
        provenance: Provenance {
            source: "import-torch".into(),
            created_by: format!("pinc {}", env!("CARGO_PKG_VERSION")),
            ..Provenance::default()
        },
        weights: Weights { hidden, output },
        vehicle: crate::vehicle::VehicleParams::default(),
        hybrid: None,
        fitted: None,
    };
    validate(&model).map_err(|e| err(format!("the imported network is inconsistent: {e}")))?;
    Ok(model)
}
