//! The frozen `.pinc` model: what a file holds, as serde structs.
//!
//! On disk: `MAGIC (8 bytes) | FORMAT_VERSION (u32 LE) | payload length (u64 LE) |
//! CRC-32 of the payload (u32 LE) | payload`, the payload being [`PincModel`] encoded with
//! bincode 2 (standard configuration). The fixed header lets a reader refuse a foreign
//! file, a future version, a lying length or a corrupted payload before decoding anything.

use crate::types::{NU, NX};
use crate::vehicle::VehicleParams;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// First bytes of every `.pinc` file.
pub const MAGIC: [u8; 8] = *b"PINC\x00MDL";
/// Version written by this build; readers refuse newer ones and read every older one from
/// [`OLDEST_READ_VERSION`] on.
pub const FORMAT_VERSION: u32 = 4;
/// The oldest version still read: version 1 files have no vehicle and were all trained on
/// the BlueROV2.
pub const OLDEST_READ_VERSION: u32 = 1;
/// Bytes before the payload: magic, version, length, checksum.
pub const HEADER_SIZE: usize = 8 + 4 + 8 + 4;
/// Largest file a reader accepts (bytes); far above any network this runtime is for.
pub const MAX_FILE_BYTES: usize = 64 << 20;
/// Most hidden layers a model may declare.
pub const MAX_LAYERS: usize = 64;
/// Widest hidden layer a model may declare.
pub const MAX_WIDTH: usize = 4096;

const _: () = assert!(HEADER_SIZE == 24 && MAX_FILE_BYTES > HEADER_SIZE);

/// Hidden-layer activation, one learnable `beta` per layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Activation {
    /// `softplus(beta h) / beta`, with PyTorch's convention of returning `h` where
    /// `beta h > 20`.
    Softplus,
    /// `tanh(beta h)`.
    Tanh,
}

/// Shape and semantics of the network.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Architecture {
    /// Indices (into the 9-state) of the state components the network sees, increasing.
    /// The paper's network sees all nine; a position-free network omits 0, 1, 2.
    pub state_inputs: Vec<u8>,
    /// Number of hidden layers.
    pub hidden_layers: usize,
    /// Units per hidden layer.
    pub width: usize,
    /// Activation of every hidden layer.
    pub activation: Activation,
    /// For each hidden layer, whether a LayerNorm follows its activation.
    pub layer_norm: Vec<bool>,
    /// `x_hat = x + N(..)` (true, the paper's) or `x_hat = N(..)`.
    pub residual: bool,
    /// Rotate the planar increments `[dx, dy]` from body to world frame with the predicted yaw.
    pub rotate_xy: bool,
}

impl Architecture {
    /// The paper's network: all nine states seen, `hidden_layers x width`, adaptive softplus,
    /// LayerNorm after hidden layers 1, 3, 5, ... (1-based), residual and rotation on.
    pub fn paper(hidden_layers: usize, width: usize) -> Self {
        Self {
            state_inputs: (0..NX as u8).collect(),
            hidden_layers,
            width,
            activation: Activation::Softplus,
            layer_norm: (0..hidden_layers).map(|l| l % 2 == 0).collect(),
            residual: true,
            rotate_xy: true,
        }
    }

    /// Network input size: seen states, the four inputs and the time.
    pub fn input_size(&self) -> usize {
        self.state_inputs.len() + NU + 1
    }
}

/// A dense layer `y = W x + b`, `W` row-major `[rows x cols]` as PyTorch stores it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Linear {
    /// Output size.
    pub rows: usize,
    /// Input size.
    pub cols: usize,
    /// `rows * cols` weights, row-major.
    pub weight: Vec<f32>,
    /// `rows` biases.
    pub bias: Vec<f32>,
}

/// LayerNorm over one hidden layer: `gain * (a - mean) / sqrt(var + eps) + bias`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LayerNormWeights {
    /// Per-unit gain.
    pub gain: Vec<f32>,
    /// Per-unit bias.
    pub bias: Vec<f32>,
    /// Variance epsilon (PyTorch default 1e-5).
    pub eps: f32,
}

/// One hidden layer: linear map, adaptive activation, optional LayerNorm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HiddenLayer {
    /// The linear map.
    pub linear: Linear,
    /// The activation's learnable slope (any finite non-zero value, negative included).
    pub beta: f32,
    /// LayerNorm after the activation, where the architecture places one.
    pub layer_norm: Option<LayerNormWeights>,
}

