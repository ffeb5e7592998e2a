//! The training loop: per-loss gradients, their combination and global clip, AdamW,
//! reduce-on-plateau on the smoothed dev loss, best-on-dev selection with the frozen
//! runtime, and a clean stop on interruption or a non-finite loss.

use super::GradCombine;
use super::Hybrid;
use super::config::{Backend, LossKind, LrSchedule, TrainConfig};
use super::grad_combine::{clip_global_norm, coefficients, weighted_sum};
use super::losses::{Batch, joint_losses, loss};
use super::net::PincNet;
use crate::dataset::TrajectorySet;
use crate::eval::{mean, one_step_mse, rollout_mse_per_trajectory, vpt};
use crate::model::{Envelope, PincModel, Provenance};
use crate::runtime::Predictor;
use crate::types::{NU, NX};
use crate::vehicle::VehicleParams;
use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::{AdamWConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use burn::tensor::Gradients;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Why training could not start.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// The configuration is inconsistent.
    #[error("invalid training configuration: {0}")]
    Config(String),
    /// A set does not fit the run.
    #[error("{set} set: {what}")]
    Data {
        /// Which set.
        set: &'static str,
        /// What is wrong with it.
        what: String,
    },
}

/// What one epoch did.
#[derive(Debug, Clone, Serialize)]
pub struct EpochRecord {
    /// 1-based epoch.
    pub epoch: usize,
    /// Learning rate used in the epoch.
    pub lr: f64,
    /// Mean of each loss over the epoch's batches, in the configuration's order (NaN for a
    /// loss the curriculum still held back).
    pub train: Vec<(LossKind, f64)>,
    /// One-step MSE on the dev set after the epoch.
    pub dev_one_step: f64,
    /// 10-step rollout MSE on the dev set (the scheduled loss).
    pub dev_rollout10: f64,
    /// Mean VPT on the dev set (s), the selection criterion.
    pub dev_vpt: f64,
    /// Exponentially smoothed `dev_rollout10`.
    pub dev_smoothed: f64,
    /// Whether these weights are the best so far.
    pub best: bool,
    /// Wall time since the start (s).
    pub elapsed_s: f64,
}

/// How training ended.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum StopReason {
    /// All epochs ran.
    Completed,
    /// The interrupt flag was raised.
    Interrupted {
        /// Epoch during which it was noticed.
        epoch: usize,
    },
    /// The wall-clock budget ran out.
    TimeLimit {
        /// Last completed epoch.
        epoch: usize,
    },
    /// A loss became NaN or infinite; the weights before that batch are kept.
    NonFiniteLoss {
        /// Epoch of the batch.
        epoch: usize,
        /// Which loss.
        loss: LossKind,
    },
}

/// The result of a run: the best-on-dev frozen model and the history.
pub struct TrainOutcome {
    /// Best weights, frozen, with envelope and provenance.
    pub model: PincModel,
    /// Epoch whose weights were kept (0: the initialisation).
    pub best_epoch: usize,
    /// Every completed epoch.
    pub history: Vec<EpochRecord>,
    /// How it ended.
    pub stop: StopReason,
    /// Wall time (s).
    pub seconds: f64,
    /// Mean wall time of one optimisation step (ms).
    pub step_ms: f64,
}

/// The training device of `backend`, with autodiff.
pub fn device(backend: Backend) -> Device {
    match backend {
        #[allow(deprecated)] // burn marks ndarray deprecated in favour of flex; the design asks for it.
        Backend::Ndarray => Device::ndarray().autodiff(),
        Backend::Flex => Device::flex().autodiff(),
    }
}

/// Per-channel min / max of the states and inputs of `set`.
pub fn envelope_of(set: &TrajectorySet) -> Envelope {
    let mut e = Envelope {
        state_min: [f64::INFINITY; NX],
        state_max: [f64::NEG_INFINITY; NX],
        input_min: [f64::INFINITY; NU],
        input_max: [f64::NEG_INFINITY; NU],
    };
    // The network sees the starts where the set has them, and is scored on the states.
    for x in set.states.iter().chain(&set.starts) {
        for k in 0..NX {
            e.state_min[k] = e.state_min[k].min(x[k]);
            e.state_max[k] = e.state_max[k].max(x[k]);
        }
    }
    for u in &set.inputs {
        for k in 0..NU {
            e.input_min[k] = e.input_min[k].min(u[k]);
            e.input_max[k] = e.input_max[k].max(u[k]);
        }
    }
    e
}

