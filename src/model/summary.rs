//! What `pinc inspect` shows: the header of a model without its weights.

use super::{Activation, Envelope, FORMAT_VERSION, HybridPhysics, PincModel, Provenance};
use crate::types::STATE_NAMES;
use crate::vehicle::VehicleParams;
use serde::Serialize;

/// A model's header: architecture, sample period, envelope, provenance, sizes.
#[derive(Debug, Clone, Serialize)]
pub struct ModelSummary {
    /// File format version.
    pub format_version: u32,
    /// File size in bytes, when read from a file.
    pub file_bytes: Option<usize>,
    /// Learned scalars.
    pub parameters: usize,
    /// Hidden layers.
    pub hidden_layers: usize,
    /// Units per hidden layer.
    pub width: usize,
    /// `softplus` or `tanh`.
    pub activation: &'static str,
    /// Learned betas, one per hidden layer.
    pub betas: Vec<f32>,
    /// 1-based hidden layers followed by a LayerNorm.
    pub layer_norm_after: Vec<usize>,
    /// Residual output.
    pub residual: bool,
    /// Planar increments rotated by the predicted yaw.
    pub rotate_xy: bool,
    /// Names of the state components the network sees.
    pub state_inputs: Vec<&'static str>,
    /// Sample period (s).
    pub dt: f64,
    /// Input normalisation present.
    pub input_scaling: bool,
    /// Output de-normalisation present.
    pub output_scaling: bool,
    /// Training envelope, if recorded.
    pub envelope: Option<Envelope>,
    /// The vehicle the physics loss used (in a hybrid, also the physics the network corrects).
    pub vehicle: VehicleParams,
    /// A hybrid's analytic part; `None` for a PINC.
    pub hybrid: Option<HybridPhysics>,
    /// Provenance and metrics.
    pub provenance: Provenance,
}

impl ModelSummary {
    /// Summarises `m`; `file_bytes` is the size of the file it came from, if any.
    pub fn new(m: &PincModel, file_bytes: Option<usize>) -> Self {
        let a = &m.architecture;
        Self {
            format_version: FORMAT_VERSION,
            file_bytes,
            parameters: m.parameter_count(),
            hidden_layers: a.hidden_layers,
            width: a.width,
            activation: match a.activation {
                Activation::Softplus => "softplus",
                Activation::Tanh => "tanh",
            },
            betas: m.weights.hidden.iter().map(|h| h.beta).collect(),
            layer_norm_after: a.layer_norm.iter().enumerate().filter(|(_, on)| **on).map(|(l, _)| l + 1).collect(),
            residual: a.residual,
            rotate_xy: a.rotate_xy,
            state_inputs: a.state_inputs.iter().map(|&i| STATE_NAMES[i as usize]).collect(),
            dt: m.dt,
            input_scaling: m.input_scaling.is_some(),
            output_scaling: m.output_scaling.is_some(),
            envelope: m.envelope.clone(),
            vehicle: m.vehicle,
            hybrid: m.hybrid,
            provenance: m.provenance.clone(),
        }
    }
}

impl std::fmt::Display for ModelSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "format version  {}", self.format_version)?;
        match &self.hybrid {
            Some(h) => writeln!(
                f,
                "model           hybrid: the vehicle below (RK4, {} sub-steps per step) plus the network's correction",
                h.substeps
            )?,
            None => writeln!(f, "model           PINC: the network's increment on the current state")?,
        }
        if let Some(b) = self.file_bytes {
            writeln!(f, "file size       {b} bytes")?;
        }
        writeln!(
            f,
            "network         {} x {} {}, {} parameters",
            self.hidden_layers, self.width, self.activation, self.parameters
        )?;
        writeln!(f, "betas           {:?}", self.betas)?;
        writeln!(f, "LayerNorm after hidden layers {:?}", self.layer_norm_after)?;
        writeln!(f, "residual        {}, yaw rotation {}", self.residual, self.rotate_xy)?;
        writeln!(f, "sees states     {}", self.state_inputs.join(", "))?;
        writeln!(f, "sample period   {} s", self.dt)?;
        writeln!(f, "scaling         input {}, output {}", self.input_scaling, self.output_scaling)?;
        match &self.envelope {
            Some(e) => {
                writeln!(f, "envelope        (training min .. max)")?;
                for (i, name) in STATE_NAMES.iter().enumerate() {
                    writeln!(f, "  {name:<8} {:>10.4} .. {:<10.4}", e.state_min[i], e.state_max[i])?;
                }
                for (i, name) in crate::types::INPUT_NAMES.iter().enumerate() {
                    writeln!(f, "  {name:<8} {:>10.4} .. {:<10.4}", e.input_min[i], e.input_max[i])?;
                }
            }
            None => writeln!(f, "envelope        none recorded")?,
        }
        // A hybrid's physics is half the model: every coefficient.
        if self.hybrid.is_some() {
            let all: Vec<String> = self.vehicle.named().iter().map(|(k, v)| format!("{k} = {v}")).collect();
            writeln!(f, "vehicle         {}", all.join(", "))?;
            return self.provenance_lines(f);
        }
        // The coefficients that differ from the BlueROV2's, or that it is the BlueROV2.
        let default = VehicleParams::default().named();
        let changed: Vec<String> = self
            .vehicle
            .named()
            .iter()
            .zip(default)
            .filter(|(a, b)| a.1 != b.1)
            .map(|((k, v), _)| format!("{k} = {v}"))
            .collect();
        match changed.is_empty() {
            true => writeln!(f, "vehicle         BlueROV2 (models/bluerov2.toml)")?,
            false => writeln!(f, "vehicle         BlueROV2 but {}", changed.join(", "))?,
        }
        self.provenance_lines(f)
    }
}

impl ModelSummary {
    fn provenance_lines(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let p = &self.provenance;
        writeln!(
            f,
            "source          {} (seed {}, {} epochs), written by {}",
            p.source, p.seed, p.epochs, p.created_by
        )?;
        for (k, v) in &p.metrics {
            writeln!(f, "  {k:<8} {v}")?;
        }
        Ok(())
    }
}
