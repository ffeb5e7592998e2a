//! A few epochs on a tiny set: the losses fall, the frozen model loads and runs, and a run
//! that meets a NaN or an interrupt stops cleanly with finite best weights.
#![cfg(feature = "train")]

use pinc::dataset::{DatasetPreset, TrajectorySet, generate_set};
use pinc::model::PincModel;
use pinc::runtime::Predictor;
use pinc::train::{Backend, LossKind, LrSchedule, StopReason, TrainConfig, member_seed, train, train_members};
use pinc::{Input, State};
use std::sync::atomic::AtomicBool;

fn set(name: &str, count: usize) -> TrajectorySet {
    let mut spec = DatasetPreset::paper().set(name).unwrap().clone();
    spec.count = count;
    generate_set(&spec, &Default::default(), 3, || {})
}

fn tiny_config(epochs: usize) -> TrainConfig {
    let mut cfg = TrainConfig::paper();
    cfg.epochs = epochs;
    cfg.batch = 4;
    cfg.rollout_steps = 10;
    cfg.rollout_stride = 8;
    cfg.backend = Backend::Flex;
    cfg
}

fn runs(m: &PincModel) {
    let p = Predictor::<f32>::new(m);
    let mut ws = p.workspace();
    let x0 = State::from([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let mut out = vec![State::zeros(); 11];
    p.rollout(&mut ws, &x0, &[Input::new(1.0, 0.0, 2.0, 0.0); 10], &mut out).unwrap();
    assert!(out.iter().all(|s| s.iter().all(|v| v.is_finite())));
}

#[test]
fn a_short_run_reduces_every_loss_and_freezes_a_loadable_model() {
    let (train_set, dev) = (set("train", 8), set("dev", 6));
    let cfg = tiny_config(8);
    let mut seen = 0;
    let out = train(&cfg, &train_set, &dev, "test", &AtomicBool::new(false), |_| seen += 1).unwrap();
    assert_eq!(out.stop, StopReason::Completed);
    assert_eq!((seen, out.history.len()), (8, 8));
    let (first, last) = (&out.history[0], &out.history[7]);
    for (i, &k) in cfg.losses.iter().enumerate() {
        assert!(
            last.train[i].1 < 0.5 * first.train[i].1,
            "{} loss did not fall: {:e} -> {:e}",
            k.name(),
            first.train[i].1,
            last.train[i].1
        );
    }
    assert!(last.dev_rollout10 < first.dev_rollout10);
    let bytes = out.model.to_bytes().unwrap();
    let back = PincModel::from_bytes(&bytes).unwrap();
    assert!(back.envelope.is_some());
    assert_eq!(back.provenance.metrics["dev_vpt_s"], out.history[out.best_epoch - 1].dev_vpt);
    runs(&back);
}

#[test]
fn a_nan_in_the_data_stops_training_and_keeps_finite_weights() {
    let (mut train_set, dev) = (set("train", 8), set("dev", 4));
    train_set.states[5][6] = f64::NAN;
    let cfg = tiny_config(3).with_losses(&[LossKind::Data]);
    let out = train(&cfg, &train_set, &dev, "test", &AtomicBool::new(false), |_| {}).unwrap();
    assert_eq!(out.stop, StopReason::NonFiniteLoss { epoch: 1, loss: LossKind::Data });
    assert_eq!(out.best_epoch, 0);
    runs(&out.model);
}

#[test]
fn an_interrupt_stops_before_the_next_batch_with_the_best_weights() {
    let (train_set, dev) = (set("train", 8), set("dev", 4));
    let out = train(&tiny_config(3), &train_set, &dev, "test", &AtomicBool::new(true), |_| {}).unwrap();
    assert_eq!(out.stop, StopReason::Interrupted { epoch: 1 });
    assert!(out.history.is_empty());
    runs(&out.model);
}

#[test]
fn inconsistent_inputs_are_refused_with_a_reason() {
    let (train_set, mut dev) = (set("train", 4), set("dev", 4));
    let mut cfg = tiny_config(1);
    cfg.losses.rotate_left(1);
    let e = train(&cfg, &train_set, &dev, "t", &AtomicBool::new(false), |_| {}).err().unwrap();
    assert!(e.to_string().contains("data loss must be active and first"), "{e}");
    dev.dt = 0.1;
    let e = train(&tiny_config(1), &train_set, &dev, "t", &AtomicBool::new(false), |_| {}).err().unwrap();
    assert!(e.to_string().contains("sample period"), "{e}");
}

#[test]
fn a_time_budget_ends_training_after_the_epoch_that_spends_it() {
    let (train_set, dev) = (set("train", 4), set("dev", 4));
    let mut cfg = tiny_config(5).with_losses(&[LossKind::Data]);
    cfg.time_limit_s = Some(1e-9);
    let out = train(&cfg, &train_set, &dev, "test", &AtomicBool::new(false), |_| {}).unwrap();
    assert_eq!(out.stop, StopReason::TimeLimit { epoch: 1 });
    assert_eq!(out.history.len(), 1);
    cfg.time_limit_s = Some(0.0);
    let e = train(&cfg, &train_set, &dev, "test", &AtomicBool::new(false), |_| {}).err().unwrap();
    assert!(e.to_string().contains("time_limit_s"), "{e}");
}

#[test]
fn the_cosine_schedule_falls_to_the_floor_and_the_curriculum_holds_the_physics_back() {
    let (train_set, dev) = (set("train", 8), set("dev", 6));
    let mut cfg = tiny_config(6);
    cfg.lr_schedule = LrSchedule::Cosine;
    cfg.physics_after = 0.5;
    cfg.grad_refresh = 3;
    let out = train(&cfg, &train_set, &dev, "test", &AtomicBool::new(false), |_| {}).unwrap();
    assert_eq!(out.history.len(), 6);
    // Two batches per epoch; the record keeps the rate of the epoch's last step, at
    // progress (epoch - 1 + 1/2) / 6.
    for r in &out.history {
        let p = (r.epoch as f64 - 0.5) / 6.0;
        let want = cfg.lr_min + 0.5 * (cfg.lr - cfg.lr_min) * (1.0 + (std::f64::consts::PI * p).cos());
        assert!((r.lr - want).abs() < 1e-12, "epoch {}: lr {} vs {want}", r.epoch, r.lr);
    }
    // Epochs 1-3 start before half the budget: data and rollout only.
    for r in &out.history {
        for &(k, v) in &r.train {
            let held = TrainConfig::is_physics(k) && r.epoch <= 3;
            assert_eq!(v.is_nan(), held, "epoch {} {}: {v}", r.epoch, k.name());
        }
    }
    // Only weights trained with every loss may be kept.
    assert!(out.best_epoch == 0 || out.best_epoch >= 4, "best epoch {}", out.best_epoch);
    assert!(out.history.iter().take(3).all(|r| !r.best));
}

#[test]
fn members_train_side_by_side_and_the_best_dev_vpt_is_kept() {
    let (train_set, dev) = (set("train", 8), set("dev", 6));
    let cfg = tiny_config(3);
    let seen = std::sync::Mutex::new([0usize; 3]);
    let out = train_members(&cfg, 3, &train_set, &dev, "test", &AtomicBool::new(false), &|i, _| {
        seen.lock().unwrap()[i] += 1;
    })
    .unwrap();
    assert_eq!(*seen.lock().unwrap(), [3, 3, 3]);
    // Member 0 is the plain run with the same seed, weight for weight (each member is a
    // training of its own, not disturbed by the others beside it).
    let plain = train(&cfg, &train_set, &dev, "test", &AtomicBool::new(false), |_| {}).unwrap();
    assert_eq!(out.members[0].model.weights, plain.model.weights);
    // Member 1 is the plain run with its own seed.
    let cfg1 = TrainConfig { seed: member_seed(cfg.seed, 1), ..cfg.clone() };
    let one = train(&cfg1, &train_set, &dev, "test", &AtomicBool::new(false), |_| {}).unwrap();
    assert_eq!(out.members[1].model.weights, one.model.weights);
    assert_ne!(out.members[0].model.weights, out.members[1].model.weights);
    let vpt = |i: usize| out.members[i].model.provenance.metrics["dev_vpt_s"];
    assert!((0..3).all(|i| vpt(out.chosen) >= vpt(i)), "kept member {} is not the best on dev", out.chosen);
    assert_eq!(out.best().model.weights, out.members[out.chosen].model.weights);
    assert!(train_members(&cfg, 0, &train_set, &dev, "test", &AtomicBool::new(false), &|_, _| {}).is_err());
}
