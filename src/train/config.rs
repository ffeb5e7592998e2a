//! Everything a training run depends on, in one serialisable struct (it is stored verbatim
//! in the frozen model's provenance).

use super::GradCombine;
use crate::model::{Architecture, HybridPhysics};
use crate::vehicle::VehicleParams;
use serde::{Deserialize, Serialize};

/// The CPU backend burn trains on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Backend {
    /// burn's ndarray backend (the design's default).
    Ndarray,
    /// burn's pure-Rust flex backend.
    Flex,
}

/// The five losses of docs/MODEL.md section 4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum LossKind {
    /// One-step prediction against the next sample.
    Data,
    /// ODE residual at the collocation times.
    Physics,
    /// `x_hat(0) = x(0)`.
    InitialCondition,
    /// Multi-step rollout against the trajectory.
    Rollout,
    /// ODE residual along the rollout.
    PhysicsRollout,
}

impl LossKind {
    /// All kinds, the data loss first (the normalisation's reference gradient).
    pub const ALL: [LossKind; 5] =
        [LossKind::Data, LossKind::Physics, LossKind::InitialCondition, LossKind::Rollout, LossKind::PhysicsRollout];

    /// Short column name.
    pub fn name(self) -> &'static str {
        match self {
            LossKind::Data => "data",
            LossKind::Physics => "physics",
            LossKind::InitialCondition => "ic",
            LossKind::Rollout => "rollout",
            LossKind::PhysicsRollout => "physics_rollout",
        }
    }

    /// The kind named `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }

    /// The paper's weight for this loss in the normalisation scheme.
    pub fn paper_weight(self) -> f64 {
        match self {
            LossKind::Data | LossKind::Rollout => 1.0,
            LossKind::Physics | LossKind::PhysicsRollout | LossKind::InitialCondition => 0.5,
        }
    }
}

/// How the learning rate moves over a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum LrSchedule {
    /// Reduce-on-plateau on the smoothed dev loss (`patience`, `lr_factor`, `lr_min`).
    #[default]
    Plateau,
    /// Half a cosine from `lr` to `lr_min` over the run's epochs, updated every step: a fixed
    /// budget spends its end at a small rate instead of waiting out patience. It follows the
    /// epochs only (a time limit cuts the run short and does not speed the schedule up).
    Cosine,
}

/// A training run's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Network shape.
    pub architecture: Architecture,
    /// Active losses; the data loss must be among them and comes first.
    pub losses: Vec<LossKind>,
    /// Per-loss weights, parallel to `losses`.
    pub weights: Vec<f64>,
    /// How per-loss gradients are combined.
    pub grad: GradCombine,
    /// Epochs (passes over the training trajectories).
    pub epochs: usize,
    /// Trajectories per batch.
    pub batch: usize,
    /// Rollout length of the rollout losses.
    pub rollout_steps: usize,
    /// Rollouts start from every `rollout_stride`-th point (1: every point, as the paper).
    pub rollout_stride: usize,
    /// Initial learning rate.
    pub lr: f64,
    /// Learning-rate floor of the plateau scheduler.
    pub lr_min: f64,
    /// Epochs without improvement of the smoothed dev loss before the rate is cut.
    pub patience: usize,
    /// Factor the rate is cut by.
    pub lr_factor: f64,
    /// Exponential smoothing of the dev loss (weight of the newest value).
    pub dev_smoothing: f64,
    /// Global gradient-norm clip.
    pub clip_norm: f64,
    /// AdamW weight decay (decoupled).
    pub weight_decay: f64,
    /// AdamW epsilon.
    pub adam_eps: f64,
    /// Standard deviation of Gaussian noise added to the network's state and input features.
    pub input_noise: f64,
    /// Seed of the initialisation, shuffling and noise.
    pub seed: u64,
    /// Burn backend.
    pub backend: Backend,
    /// Wall-clock budget (s): training stops after the epoch that exceeds it.
    pub time_limit_s: Option<f64>,
    /// The vehicle whose equations the physics losses use (recorded in the model file).
    /// Default: the BlueROV2.
    #[serde(default)]
    pub vehicle: VehicleParams,
    /// Per-loss gradients are measured every `grad_refresh`-th step; the steps between take
    /// one backward pass of `sum_n a_n L_n` with the combination coefficients `a_n` of the
    /// last measuring step. 1: every step measures (the paper's scheme, one backward pass per
    /// loss). Ignored by the plain sum, which needs one pass anyway.
    #[serde(default = "one")]
    pub grad_refresh: usize,
    /// The learning-rate schedule.
    #[serde(default)]
    pub lr_schedule: LrSchedule,
    /// Curriculum: the physics, initial-condition and physics-rollout losses join once this
    /// fraction of the epochs has passed; before, only the data and
    /// rollout losses train. Weights are selected only from epochs with every loss active.
    #[serde(default)]
    pub physics_after: f64,
    /// Train a hybrid model: the network corrects `vehicle`'s RK4 step (this many sub-steps
    /// per step) instead of predicting the whole transition, and starts at zero, as the
    /// physics (docs/MODEL.md section 13). `None`: a PINC.
    #[serde(default)]
    pub hybrid: Option<HybridPhysics>,
}