/// Every learned parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Weights {
    /// Hidden layers, input side first.
    pub hidden: Vec<HiddenLayer>,
    /// Output layer `[9 x width]`.
    pub output: Linear,
}

/// Per-channel affine normalisation `(v - mean) / std`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Affine {
    /// Channel means.
    pub mean: Vec<f64>,
    /// Channel standard deviations (positive).
    pub std: Vec<f64>,
}

/// Per-channel ranges seen in training; the runtime flags anything outside.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// Minimum of each network-form state component.
    pub state_min: [f64; NX],
    /// Maximum of each network-form state component.
    pub state_max: [f64; NX],
    /// Minimum of each input.
    pub input_min: [f64; NU],
    /// Maximum of each input.
    pub input_max: [f64; NU],
}

/// Where a model came from.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    /// Dataset preset, or the import source.
    pub source: String,
    /// Dataset / training seed.
    pub seed: u64,
    /// Training epochs run.
    pub epochs: u64,
    /// Training configuration as JSON, verbatim.
    pub config_json: String,
    /// Final metrics (`l1`..`l5`, `vpt1`..`vpt3`, ...).
    pub metrics: BTreeMap<String, f64>,
    /// Tool and version that wrote the file.
    pub created_by: String,
}

/// A frozen PINC: everything needed to run it, and where it came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PincModel {
    /// Network shape and semantics.
    pub architecture: Architecture,
    /// Sample period the model was trained for (s).
    pub dt: f64,
    /// Normalisation of the network input `[seen states, inputs, t]`, if any.
    pub input_scaling: Option<Affine>,
    /// De-normalisation of the 9 network outputs (`out * std + mean`), if any.
    pub output_scaling: Option<Affine>,
    /// Training envelope, if known (an imported model has none).
    pub envelope: Option<Envelope>,
    /// Provenance and metrics.
    pub provenance: Provenance,
    /// The learned parameters.
    pub weights: Weights,
    /// The vehicle whose equations the physics loss used (format version 2; version 1 files
    /// read as the BlueROV2, the only vehicle they could have used). In a hybrid model, also
    /// the vehicle whose step the network corrects.
    pub vehicle: VehicleParams,
    /// Present in a hybrid model (format version 3): the next state is the analytic
    /// `vehicle`'s RK4 step plus the network's correction (docs/MODEL.md section 13). Absent:
    /// a PINC, the network's increment added to the current state. Files before version 3
    /// read as PINCs.
    pub hybrid: Option<HybridPhysics>,
    /// Present in a model fitted to a vehicle by `pinc fit` (format version 4): what the
    /// controller and the estimator need of that vehicle besides the dynamics.
    pub fitted: Option<FittedVehicle>,
}

/// The analytic part of a hybrid model: how `vehicle` is integrated over a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct HybridPhysics {
    /// Classic RK4 sub-steps per step (of whatever length the step is: `dt / substeps` each),
    /// as `pinc simulate` and the oracle integrate the vehicle.
    pub substeps: u32,
    /// The network's correction is taken relative to its output at rest (zero body
    /// velocities, the input that holds the physics still: the heave force that cancels its
    /// net buoyancy; the same step), so a vehicle holding station steps as its physics alone
    /// (format version 4; earlier hybrids read as `false`). Needs a network that sees no
    /// position or heading.
    pub rest_anchored: bool,
}

impl HybridPhysics {
    /// Sub-steps of at most the integrator's default 5 ms over a step of `dt`.
    pub fn for_period(dt: f64, rest_anchored: bool) -> Self {
        Self { substeps: crate::vehicle::Rk4Vehicle::with_dt(dt).substeps as u32, rest_anchored }
    }
}

/// The sensors of a vehicle as a fit identified them: what its state estimator assumes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SensorModel {
    /// Standard deviation of the depth reading (m).
    pub depth_std: f64,
    /// How long the depth reading lags the depth (s).
    pub depth_delay: f64,
    /// Standard deviation of the heading (rad).
    pub heading_std: f64,
    /// Standard deviation of the yaw rate (rad/s).
    pub yaw_rate_std: f64,
}

/// What a model fitted to one vehicle carries of it (docs/FIT.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FittedVehicle {
    /// The vehicle file's `[[thruster]]` and `[curve.*]` tables (TOML text): how a wrench
    /// becomes that vehicle's commands.
    pub thrusters_toml: String,
    /// The sensors, identified from the same recordings.
    pub sensors: SensorModel,
    /// What the fit's report found the data could not determine, one line each (empty: the
    /// fit passed); `mpc_track` prints them before it flies the model.
    pub warnings: Vec<String>,
}

