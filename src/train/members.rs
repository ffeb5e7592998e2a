//! Several independently initialised trainings of one configuration on one data set, run
//! side by side (one thread each), and the member with the best dev VPT kept.
//!
//! One training's outcome depends on its initialisation and shuffling as much as on its
//! recipe (the paper's PINC recipe gave VPT1 from 2.65 to 3.79 s over three seeds here).
//! Members turn idle cores into a choice among draws, made on the dev set alone, so the
//! evaluation sets stay unseen.

use super::config::TrainConfig;
use super::trainer::{EpochRecord, TrainError, TrainOutcome, train};
use crate::dataset::TrajectorySet;
use std::sync::atomic::AtomicBool;

/// Initialisation and shuffling seed of member `index`: member 0 keeps the run's seed (one
/// member is exactly a plain training), the others are spread far from any small seed a
/// user would pick for another run.
pub fn member_seed(seed: u64, index: usize) -> u64 {
    seed.wrapping_add((index as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15))
}

/// Every member's outcome and which one was kept.
pub struct MembersOutcome {
    /// One per member, in member order.
    pub members: Vec<TrainOutcome>,
    /// Index of the kept member: the highest dev VPT of its best weights, ties broken by
    /// the 10-step dev rollout MSE.
    pub chosen: usize,
}

impl MembersOutcome {
    /// The kept member's outcome.
    pub fn best(&self) -> &TrainOutcome {
        &self.members[self.chosen]
    }
}

/// The dev VPT and 10-step rollout MSE of an outcome's kept weights.
fn dev_score(o: &TrainOutcome) -> (f64, f64) {
    let m = &o.model.provenance.metrics;
    let get = |k: &str| m.get(k).copied().unwrap_or(f64::NAN);
    (get("dev_vpt_s"), get("dev_rollout10_mse"))
}

/// Trains `members` copies of `cfg` at once, member `i` with seed [`member_seed`]`(cfg.seed,
/// i)` for its initialisation and shuffling (the data are the caller's), each with the whole
/// time limit, and keeps the one with the best dev VPT. `on_epoch` sees every member's
/// epochs with the member's index; `interrupt` stops them all.
///
/// # Errors
/// What [`train`] refuses, or zero members.
pub fn train_members(
    cfg: &TrainConfig,
    members: usize,
    train_set: &TrajectorySet,
    dev: &TrajectorySet,
    source: &str,
    interrupt: &AtomicBool,
    on_epoch: &(dyn Fn(usize, &EpochRecord) + Sync),
) -> Result<MembersOutcome, TrainError> {
    if members == 0 {
        return Err(TrainError::Config("members: need at least one".into()));
    }
    let configs: Vec<TrainConfig> =
        (0..members).map(|i| TrainConfig { seed: member_seed(cfg.seed, i), ..cfg.clone() }).collect();
    let outcomes: Vec<Result<TrainOutcome, TrainError>> = std::thread::scope(|s| {
        let handles: Vec<_> = configs
            .iter()
            .enumerate()
            .map(|(i, c)| s.spawn(move || train(c, train_set, dev, source, interrupt, |r| on_epoch(i, r))))
            .collect();
        handles.into_iter().map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p))).collect()
    });
    let members = outcomes.into_iter().collect::<Result<Vec<_>, _>>()?;
    let chosen = (0..members.len())
        .max_by(|&a, &b| {
            let (va, ra) = dev_score(&members[a]);
            let (vb, rb) = dev_score(&members[b]);
            // Higher VPT wins; at equal VPT the lower rollout error; earlier member on a tie.
            va.total_cmp(&vb).then(rb.total_cmp(&ra)).then(b.cmp(&a))
        })
        .expect("at least one member");
    Ok(MembersOutcome { members, chosen })
}