/// Flattens one loss's gradients in the module's visiting order (zeros where unused).
struct FlattenGrads<'a> {
    grads: &'a Gradients,
    out: Vec<f32>,
}

impl ModuleVisitor for FlattenGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        match param.grad(self.grads) {
            Some(g) => self.out.extend(g.try_into_vec_as::<f32>().expect("float gradient")),
            None => self.out.extend(std::iter::repeat_n(0.0, param.dims().iter().product())),
        }
    }
}

/// Cuts a flat gradient back into per-parameter tensors for the optimiser.
struct SplitGrads<'a> {
    flat: &'a [f32],
    offset: usize,
    device: Device,
    out: GradientsParams,
}

impl ModuleVisitor for SplitGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let dims: [usize; D] = param.dims();
        let n: usize = dims.iter().product();
        let chunk = self.flat[self.offset..self.offset + n].to_vec();
        self.offset += n;
        self.out.register(param.id, Tensor::<D>::from_data(TensorData::new(chunk, dims), &self.device));
    }
}

pub(super) fn flatten(net: &PincNet, grads: &Gradients) -> Vec<f32> {
    let mut v = FlattenGrads { grads, out: Vec::with_capacity(net.num_params()) };
    net.visit(&mut v);
    v.out
}

/// Freezes `net` with the run's envelope, provenance and vehicle (a hybrid's physics).
fn freeze(net: &PincNet, dt: f64, envelope: &Envelope, provenance: Provenance, vehicle: VehicleParams) -> PincModel {
    PincModel {
        hybrid: net.hybrid().map(|h| h.physics),
        fitted: None,
        architecture: net.architecture().clone(),
        dt,
        input_scaling: None,
        output_scaling: None,
        envelope: Some(envelope.clone()),
        provenance,
        weights: net.weights(),
        vehicle,
    }
}

/// Dev metrics of a frozen model: (one-step MSE, 10-step rollout MSE, mean VPT), and the
/// last two per dev window.
fn dev_metrics(model: &PincModel, dev: &TrajectorySet) -> ((f64, f64, f64), PerWindow) {
    let p = Predictor::<f32>::new(model);
    let one = one_step_mse(&p, dev).unwrap_or(f64::INFINITY);
    let roll = rollout_mse_per_trajectory(&p, dev, 10).unwrap_or_else(|_| vec![f64::INFINITY; dev.count]);
    let v = vpt(&p, dev).unwrap_or_else(|_| vec![0.0; dev.count]);
    ((one, mean(&roll), mean(&v)), PerWindow { vpt: v, rollout10: roll })
}

/// A model's dev metrics window by window.
#[derive(Debug, Clone)]
struct PerWindow {
    vpt: Vec<f64>,
    rollout10: Vec<f64>,
}

impl PerWindow {
    /// Whether `self` beats `base` on dev window by window beyond chance: the mean per-window
    /// VPT gain and the mean per-window 10-step MSE reduction both above twice their standard
    /// error (docs/MODEL.md section 13). A hybrid's correction must pass this against its
    /// physics; on a few dev windows, a gain in the mean alone is as often noise.
    fn clearly_better_than(&self, base: &PerWindow) -> bool {
        let clear = |gains: Vec<f64>| {
            let n = gains.len() as f64;
            if n < 2.0 || gains.iter().any(|g| !g.is_finite()) {
                return false;
            }
            let m = mean(&gains);
            let var = gains.iter().map(|g| (g - m).powi(2)).sum::<f64>() / (n - 1.0);
            m > 2.0 * (var / n).sqrt()
        };
        clear(self.vpt.iter().zip(&base.vpt).map(|(a, b)| a - b).collect())
            && clear(self.rollout10.iter().zip(&base.rollout10).map(|(a, b)| b - a).collect())
    }
}

