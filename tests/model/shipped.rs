//! The models shipped in `models/`: they load, say where they came from, and keep their
//! accuracy on trajectories they were never selected on (a seed other than the training's).
#![cfg(feature = "tools")]

use pinc::dataset::{DatasetPreset, TrajectorySet, generate_set};
use pinc::eval::vpt;
use pinc::model::PincModel;
use pinc::runtime::Predictor;

fn shipped(name: &str) -> PincModel {
    PincModel::load(format!("{}/models/{name}", env!("CARGO_MANIFEST_DIR"))).unwrap()
}

fn fresh(set: &str, seed: u64) -> TrajectorySet {
    let mut spec = DatasetPreset::paper().set(set).unwrap().clone();
    spec.count = 200;
    generate_set(&spec, &Default::default(), seed, || {})
}

fn mean_vpt(m: &PincModel, set: &TrajectorySet) -> f64 {
    let v = vpt(&Predictor::<f32>::new(m), set).unwrap();
    v.iter().sum::<f64>() / v.len() as f64
}

fn config(m: &PincModel) -> serde_json::Value {
    serde_json::from_str(&m.provenance.config_json).unwrap()
}

#[test]
fn shipped_paper_models_carry_their_provenance_and_envelope() {
    for (name, physics) in [("paper_pinc.pinc", true), ("paper_dnn.pinc", false)] {
        let m = shipped(name);
        assert!(m.provenance.source.contains("--preset paper"), "{name}: {}", m.provenance.source);
        assert!(m.provenance.epochs > 0 && m.envelope.is_some(), "{name}");
        for key in ["l1", "l2", "l3", "l4", "l5", "vpt1", "vpt2", "vpt3", "train_seconds"] {
            assert!(m.provenance.metrics[key].is_finite(), "{name}: metric {key}");
        }
        assert!(m.provenance.metrics["train_seconds"] <= 30.0 * 60.0, "{name}: training budget");
        let losses = config(&m)["losses"].to_string();
        assert_eq!(losses.contains("Physics"), physics, "{name}: losses {losses}");
        assert_eq!((m.architecture.hidden_layers, m.architecture.width), (4, 32), "{name}");
    }
}

#[test]
fn shipped_pinc_beats_the_data_only_baseline_at_sample_periods_it_was_not_fitted_on() {
    // The data-only network only ever sees t = T; the physics and initial-condition losses
    // teach the PINC what its time input means, so it keeps predicting at 0.06 s and 0.10 s.
    let (pinc, dnn) = (shipped("paper_pinc.pinc"), shipped("paper_dnn.pinc"));
    for set in ["interp", "extrap"] {
        let s = fresh(set, 7);
        let (a, b) = (mean_vpt(&pinc, &s), mean_vpt(&dnn, &s));
        assert!(a > b + 0.2, "{set}: PINC VPT {a:.3} s is not above the baseline's {b:.3} s");
    }
    // At the training period both predict for well over a second.
    let dev = fresh("dev_eval", 7);
    for (name, m) in [("pinc", &pinc), ("dnn", &dnn)] {
        let v = mean_vpt(m, &dev);
        assert!(v > 1.5, "{name}: dev VPT {v:.3} s");
    }
}
