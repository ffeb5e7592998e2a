//! Every check a model must pass before the runtime uses it.

use super::{Affine, Linear, MAX_LAYERS, MAX_WIDTH, ModelError, PincModel};
use crate::types::NX;

/// Most RK4 sub-steps a hybrid model may ask for per step (a 1 s step at 0.1 ms).
pub const MAX_SUBSTEPS: u32 = 10_000;

fn dim(what: impl Into<String>, expected: usize, found: usize) -> Result<(), ModelError> {
    if expected == found { Ok(()) } else { Err(ModelError::DimensionMismatch { what: what.into(), expected, found }) }
}

fn finite<T: Copy + Into<f64>>(what: &str, values: &[T]) -> Result<(), ModelError> {
    match values.iter().map(|&v| v.into()).enumerate().find(|(_, v)| !v.is_finite()) {
        Some((index, value)) => Err(ModelError::NonFinite { what: what.into(), index, value }),
        None => Ok(()),
    }
}

fn invalid(what: impl Into<String>, message: impl Into<String>) -> ModelError {
    ModelError::Invalid { what: what.into(), message: message.into() }
}

fn linear(name: &str, l: &Linear, rows: usize, cols: usize) -> Result<(), ModelError> {
    dim(format!("{name}.rows"), rows, l.rows)?;
    dim(format!("{name}.cols"), cols, l.cols)?;
    dim(format!("{name}.weight length"), rows * cols, l.weight.len())?;
    dim(format!("{name}.bias length"), rows, l.bias.len())?;
    finite(&format!("{name}.weight"), &l.weight)?;
    finite(&format!("{name}.bias"), &l.bias)
}

fn affine(name: &str, a: &Affine, n: usize) -> Result<(), ModelError> {
    dim(format!("{name}.mean length"), n, a.mean.len())?;
    dim(format!("{name}.std length"), n, a.std.len())?;
    finite(&format!("{name}.mean"), &a.mean)?;
    finite(&format!("{name}.std"), &a.std)?;
    match a.std.iter().position(|&s| s <= 0.0) {
        Some(i) => Err(invalid(format!("{name}.std[{i}]"), "must be positive")),
        None => Ok(()),
    }
}

/// Checks limits, every dimension against the architecture, finiteness and ranges.
pub fn validate(m: &PincModel) -> Result<(), ModelError> {
    m.vehicle.validate().map_err(|e| invalid("vehicle", e.to_string()))?;
    let a = &m.architecture;
    if a.hidden_layers == 0 || a.hidden_layers > MAX_LAYERS {
        return Err(ModelError::LimitExceeded {
            what: "hidden_layers (1 at least)",
            value: a.hidden_layers,
            max: MAX_LAYERS,
        });
    }
    if a.width == 0 || a.width > MAX_WIDTH {
        return Err(ModelError::LimitExceeded { what: "width (1 at least)", value: a.width, max: MAX_WIDTH });
    }
    if a.state_inputs.windows(2).any(|w| w[0] >= w[1]) || a.state_inputs.iter().any(|&i| i as usize >= NX) {
        return Err(invalid(
            "architecture.state_inputs",
            format!("{:?} must be increasing indices below 9", a.state_inputs),
        ));
    }
    dim("architecture.layer_norm length", a.hidden_layers, a.layer_norm.len())?;
    dim("hidden layer count", a.hidden_layers, m.weights.hidden.len())?;
    if !(m.dt.is_finite() && m.dt > 0.0) {
        return Err(invalid("dt", format!("{} is not a positive number of seconds", m.dt)));
    }
    for (l, h) in m.weights.hidden.iter().enumerate() {
        let cols = if l == 0 { a.input_size() } else { a.width };
        linear(&format!("hidden[{l}]"), &h.linear, a.width, cols)?;
        if !h.beta.is_finite() || h.beta == 0.0 {
            return Err(invalid(format!("hidden[{l}].beta"), format!("{} must be finite and non-zero", h.beta)));
        }
        match (&h.layer_norm, a.layer_norm[l]) {
            (Some(n), true) => {
                dim(format!("hidden[{l}].layer_norm.gain length"), a.width, n.gain.len())?;
                dim(format!("hidden[{l}].layer_norm.bias length"), a.width, n.bias.len())?;
                finite(&format!("hidden[{l}].layer_norm.gain"), &n.gain)?;
                finite(&format!("hidden[{l}].layer_norm.bias"), &n.bias)?;
                if !(n.eps.is_finite() && n.eps > 0.0) {
                    return Err(invalid(format!("hidden[{l}].layer_norm.eps"), format!("{} must be positive", n.eps)));
                }
            }
            (None, false) => {}
            (has, _) => {
                return Err(invalid(
                    format!("hidden[{l}].layer_norm"),
                    format!(
                        "architecture says {}, weights {}",
                        a.layer_norm[l],
                        if has.is_some() { "have one" } else { "have none" }
                    ),
                ));
            }
        }
    }
    linear("output", &m.weights.output, NX, a.width)?;
    if let Some(h) = &m.hybrid {
        if !a.residual {
            return Err(invalid(
                "architecture.residual",
                "a hybrid model's network corrects the physics' step: it must be residual",
            ));
        }
        if h.substeps == 0 || h.substeps > MAX_SUBSTEPS {
            return Err(ModelError::LimitExceeded {
                what: "hybrid.substeps (1 at least)",
                value: h.substeps as usize,
                max: MAX_SUBSTEPS as usize,
            });
        }
        if h.rest_anchored && a.state_inputs.iter().any(|&i| i < 5) {
            return Err(invalid(
                "hybrid.rest_anchored",
                "a correction anchored at rest must see the body velocities only (the network sees the position or heading)",
            ));
        }
    }
    if let Some(f) = &m.fitted {
        let s = &f.sensors;
        let positive = [("depth_std", s.depth_std), ("heading_std", s.heading_std), ("yaw_rate_std", s.yaw_rate_std)];
        if let Some((name, v)) = positive.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
            return Err(invalid("fitted.sensors", format!("{name} {v} must be a positive number")));
        }
        if !(s.depth_delay.is_finite() && (0.0..=1.0).contains(&s.depth_delay)) {
            return Err(invalid("fitted.sensors", format!("depth_delay {} must be 0 to 1 s", s.depth_delay)));
        }
    }
    if let Some(s) = &m.input_scaling {
        affine("input_scaling", s, a.input_size())?;
    }
    if let Some(s) = &m.output_scaling {
        affine("output_scaling", s, NX)?;
    }
    if let Some(e) = &m.envelope {
        for (name, lo, hi) in
            [("state", &e.state_min[..], &e.state_max[..]), ("input", &e.input_min[..], &e.input_max[..])]
        {
            finite(&format!("envelope.{name}_min"), lo)?;
            finite(&format!("envelope.{name}_max"), hi)?;
            if let Some(i) = lo.iter().zip(hi).position(|(l, h)| l > h) {
                return Err(invalid(format!("envelope.{name}[{i}]"), "min exceeds max"));
            }
        }
    }
    Ok(())
}