/// Reduce-on-plateau with PyTorch's semantics (relative threshold 1e-4).
struct Plateau {
    best: f64,
    bad: usize,
}

impl Plateau {
    fn update(&mut self, cfg: &TrainConfig, metric: f64, lr: f64) -> f64 {
        if metric < self.best * (1.0 - 1e-4) {
            self.best = metric;
            self.bad = 0;
            return lr;
        }
        self.bad += 1;
        if self.bad > cfg.patience {
            self.bad = 0;
            return (lr * cfg.lr_factor).max(cfg.lr_min);
        }
        lr
    }
}

/// Trains on `train_set`, selects on `dev`, and returns the best frozen model. `source`
/// names the data in the provenance; `on_epoch` sees every epoch; raising `interrupt`
/// stops after the current batch.
///
/// # Errors
/// An invalid configuration, or sets that do not fit (empty, different sample periods).
pub fn train(
    cfg: &TrainConfig,
    train_set: &TrajectorySet,
    dev: &TrajectorySet,
    source: &str,
    interrupt: &AtomicBool,
    mut on_epoch: impl FnMut(&EpochRecord),
) -> Result<TrainOutcome, TrainError> {
    check_run(cfg, train_set, dev)?;
    let run = Run::new(cfg, train_set, dev, source);
    let mut net = PincNet::init(&cfg.architecture, cfg.seed, &run.device);
    if let Some(h) = cfg.hybrid {
        net = net.into_hybrid(Hybrid { vehicle: cfg.vehicle, physics: h });
    }
    let mut optim =
        AdamWConfig::new().with_epsilon(cfg.adam_eps as f32).with_weight_decay(cfg.weight_decay as f32).init();
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x7261_696e);
    // Epoch 0: for a hybrid, its physics (the network starts at zero), which a correction
    // must beat clearly on dev to replace.
    let (mut best, physics) = {
        let (model, metrics, windows) = run.measure(&net, 0);
        (Best::of(model, 0, metrics), cfg.hybrid.is_some().then_some(windows))
    };
    let mut schedule = Schedule { plateau: Plateau { best: f64::INFINITY, bad: 0 }, smoothed: f64::NAN, lr: cfg.lr };
    let mut history = Vec::new();
    let mut stop = StopReason::Completed;
    let mut steps = Steps::default();
    let mut order: Vec<usize> = (0..train_set.count).collect();
    for epoch in 1..=cfg.epochs {
        order.shuffle(&mut rng);
        let active = run.active(epoch);
        let losses;
        (net, losses) =
            run.epoch(epoch, net, &mut optim, &order, &mut schedule, &mut rng, interrupt, &mut steps, &active);
        let losses = match losses {
            Ok(losses) => losses,
            Err(reason) => {
                stop = reason;
                break;
            }
        };
        // Under the curriculum, only weights trained with every loss count.
        let complete = active.iter().all(|&on| on);
        let record = run.close_epoch(epoch, &net, losses, &mut schedule, &mut best, complete, physics.as_ref());
        on_epoch(&record);
        history.push(record);
        if cfg.time_limit_s.is_some_and(|t| run.start.elapsed().as_secs_f64() >= t) && epoch < cfg.epochs {
            stop = StopReason::TimeLimit { epoch };
            break;
        }
    }
    Ok(TrainOutcome {
        model: best.model,
        best_epoch: best.epoch,
        history,
        stop,
        seconds: run.start.elapsed().as_secs_f64(),
        step_ms: 1e3 * steps.seconds / steps.taken.max(1) as f64,
    })
}

/// Refuses an invalid configuration and sets that cannot be trained on together.
fn check_run(cfg: &TrainConfig, train_set: &TrajectorySet, dev: &TrajectorySet) -> Result<(), TrainError> {
    cfg.check().map_err(TrainError::Config)?;
    for (name, s) in [("training", train_set), ("dev", dev)] {
        if s.count == 0 || s.points < 2 {
            return Err(TrainError::Data {
                set: name,
                what: format!("{} trajectories of {} points", s.count, s.points),
            });
        }
    }
    if (train_set.dt - dev.dt).abs() > 1e-12 {
        return Err(TrainError::Data {
            set: "dev",
            what: format!("sample period {} s differs from training's {} s", dev.dt, train_set.dt),
        });
    }
    Ok(())
}

