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

impl EnvelopeExit {
    /// How far outside: the distance past the nearer bound in units of the range's width,
    /// so that components of different units can be ranked.
    pub fn excess(&self) -> f64 {
        let past = if self.value < self.min { self.min - self.value } else { self.value - self.max };
        past / (self.max - self.min).max(f64::MIN_POSITIVE)
    }
}

/// How far a predicted `(cos psi, sin psi)` may be off unit length, before the runtime
/// rescales it, without a warning: 1 %. A network trained on unit vectors that predicts one
/// further off has left what it learned (the drift grows along a horizon when nothing
/// rescales it: up to 10 % at the end of one for a model of the whole thrust range).
pub const HEADING_TOLERANCE: f64 = 0.01;

/// The predicted heading vector furthest off the unit circle during a call.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadingDrift {
    /// Step of the call whose prediction it was (0 for the first).
    pub step: usize,
    /// `|(cos psi, sin psi)| - 1` of the raw prediction (before any rescaling).
    pub deviation: f64,
}

/// Envelope exits counted during the last runtime call, and predicted heading vectors that
/// left the unit circle (a warning of its own kind: the heading is not a training-range
/// quantity, `cos psi` and `sin psi` are not checked against the envelope).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EnvelopeStatus {
    /// Steps at which a seen state or input component was outside the envelope.
    pub exits: usize,
    /// The first of them.
    pub first: Option<EnvelopeExit>,
    /// Per component (the 9 states, then the 4 inputs): its farthest exit.
    worst: [Option<EnvelopeExit>; NX + NU],
    /// Predictions whose heading vector was off unit length by more than
    /// [`HEADING_TOLERANCE`].
    pub heading_off_circle: usize,
    /// The farthest of them.
    pub heading_worst: Option<HeadingDrift>,
}

impl EnvelopeStatus {
    /// True if every value was inside the envelope (or the model has none).
    pub fn inside(&self) -> bool {
        self.exits == 0
    }

    /// True if no predicted heading vector left the unit circle by more than
    /// [`HEADING_TOLERANCE`].
    pub fn heading_on_circle(&self) -> bool {
        self.heading_off_circle == 0
    }

    /// True if nothing at all was recorded.
    pub(crate) fn is_clear(&self) -> bool {
        self.inside() && self.heading_on_circle()
    }

    /// Records the raw predicted heading vector's distance from unit length at `step`.
    #[inline(always)]
    pub(crate) fn record_heading(&mut self, step: usize, deviation: f64) {
        // NaN compares false: a prediction that is not finite is an error of its own.
        if deviation.abs() > HEADING_TOLERANCE {
            self.heading_off_circle += 1;
            if self.heading_worst.is_none_or(|w| deviation.abs() > w.deviation.abs()) {
                self.heading_worst = Some(HeadingDrift { step, deviation });
            }
        }
    }

    /// Every component that left the envelope, each at its farthest exit, the farthest
    /// ([`EnvelopeExit::excess`]) first.
    pub fn worst_exits(&self) -> Vec<EnvelopeExit> {
        let mut v: Vec<EnvelopeExit> = self.worst.iter().flatten().copied().collect();
        v.sort_by(|a, b| b.excess().total_cmp(&a.excess()));
        v
    }

    /// Records an exit of component `slot` (state index, or `NX +` input index).
    fn record(&mut self, slot: usize, exit: EnvelopeExit) {
        self.first.get_or_insert(exit);
        if self.worst[slot].is_none_or(|w| exit.excess() > w.excess()) {
            self.worst[slot] = Some(exit);
        }
    }
}

/// The envelope restricted to what the network sees.
#[derive(Debug, Clone)]
pub(crate) struct EnvelopeCheck {
    seen: [bool; NX],
    envelope: Option<Envelope>,
}

impl EnvelopeCheck {
    /// The check of `envelope` on the components in `seen`, less `cos psi` and `sin psi`:
    /// they lie on the unit circle by construction, so the range a training set happened to
    /// cover says nothing, and a prediction off the circle is reported apart
    /// ([`EnvelopeStatus::heading_off_circle`]). The envelope returned by
    /// [`Self::envelope`] keeps `[-1, 1]` for them.
    pub(crate) fn new(mut envelope: Option<Envelope>, seen: &[usize]) -> Self {
        let mut mask = [false; NX];
        for &i in seen {
            mask[i] = !matches!(i, 3 | 4);
        }
        if let Some(e) = &mut envelope {
            for i in [3, 4] {
                e.state_min[i] = e.state_min[i].min(-1.0);
                e.state_max[i] = e.state_max[i].max(1.0);
            }
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

    /// Records in `status` if `x` or `u` is outside the envelope at `step`: one exit for the
    /// step, and each component's farthest value outside.
    #[inline]
    pub(crate) fn check(&self, status: &mut EnvelopeStatus, step: usize, x: &State, u: &Input) {
        let Some(e) = &self.envelope else { return };
        let states =
            (0..NX).filter(|&i| self.seen[i]).map(|i| (i, Quantity::State(i), x[i], e.state_min[i], e.state_max[i]));
        let inputs = (0..NU).map(|i| (NX + i, Quantity::Input(i), u[i], e.input_min[i], e.input_max[i]));
        let mut left = false;
        for (slot, quantity, value, min, max) in states.chain(inputs) {
            if !(min..=max).contains(&value) {
                left = true;
                status.record(slot, EnvelopeExit { step, quantity, value, min, max });
            }
        }
        if left {
            status.exits += 1;
        }
    }
}
