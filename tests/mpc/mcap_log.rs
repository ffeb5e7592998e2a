//! The MCAP log of a closed-loop run, read back with the `mcap` crate's reader: topics,
//! message counts, JSON contents against the samples, metadata, and the `/log` messages of
//! fallbacks. The runs stop early (as Ctrl-C does), so these are also the early-stop files.
#![cfg(feature = "mpc")]

use crate::common;
use mcap::MessageStream;
use pinc::closed_loop::{LogStats, McapLog, RunInfo, file_sha256};
use pinc::closed_loop::{Sample, Scenario, run, summarise};
use pinc::model::PincModel;
use pinc::mpc::{Mpc, MpcConfig};
use pinc::runtime::Predictor;
use pinc::traits::DiscreteModel;
use pinc::vehicle::VehicleParams;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;

const MODEL: &str = "models/mpc_pinc.pinc";

/// Runs the PINC-MPC for `seconds` of `Default` with a log; returns the samples, the
/// writer's counts and the file's bytes.
fn logged_run(cfg: MpcConfig, seconds: f64) -> (Vec<Sample>, LogStats, Vec<u8>) {
    let model = PincModel::load(Path::new(MODEL)).unwrap();
    let predictor = Predictor::reference(&model);
    let bounds = predictor.input_bounds().unwrap();
    let cfg = MpcConfig { bounds: Some(bounds), ..cfg };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let info = RunInfo {
        controller: "pinc",
        model_path: Path::new(MODEL),
        scenario: &Scenario::default(),
        config: &cfg,
        bounds,
        dt: model.dt,
        vehicle: &VehicleParams::default(),
    };
    let mut log = McapLog::create(&path, &info).unwrap();
    let mut mpc = Mpc::new(predictor, cfg.clone()).unwrap();
    let samples = run(&mut mpc, &Scenario::default(), &VehicleParams::default(), |s| {
        log.record(s).unwrap();
        s.t + 1e-9 < seconds
    });
    let summary = summarise(&samples, &Scenario::default(), 1.6);
    let stats = log.finish(&summary, samples.last().unwrap().t).unwrap();
    (samples, stats, std::fs::read(&path).unwrap())
}

/// Every message as `(topic, log_time, JSON)`, in file order.
fn messages(bytes: &[u8]) -> Vec<(String, u64, Value)> {
    MessageStream::new(bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            assert_eq!(m.channel.message_encoding, "json");
            let schema = m.channel.schema.as_ref().expect("every channel has a schema");
            assert_eq!(schema.encoding, "jsonschema");
            let _: Value = serde_json::from_slice(&schema.data).expect("schema is JSON");
            (m.channel.topic.clone(), m.log_time, serde_json::from_slice(&m.data).expect("message is JSON"))
        })
        .collect()
}

fn metadata(bytes: &[u8], name: &str) -> BTreeMap<String, String> {
    let summary = mcap::Summary::read(bytes).unwrap().expect("a finished file has a summary section");
    let index = summary.metadata_indexes.iter().find(|i| i.name == name).expect("metadata record");
    mcap::read::metadata(bytes, index).unwrap().metadata
}

