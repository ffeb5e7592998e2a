//! The training envelope check: cheap, read by the caller after each call.

use crate::model::Envelope;
use crate::types::{Input, NU, NX, State};

/// Which side of the envelope was left.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// A state component (index into the 9-state).
    State(usize),
    /// An input component.
    Input(usize),
}

/// The first value found outside the training envelope.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvelopeExit {
    /// Step of the call (0 for the first).
    pub step: usize,
    /// What left the envelope.
    pub quantity: Quantity,
    /// The value.
    pub value: f64,
    /// Training minimum.
    pub min: f64,
    /// Training maximum.
    pub max: f64,
}

/// Envelope exits counted during the last runtime call.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EnvelopeStatus {
    /// Steps at which a seen state or input component was outside the envelope.
    pub exits: usize,
    /// The first of them.
    pub first: Option<EnvelopeExit>,
}

impl EnvelopeStatus {
    /// True if every value was inside the envelope (or the model has none).
    pub fn inside(&self) -> bool {
        self.exits == 0
    }
}

/// The envelope restricted to what the network sees.
#[derive(Debug, Clone)]
pub(crate) struct EnvelopeCheck {
    seen: [bool; NX],
    envelope: Option<Envelope>,
}

impl EnvelopeCheck {
    pub(crate) fn new(envelope: Option<Envelope>, seen: &[usize]) -> Self {
        let mut mask = [false; NX];
        for &i in seen {
            mask[i] = true;
        }
        Self { seen: mask, envelope }
    }

    pub(crate) fn envelope(&self) -> Option<&Envelope> {
        self.envelope.as_ref()
    }

    /// Marks in `outside` the lanes of component-major `x`, `u` that [`Self::check`] would
    /// record (lanes past the used ones are marked too and must be ignored); true if any.
    /// Vectorises, so that the batch rollout checks per lane only where something left.
    #[inline]
    pub(crate) fn mark_lanes<const L: usize>(
        &self,
        x: &[[f64; L]; NX],
        u: &[[f64; L]; NU],
        outside: &mut [bool; L],
    ) -> bool {
        let Some(e) = &self.envelope else { return false };
        *outside = [false; L];
        let mut mark = |v: &[f64; L], min: f64, max: f64| {
            for (o, &v) in outside.iter_mut().zip(v) {
                *o |= !(v >= min && v <= max);
            }
        };
        for i in (0..NX).filter(|&i| self.seen[i]) {
            mark(&x[i], e.state_min[i], e.state_max[i]);
        }
        for i in 0..NU {
            mark(&u[i], e.input_min[i], e.input_max[i]);
        }
        outside.iter().any(|&o| o)
    }

    /// Records in `status` if `x` or `u` is outside the envelope at `step`.
    #[inline]
    pub(crate) fn check(&self, status: &mut EnvelopeStatus, step: usize, x: &State, u: &Input) {
        let Some(e) = &self.envelope else { return };
        let mut first = None;
        for i in 0..NX {
            if self.seen[i] && !(e.state_min[i]..=e.state_max[i]).contains(&x[i]) {
                first = Some(EnvelopeExit {
                    step,
                    quantity: Quantity::State(i),
                    value: x[i],
                    min: e.state_min[i],
                    max: e.state_max[i],
                });
                break;
            }
        }
        if first.is_none() {
            for i in 0..NU {
                if !(e.input_min[i]..=e.input_max[i]).contains(&u[i]) {
                    first = Some(EnvelopeExit {
                        step,
                        quantity: Quantity::Input(i),
                        value: u[i],
                        min: e.input_min[i],
                        max: e.input_max[i],
                    });
                    break;
                }
            }
        }
        if let Some(exit) = first {
            status.exits += 1;
            status.first.get_or_insert(exit);
        }
    }
}