/// A version 3 hybrid: without the anchoring at rest.
#[derive(Deserialize)]
pub(crate) struct HybridPhysicsV3 {
    substeps: u32,
}

/// A version 3 payload: [`PincModel`] without the fitted vehicle.
#[derive(Deserialize)]
pub(crate) struct PincModelV3 {
    architecture: Architecture,
    dt: f64,
    input_scaling: Option<Affine>,
    output_scaling: Option<Affine>,
    envelope: Option<Envelope>,
    provenance: Provenance,
    weights: Weights,
    vehicle: VehicleParams,
    hybrid: Option<HybridPhysicsV3>,
}

impl From<PincModelV3> for PincModel {
    fn from(v: PincModelV3) -> Self {
        Self {
            architecture: v.architecture,
            dt: v.dt,
            input_scaling: v.input_scaling,
            output_scaling: v.output_scaling,
            envelope: v.envelope,
            provenance: v.provenance,
            weights: v.weights,
            vehicle: v.vehicle,
            hybrid: v.hybrid.map(|h| HybridPhysics { substeps: h.substeps, rest_anchored: false }),
            fitted: None,
        }
    }
}

/// A version 2 payload: [`PincModel`] without the hybrid part.
#[derive(Deserialize)]
pub(crate) struct PincModelV2 {
    architecture: Architecture,
    dt: f64,
    input_scaling: Option<Affine>,
    output_scaling: Option<Affine>,
    envelope: Option<Envelope>,
    provenance: Provenance,
    weights: Weights,
    vehicle: VehicleParams,
}

impl From<PincModelV2> for PincModel {
    fn from(v: PincModelV2) -> Self {
        Self {
            architecture: v.architecture,
            dt: v.dt,
            input_scaling: v.input_scaling,
            output_scaling: v.output_scaling,
            envelope: v.envelope,
            provenance: v.provenance,
            weights: v.weights,
            vehicle: v.vehicle,
            hybrid: None,
            fitted: None,
        }
    }
}

/// A version 1 payload: [`PincModel`] without the vehicle.
#[derive(Deserialize)]
pub(crate) struct PincModelV1 {
    architecture: Architecture,
    dt: f64,
    input_scaling: Option<Affine>,
    output_scaling: Option<Affine>,
    envelope: Option<Envelope>,
    provenance: Provenance,
    weights: Weights,
}

impl From<PincModelV1> for PincModel {
    fn from(v: PincModelV1) -> Self {
        PincModelV2 {
            architecture: v.architecture,
            dt: v.dt,
            input_scaling: v.input_scaling,
            output_scaling: v.output_scaling,
            envelope: v.envelope,
            provenance: v.provenance,
            weights: v.weights,
            vehicle: VehicleParams::default(),
        }
        .into()
    }
}

impl PincModel {
    /// A hybrid model's physics: its vehicle with the file's sub-steps over the model's
    /// sample period; `None` for a PINC.
    pub fn hybrid_vehicle(&self) -> Option<crate::vehicle::Rk4Vehicle> {
        self.hybrid.map(|h| crate::vehicle::Rk4Vehicle {
            params: self.vehicle,
            dt: self.dt,
            substeps: h.substeps as usize,
        })
    }

    /// Whether this is a hybrid whose network adds nothing (its output layer, and any output
    /// scaling's mean, zero): the model is its physics everywhere, as a fit writes it when no
    /// correction beat the identified physics.
    pub fn correction_is_zero(&self) -> bool {
        let out = &self.weights.output;
        self.hybrid.is_some()
            && out.weight.iter().chain(&out.bias).all(|v| *v == 0.0)
            && self.output_scaling.as_ref().is_none_or(|s| s.mean.iter().all(|m| *m == 0.0))
    }

    /// The input that holds this model's vehicle still: the heave force that cancels its net
    /// buoyancy (what a hybrid anchored at rest is anchored at).
    pub fn rest_input(&self) -> crate::types::Input {
        crate::types::Input::new(0.0, 0.0, -self.vehicle.net_buoyancy(), 0.0)
    }

    /// Number of learned scalars.
    pub fn parameter_count(&self) -> usize {
        let lin = |l: &Linear| l.weight.len() + l.bias.len();
        let hidden: usize = self
            .weights
            .hidden
            .iter()
            .map(|h| lin(&h.linear) + 1 + h.layer_norm.as_ref().map_or(0, |n| n.gain.len() + n.bias.len()))
            .sum();
        hidden + lin(&self.weights.output)
    }
}