#[test]
fn a_log_holds_every_topic_once_per_sample_with_the_run_in_its_json() {
    // No fallbacks expected here (the next test makes them on purpose).
    let (samples, stats, bytes) = logged_run(common::untimed(), 4.0);
    let n = samples.len();
    assert_eq!(n, 51);
    let all = messages(&bytes);
    assert_eq!(all.len() as u64, stats.messages);
    let mut counts = BTreeMap::<&str, usize>::new();
    for (topic, _, _) in &all {
        *counts.entry(topic.as_str()).or_default() += 1;
    }
    for topic in ["/vehicle/state", "/vehicle/pose", "/mpc/reference", "/mpc/command", "/mpc/prediction", "/mpc/solver"]
    {
        assert_eq!(counts.get(topic), Some(&n), "{topic}: {counts:?}");
    }
    assert_eq!(counts["/tf"], 1);
    assert_eq!(counts["/log"] as u64, stats.log_messages);
    assert!(stats.log_messages >= 2, "start and end of the run");

    let on = |topic: &'static str| all.iter().filter(move |m| m.0 == topic);
    for ((_, time, state), s) in on("/vehicle/state").zip(&samples) {
        assert_eq!(*time, (s.t * 1e9).round() as u64);
        assert_eq!(state["sim"]["z"].as_f64().unwrap(), s.state[2]);
        assert_eq!(state["network"]["sin_psi"].as_f64().unwrap(), s.state[3].sin());
        assert_eq!(state["timestamp"]["nsec"].as_u64().unwrap() as f64, ((s.t * 1e9).round() % 1e9));
    }
    for ((_, _, pose), s) in on("/vehicle/pose").zip(&samples) {
        let q = &pose["pose"]["orientation"];
        let psi = 2.0 * q["z"].as_f64().unwrap().atan2(q["w"].as_f64().unwrap());
        assert!((psi - s.state[3]).abs() < 1e-12);
        assert_eq!(pose["frame_id"], "ned");
    }
    for ((_, _, cmd), s) in on("/mpc/command").zip(&samples) {
        assert_eq!(cmd["input"]["Mz"].as_f64().unwrap(), s.cycle.input[3]);
        assert_eq!(cmd["saturated"]["Z"].as_bool().unwrap(), s.cycle.saturated[2]);
        assert_eq!(cmd["fallback"], false);
    }
    for ((_, _, pred), s) in on("/mpc/prediction").zip(&samples) {
        let z: Vec<f64> = pred["z"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        assert_eq!(z.len(), 21);
        assert_eq!(z, s.prediction.iter().map(|x| x[2]).collect::<Vec<_>>());
        assert!((pred["t"][20].as_f64().unwrap() - (s.t + 1.6)).abs() < 1e-9);
    }
    for ((_, _, solver), s) in on("/mpc/solver").zip(&samples) {
        assert_eq!(solver["status"], "Solved");
        assert_eq!(solver["iterations"].as_u64().unwrap(), u64::from(s.cycle.iterations));
        assert_eq!(solver["solve_us"].as_f64().unwrap(), s.cycle.solve_us);
    }
    let reference: Vec<f64> = on("/mpc/reference").map(|m| m.2["depth_m"].as_f64().unwrap()).collect();
    assert_eq!(reference.iter().filter(|d| **d == 1.0).count(), samples.iter().filter(|s| s.t >= 2.0).count());

    let run = metadata(&bytes, "run");
    assert_eq!(run["model_sha256"], file_sha256(Path::new(MODEL)).unwrap());
    assert_eq!(run["horizon"], "20");
    assert_eq!(run["dt_s"], "0.08");
    assert_eq!(run["scenario"], "default");
    let input_max: Vec<f64> = serde_json::from_str(&run["input_max"]).unwrap();
    assert_eq!(input_max.len(), 4);
    let summary = metadata(&bytes, "summary");
    assert_eq!(summary["samples"], "51");
}

#[test]
fn fallbacks_are_logged_as_errors_and_the_file_still_reads() {
    let (samples, _, bytes) = logged_run(MpcConfig { solver_time_limit: 1e-12, ..MpcConfig::default() }, 1.0);
    assert!(samples.iter().all(|s| s.cycle.fallback.is_some()));
    let all = messages(&bytes);
    let errors: Vec<&Value> = all.iter().filter(|m| m.0 == "/log" && m.2["level"] == 4).map(|m| &m.2).collect();
    assert_eq!(errors.len(), samples.len());
    assert!(errors[0]["message"].as_str().unwrap().contains("fallback"), "{}", errors[0]);
    let commands = all.iter().filter(|m| m.0 == "/mpc/command");
    assert!(commands.clone().all(|m| m.2["fallback"] == true));
    assert_eq!(commands.count(), samples.len());
}

#[test]
fn the_model_digest_is_sha256() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("abc");
    std::fs::write(&path, b"abc").unwrap();
    // FIPS 180-2, appendix B.1.
    assert_eq!(file_sha256(&path).unwrap(), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    let e = file_sha256(&dir.path().join("missing")).unwrap_err();
    assert!(e.to_string().contains("missing"), "{e}");
}