/// What stays fixed over a run: the configuration, the data, the devices, the physics and
/// what every frozen model records.
struct Run<'a> {
    cfg: &'a TrainConfig,
    train_set: &'a TrajectorySet,
    dev: &'a TrajectorySet,
    source: &'a str,
    device: Device,
    /// The device without autodiff, where the combined gradients are rebuilt.
    plain: Device,
    params: VehicleParams,
    envelope: Envelope,
    config_json: String,
    start: Instant,
}

/// The weights kept so far: the best dev VPT, ties broken by the 10-step rollout MSE.
struct Best {
    model: PincModel,
    epoch: usize,
    vpt: f64,
    rollout10: f64,
}

impl Best {
    /// `model` after `epoch`, its dev metrics recorded in its provenance.
    fn of(mut model: PincModel, epoch: usize, (one, roll, vpt): (f64, f64, f64)) -> Self {
        model.provenance.metrics = BTreeMap::from([
            ("dev_one_step_mse".into(), one),
            ("dev_rollout10_mse".into(), roll),
            ("dev_vpt_s".into(), vpt),
        ]);
        Self { model, epoch, vpt, rollout10: roll }
    }
}

/// The learning rate and what decides it: reduce-on-plateau on the smoothed dev loss.
struct Schedule {
    plateau: Plateau,
    smoothed: f64,
    lr: f64,
}

/// Optimisation steps taken, the wall time they took, and the lagged combination.
#[derive(Default)]
struct Steps {
    taken: usize,
    seconds: f64,
    /// Combination coefficients of the last step that measured every loss's gradient (zero
    /// for a loss left out).
    coefficients: Option<Vec<f64>>,
    /// The active losses when the coefficients were measured.
    measured_on: Option<Vec<bool>>,
    /// Steps since that measurement.
    since_refresh: usize,
}

impl<'a> Run<'a> {
    fn new(cfg: &'a TrainConfig, train_set: &'a TrajectorySet, dev: &'a TrajectorySet, source: &'a str) -> Self {
        let start = Instant::now();
        let device = device(cfg.backend);
        Self {
            cfg,
            train_set,
            dev,
            source,
            plain: device.clone().without_autodiff(),
            device,
            params: cfg.vehicle,
            envelope: envelope_of(train_set),
            config_json: serde_json::to_string(cfg).expect("config serialises"),
            start,
        }
    }

    fn provenance(&self, epochs: usize) -> Provenance {
        Provenance {
            source: self.source.to_string(),
            seed: self.cfg.seed,
            epochs: epochs as u64,
            config_json: self.config_json.clone(),
            metrics: BTreeMap::new(),
            created_by: format!("pinc {} train", env!("CARGO_PKG_VERSION")),
        }
    }

    /// `net` frozen after `epoch`, and its dev metrics (one-step MSE, 10-step rollout MSE,
    /// mean VPT; and per window).
    fn measure(&self, net: &PincNet, epoch: usize) -> (PincModel, (f64, f64, f64), PerWindow) {
        let model = freeze(net, self.train_set.dt, &self.envelope, self.provenance(epoch), self.params);
        let (metrics, windows) = dev_metrics(&model, self.dev);
        (model, metrics, windows)
    }

    /// How far the run is through its epochs, in [0, 1]; `within` is the fraction of `epoch`
    /// done. Schedules follow the epochs, never the wall clock, so a run repeats bit for bit
    /// on one machine; a time limit only cuts the run short.
    fn progress(&self, epoch: usize, within: f64) -> f64 {
        ((epoch as f64 - 1.0 + within) / self.cfg.epochs as f64).clamp(0.0, 1.0)
    }

    /// Which losses train in `epoch` (the curriculum holds the physics back at first).
    fn active(&self, epoch: usize) -> Vec<bool> {
        let physics_on = self.progress(epoch, 0.0) >= self.cfg.physics_after;
        self.cfg.losses.iter().map(|&k| physics_on || !TrainConfig::is_physics(k)).collect()
    }

