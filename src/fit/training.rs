//! Stage 6, the training: the hybrid's configuration (a correction of the identified vehicle's
//! step, anchored at rest), the train and dev splits it learns on, and whether the time cap
//! cut it. Apart because it is the only stage that learns; the ones before it identify.

use super::{FitError, FitSettings};
use crate::dataset::{Dataset, TrajectorySet};
use crate::model::HybridPhysics;
use crate::train::{Backend, LossKind, LrSchedule, StopReason, TrainConfig, TrainOutcome};
use crate::vehicle::VehicleParams;

/// The train and dev splits, both non-empty.
pub(super) fn splits(data: &Dataset) -> Result<(&TrajectorySet, &TrajectorySet), FitError> {
    let get = |name: &str| {
        data.set(name)
            .filter(|s| s.count > 0)
            .ok_or_else(|| FitError::Data(format!("the {name} split is empty: record longer (a few minutes at least)")))
    };
    Ok((get("train")?, get("dev")?))
}

/// The hybrid's training: a correction of the identified vehicle's step that sees the body
/// velocities and the input only, anchored at rest, on the data and rollout losses (the
/// physics is the identified vehicle's own), a cosine schedule over the epochs, on ndarray
/// (deterministic on one machine).
pub fn train_config(settings: &FitSettings, vehicle: VehicleParams, horizontal: bool) -> TrainConfig {
    let mut cfg = TrainConfig::paper();
    cfg.architecture = crate::model::Architecture::paper(settings.layers, settings.width);
    // The body velocities it can learn from: without a position source `u` and `v` are the
    // starting file's own motion (zero under a designed heave-and-yaw excitation), so the
    // correction sees `w` and `r` only.
    cfg.architecture.state_inputs = if horizontal { (5..crate::NX as u8).collect() } else { vec![7, 8] };
    cfg = cfg.with_losses(&[LossKind::Data, LossKind::Rollout]);
    cfg.epochs = settings.epochs;
    cfg.lr = 1e-3;
    cfg.lr_schedule = LrSchedule::Cosine;
    cfg.rollout_stride = 4;
    cfg.grad_refresh = 10;
    cfg.backend = Backend::Ndarray;
    cfg.seed = settings.seed;
    cfg.time_limit_s = settings.time_cap_s;
    cfg.vehicle = vehicle;
    cfg.hybrid = Some(HybridPhysics::for_period(settings.dt, true));
    cfg
}

/// Whether the training ran its epochs or the time cap cut it.
pub fn cut_by_time(outcome: &TrainOutcome) -> Option<usize> {
    match outcome.stop {
        StopReason::TimeLimit { epoch } => Some(epoch),
        _ => None,
    }
}