fn one() -> usize {
    1
}

impl TrainConfig {
    /// The paper's best configuration (docs/MODEL.md section 6, "normalisation"): 4x32 softplus with
    /// residual, rotation and LayerNorm; all five losses with the paper's weights; batch 10;
    /// 20-step rollouts.
    pub fn paper() -> Self {
        let losses = LossKind::ALL.to_vec();
        Self {
            architecture: Architecture::paper(4, 32),
            weights: losses.iter().map(|k| k.paper_weight()).collect(),
            losses,
            grad: GradCombine::Normalize,
            epochs: 1200,
            batch: 10,
            rollout_steps: 20,
            rollout_stride: 1,
            lr: 8e-3,
            lr_min: 1e-4,
            patience: 100,
            lr_factor: 0.5,
            dev_smoothing: 0.1,
            clip_norm: 5.0,
            weight_decay: 0.01,
            adam_eps: 1e-8,
            input_noise: 0.0,
            seed: 0,
            backend: Backend::Ndarray,
            time_limit_s: None,
            vehicle: VehicleParams::default(),
            grad_refresh: 1,
            lr_schedule: LrSchedule::Plateau,
            physics_after: 0.0,
            hybrid: None,
        }
    }

    /// Keeps only the losses in `keep` (their paper weights stay).
    pub fn with_losses(mut self, keep: &[LossKind]) -> Self {
        let (losses, weights) = self.losses.iter().zip(&self.weights).filter(|(k, _)| keep.contains(k)).unzip();
        self.losses = losses;
        self.weights = weights;
        self
    }

    /// Whether `kind` is one of the losses the curriculum holds back (see `physics_after`).
    pub fn is_physics(kind: LossKind) -> bool {
        matches!(kind, LossKind::Physics | LossKind::InitialCondition | LossKind::PhysicsRollout)
    }

    /// Whether `kind` is active.
    pub fn uses(&self, kind: LossKind) -> bool {
        self.losses.contains(&kind)
    }

    /// Checks the combinations the trainer cannot run.
    ///
    /// # Errors
    /// A message naming the offending field.
    pub fn check(&self) -> Result<(), String> {
        if self.losses.first() != Some(&LossKind::Data) {
            return Err("losses: the data loss must be active and first".into());
        }
        if self.weights.len() != self.losses.len() {
            return Err("weights: one per active loss".into());
        }
        if self.epochs == 0 || self.batch == 0 {
            return Err("epochs and batch must be positive".into());
        }
        if (self.uses(LossKind::Rollout) || self.uses(LossKind::PhysicsRollout))
            && (self.rollout_steps == 0 || self.rollout_stride == 0)
        {
            return Err("rollout_steps and rollout_stride must be positive".into());
        }
        if !(self.lr > 0.0 && self.lr_min > 0.0 && self.lr_min <= self.lr) {
            return Err(format!("lr {} / lr_min {}: need 0 < lr_min <= lr", self.lr, self.lr_min));
        }
        let clip_ok = self.clip_norm.is_finite() && self.clip_norm > 0.0;
        if !clip_ok || self.dev_smoothing <= 0.0 || self.dev_smoothing > 1.0 || self.dev_smoothing.is_nan() {
            return Err("clip_norm must be positive and dev_smoothing in (0, 1]".into());
        }
        if self.grad_refresh == 0 {
            return Err("grad_refresh must be positive".into());
        }
        if !(0.0..1.0).contains(&self.physics_after) {
            return Err(format!("physics_after {}: need a fraction in [0, 1)", self.physics_after));
        }
        if let Some(h) = &self.hybrid {
            if h.substeps == 0 || h.substeps > crate::model::MAX_SUBSTEPS {
                return Err(format!("hybrid.substeps {}: need 1 to {}", h.substeps, crate::model::MAX_SUBSTEPS));
            }
            if !self.architecture.residual {
                return Err("hybrid: the network must be residual (it corrects the physics' step)".into());
            }
        }
        if self.time_limit_s.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
            return Err("time_limit_s must be positive".into());
        }
        Ok(())
    }
}