    /// One pass over the training set in `order`: per batch, the losses and their
    /// gradients, combined and clipped, and one AdamW step. Returns the mean of each loss
    /// (NaN for one held back), or why the run stops.
    #[allow(clippy::too_many_arguments)] // the run's mutable state, each named
    fn epoch(
        &self,
        epoch: usize,
        mut net: PincNet,
        optim: &mut ModuleOptimizer,
        order: &[usize],
        schedule: &mut Schedule,
        rng: &mut ChaCha8Rng,
        interrupt: &AtomicBool,
        steps: &mut Steps,
        active: &[bool],
    ) -> (PincNet, Result<Vec<f64>, StopReason>) {
        let cfg = self.cfg;
        let mut sums = vec![0.0; cfg.losses.len()];
        let mut counts = vec![0usize; cfg.losses.len()];
        let batches = order.len().div_ceil(cfg.batch);
        for (b, chunk) in order.chunks(cfg.batch).enumerate() {
            if interrupt.load(Ordering::Relaxed) {
                return (net, Err(StopReason::Interrupted { epoch }));
            }
            if cfg.lr_schedule == LrSchedule::Cosine {
                let p = self.progress(epoch, b as f64 / batches as f64);
                schedule.lr = cfg.lr_min + 0.5 * (cfg.lr - cfg.lr_min) * (1.0 + (std::f64::consts::PI * p).cos());
            }
            let t0 = Instant::now();
            let batch = Batch::new(self.train_set, chunk, cfg, rng, &self.device);
            let (values, mut g) = self.gradients(&net, &batch, active, steps);
            if let Some(i) = values.iter().position(|v| v.is_some_and(|v| !v.is_finite())) {
                return (net, Err(StopReason::NonFiniteLoss { epoch, loss: cfg.losses[i] }));
            }
            if g.iter().any(|v| !v.is_finite()) {
                return (net, Err(StopReason::NonFiniteLoss { epoch, loss: LossKind::Data }));
            }
            clip_global_norm(&mut g, cfg.clip_norm);
            let mut split = SplitGrads { flat: &g, offset: 0, device: self.plain.clone(), out: GradientsParams::new() };
            net.visit(&mut split);
            net = optim.step(schedule.lr, net, split.out);
            steps.seconds += t0.elapsed().as_secs_f64();
            steps.taken += 1;
            for ((s, c), v) in sums.iter_mut().zip(&mut counts).zip(&values) {
                if let Some(v) = v {
                    *s += v;
                    *c += 1;
                }
            }
        }
        let means = sums.into_iter().zip(counts).map(|(s, c)| if c == 0 { f64::NAN } else { s / c as f64 });
        (net, Ok(means.collect()))
    }

    /// The value of every active loss on `batch` (`None` where not computed) and the combined
    /// flat gradient: one backward pass of the weighted sum (the plain-sum scheme, or a lagged
    /// step reusing the last measured combination), or one pass per loss combined by the
    /// configured scheme (every `grad_refresh`-th step, and whenever the active set changes).
    fn gradients(
        &self,
        net: &PincNet,
        batch: &Batch,
        active: &[bool],
        steps: &mut Steps,
    ) -> (Vec<Option<f64>>, Vec<f32>) {
        let cfg = self.cfg;
        let joint = |weights: &[f64]| {
            let (total, values) = joint_losses(cfg, net, &self.params, batch, weights);
            let g = flatten(net, &total.backward());
            (values.into_iter().map(|v| v.map(|v| f64::from(v.into_scalar::<f32>()))).collect(), g)
        };
        if cfg.grad == GradCombine::Sum {
            let w: Vec<f64> = cfg.weights.iter().zip(active).map(|(&w, &on)| if on { w } else { 0.0 }).collect();
            return joint(&w);
        }
        let stale = steps.measured_on.as_deref() != Some(active) || steps.since_refresh + 1 >= cfg.grad_refresh;
        if !stale {
            steps.since_refresh += 1;
            return joint(steps.coefficients.as_ref().expect("measured before"));
        }
        let mut values = vec![None; cfg.losses.len()];
        let (mut grads, mut weights, mut which) = (Vec::new(), Vec::new(), Vec::new());
        for (i, &k) in cfg.losses.iter().enumerate() {
            if !active[i] {
                continue;
            }
            let l = loss(k, net, &self.params, batch);
            grads.push(flatten(net, &l.backward()));
            values[i] = Some(f64::from(l.into_scalar::<f32>()));
            weights.push(cfg.weights[i]);
            which.push(i);
        }
        // The coefficients once: the step's direction and what the lagged steps reuse.
        let measured = coefficients(cfg.grad, &grads, &weights);
        let g = weighted_sum(&grads, &measured);
        let mut a = vec![0.0; cfg.losses.len()];
        for (&i, c) in which.iter().zip(measured) {
            a[i] = c;
        }
        steps.coefficients = Some(a);
        steps.measured_on = Some(active.to_vec());
        steps.since_refresh = 0;
        (values, g)
    }

