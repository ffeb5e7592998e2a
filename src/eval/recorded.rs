//! A recorded dataset's set evaluated the way a controller starts its predictions: each
//! window's rollouts from the recorded first state, from the state pinc's estimator gives after
//! the samples before the window ([`crate::estimation::window_starts`]), or both side by side.
//! `pinc eval --data` and Python's `pinc.evaluate` are its two users.

use super::{SetMetrics, evaluate_set, evaluate_set_discrete};
use crate::dataset::{Dataset, TrajectorySet};
use crate::estimation::window_starts::{StartError, Targets, estimated_set};
use crate::model::PincModel;
use crate::runtime::RuntimeError;
use crate::vehicle::{Rk4Vehicle, VehicleParams};

/// Where each window's predictions start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum StartFrom {
    /// The recorded first state.
    Recorded,
    /// The estimator's state after the samples before the window.
    Estimated,
    /// Both, and the recorded start on the estimated windows alone.
    Both,
}

impl std::str::FromStr for StartFrom {
    type Err = RecordedEvalError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "recorded" => Ok(Self::Recorded),
            "estimated" => Ok(Self::Estimated),
            "both" => Ok(Self::Both),
            other => Err(RecordedEvalError::UnknownStart(other.to_string())),
        }
    }
}

/// What was evaluated in a [`Row`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Evaluated {
    /// The model at this index of the models given.
    Model(usize),
    /// The analytic model of the vehicle given.
    Vehicle,
}

/// One row of the evaluation: one model (or the analytic vehicle) from one kind of start.
#[derive(Clone, Copy, Debug)]
pub struct Row {
    /// The model or the vehicle.
    pub evaluated: Evaluated,
    /// `"recorded"`, `"recorded, estimated windows"` or `"estimated"`.
    pub start: &'static str,
    /// Its figures, scored against the recorded states whatever the start.
    pub metrics: SetMetrics,
}

/// The rows of [`evaluate_recorded`], and what the estimator assumed (`None` from recorded
/// starts alone).
#[derive(Clone, Debug)]
pub struct RecordedEvaluation {
    /// One row per start and model, then the vehicle, in that order.
    pub rows: Vec<Row>,
    /// One line of what the estimator assumed and how many windows it could start.
    pub estimator: Option<String>,
}

/// Why a recorded set could not be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum RecordedEvalError {
    /// Neither a model nor a vehicle was given.
    #[error("nothing to evaluate: give a model or a vehicle")]
    NothingToEvaluate,
    /// The dataset has no such set, or it has no window.
    #[error("the dataset has no {0:?} windows (imported with a zero fraction for it?)")]
    NoSet(String),
    /// A start other than recorded, estimated or both.
    #[error("unknown start {0:?}: recorded, estimated or both")]
    UnknownStart(String),
    /// The estimated starts could not be made.
    #[error(transparent)]
    Start(#[from] StartError),
    /// A model's rollouts failed (a non-finite value in the set).
    #[error("model {index}: {source}")]
    Model {
        /// Its index among the models given.
        index: usize,
        /// What failed.
        source: RuntimeError,
    },
    /// The analytic vehicle's rollouts failed.
    #[error("the vehicle's analytic model: {0}")]
    Vehicle(RuntimeError),
}

/// Sets, each with the label of its start.
type LabelledSets = Vec<(&'static str, TrajectorySet)>;

/// The sets `start` asks for, each with its label: the recorded starts of every window, those
/// of the windows that have an estimate, and their estimated starts (on `estimator`'s analytic
/// model, from `history_s` seconds of samples before each window).
///
/// # Errors
/// The estimator's refusals ([`StartError`]).
fn start_sets(
    data: &Dataset,
    set: &TrajectorySet,
    estimator: &VehicleParams,
    start: StartFrom,
    history_s: f64,
) -> Result<(LabelledSets, Option<String>), StartError> {
    if start == StartFrom::Recorded {
        return Ok((vec![("recorded", set.clone())], None));
    }
    let (starts, settings) = estimated_set(data, set, estimator, history_s, Targets::Recorded)?;
    let described = settings.describe(&starts);
    let sets = match start {
        StartFrom::Estimated => vec![("estimated", starts.estimated)],
        _ => vec![
            ("recorded", set.clone()),
            ("recorded, estimated windows", starts.recorded),
            ("estimated", starts.estimated),
        ],
    };
    Ok((sets, Some(described)))
}

/// [`SetMetrics`] of each model, and of `vehicle`'s analytic model, on the set `set_name` of
/// `data`, from the starts `start` asks for. The estimator runs on `vehicle` (else the first
/// model's vehicle, else the default one), so every row of a start starts from the same states;
/// a model's physics residual is against `vehicle`, else its own.
///
/// # Errors
/// Nothing to evaluate, no such set, the estimator's refusals, a rollout's failure.
pub fn evaluate_recorded(
    data: &Dataset,
    set_name: &str,
    models: &[&PincModel],
    vehicle: Option<&VehicleParams>,
    start: StartFrom,
    history_s: f64,
) -> Result<RecordedEvaluation, RecordedEvalError> {
    if models.is_empty() && vehicle.is_none() {
        return Err(RecordedEvalError::NothingToEvaluate);
    }
    let set = data.set(set_name).filter(|s| s.count > 0).ok_or_else(|| RecordedEvalError::NoSet(set_name.into()))?;
    let estimator = vehicle.copied().or_else(|| models.first().map(|m| m.vehicle)).unwrap_or_default();
    let (sets, described) = start_sets(data, set, &estimator, start, history_s)?;
    let mut rows = Vec::new();
    for (label, set) in &sets {
        for (index, model) in models.iter().enumerate() {
            let physics = vehicle.copied().unwrap_or(model.vehicle);
            let metrics =
                evaluate_set(model, set, &physics).map_err(|source| RecordedEvalError::Model { index, source })?;
            rows.push(Row { evaluated: Evaluated::Model(index), start: label, metrics });
        }
        if let Some(params) = vehicle {
            let analytic = Rk4Vehicle { params: *params, ..Rk4Vehicle::with_dt(set.dt) };
            let metrics = evaluate_set_discrete(&analytic, set).map_err(RecordedEvalError::Vehicle)?;
            rows.push(Row { evaluated: Evaluated::Vehicle, start: label, metrics });
        }
    }
    Ok(RecordedEvaluation { rows, estimator: described })
}