    /// After an epoch: dev metrics, the learning-rate schedule, best-on-dev selection (for a
    /// hybrid, only among epochs clearly better than its `physics`), and the epoch's record.
    #[allow(clippy::too_many_arguments)] // the run's state, each named
    fn close_epoch(
        &self,
        epoch: usize,
        net: &PincNet,
        losses: Vec<f64>,
        schedule: &mut Schedule,
        best: &mut Best,
        complete: bool,
        physics: Option<&PerWindow>,
    ) -> EpochRecord {
        let cfg = self.cfg;
        let (frozen, (one, roll, v), windows) = self.measure(net, epoch);
        schedule.smoothed = if schedule.smoothed.is_nan() {
            roll
        } else {
            cfg.dev_smoothing * roll + (1.0 - cfg.dev_smoothing) * schedule.smoothed
        };
        let used_lr = schedule.lr;
        if cfg.lr_schedule == LrSchedule::Plateau {
            schedule.lr = schedule.plateau.update(cfg, schedule.smoothed, schedule.lr);
        }
        let is_best = complete
            && (v > best.vpt || (v == best.vpt && roll < best.rollout10))
            && physics.is_none_or(|p| windows.clearly_better_than(p));
        if is_best {
            *best = Best::of(frozen, epoch, (one, roll, v));
        }
        EpochRecord {
            epoch,
            lr: used_lr,
            train: cfg.losses.iter().copied().zip(losses).collect(),
            dev_one_step: one,
            dev_rollout10: roll,
            dev_vpt: v,
            dev_smoothed: schedule.smoothed,
            best: is_best,
            elapsed_s: self.start.elapsed().as_secs_f64(),
        }
    }
}

#[cfg(test)]
mod gate_tests {
    use super::PerWindow;

    fn windows(vpt: &[f64], rollout10: &[f64]) -> PerWindow {
        PerWindow { vpt: vpt.to_vec(), rollout10: rollout10.to_vec() }
    }

    #[test]
    fn a_correction_must_win_window_by_window_on_both_metrics() {
        let physics = windows(&[1.0; 8], &[1e-2; 8]);
        // Better everywhere, by a little: clear.
        let steady = windows(&[1.1, 1.2, 1.1, 1.15, 1.1, 1.2, 1.1, 1.1], &[8e-3; 8]);
        assert!(steady.clearly_better_than(&physics));
        // A larger mean VPT from one window, worse on the rest: not clear.
        let lucky = windows(&[4.0, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9], &[8e-3; 8]);
        assert!(!lucky.clearly_better_than(&physics));
        // Longer predictions but a worse 10-step error: not clear.
        assert!(!windows(&[1.2; 8], &[1.1e-2; 8]).clearly_better_than(&physics));
        // Equal (the physics itself), one window, or a diverged window: never.
        assert!(!physics.clearly_better_than(&physics));
        assert!(!windows(&[2.0], &[1e-3]).clearly_better_than(&windows(&[1.0], &[1e-2])));
        assert!(!windows(&[1.2; 8], &[f64::INFINITY; 8]).clearly_better_than(&physics));
    }
}
