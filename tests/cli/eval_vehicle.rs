//! A folder of held-out runs (`--split 0,0,1`) and `pinc eval --vehicle`: the analytic model
//! of the vehicle that made the data predicts it; one with other damping does worse.

use serde_json::Value;
use std::process::{Command, Output};

const BLUEROV2: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/bluerov2.toml");

fn pinc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pinc")).args(args).output().expect("run pinc")
}

fn ok(out: Output, what: &str) -> String {
    assert!(out.status.success(), "{what} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

fn json(text: &str) -> Value {
    serde_json::from_str(text).unwrap_or_else(|e| panic!("{e}: {text}"))
}

#[test]
fn a_test_only_folder_scores_the_true_vehicle_near_zero_and_a_wrong_one_worse() {
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let mut logs = Vec::new();
    for seed in ["1", "2"] {
        let inputs = d(&format!("in{seed}.csv"));
        ok(
            pinc(&["excitation", "--design", "generic", "--out", &inputs, "--duration", "30", "--seed", seed]),
            "excitation",
        );
        let csv = ok(
            pinc(&["simulate", "--vehicle", BLUEROV2, "--x0", "0,0,1,0,0,0,0,0", "--inputs", &inputs, "--record"]),
            "simulate",
        );
        let log = d(&format!("run{seed}.csv"));
        std::fs::write(&log, csv).unwrap();
        logs.push(log);
    }
    // Held-out runs only; the period is taken from the logs (0.08 s).
    let held_out = d("held_out");
    let mut args = vec!["dataset", "import", "--out", &held_out, "--split", "0,0,1", "--json"];
    args.extend(logs.iter().map(String::as_str));
    let import = json(&ok(pinc(&args), "import"));
    assert_eq!(import["dt"], 0.08);
    assert_eq!(import["dt_from_log"], true);
    // 30 s: 375 intervals (the last row has no input), 5 windows of 66 points per run.
    assert_eq!(import["windows"], serde_json::json!({"train": 0, "dev": 0, "test": 10}));
    let streams = &import["files"][0]["report"]["streams"];
    assert_eq!(streams[0]["name"], "position");
    assert!((streams[0]["rate_hz"].as_f64().unwrap() - 12.5).abs() < 1e-6, "{streams}");

    // Nothing to train on: train refuses (in a build with the trainer), identify refuses.
    let out = pinc(&["identify", "--data", &held_out]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no train windows"));

    let wrong = d("wrong.toml");
    std::fs::write(&wrong, "x_u = -8.0\ny_v = -12.0\nn_r = -0.5\nz_ww = -60\n").unwrap();
    let eval = |vehicle: &str| {
        let v = json(&ok(pinc(&["eval", "--vehicle", vehicle, "--data", &held_out, "--json"]), "eval --vehicle"));
        assert_eq!(v.as_array().unwrap().len(), 1, "one row: {v}");
        v[0].clone()
    };
    let right = eval(BLUEROV2);
    assert_eq!(right["vehicle"], BLUEROV2);
    assert_eq!(right["windows"], 10);
    assert!(right["physics_mse"].is_null(), "n/a for the analytic model: {right}");
    // The same RK4 at the same period: only the state form (cos/sin integrated vs psi) and
    // the CSV's decimal digits differ.
    assert!(right["one_step_mse"].as_f64().unwrap() < 1e-12, "{right}");
    assert!(right["rollout10_mse"].as_f64().unwrap() < 1e-12, "{right}");
    assert!((right["vpt_s"].as_f64().unwrap() - 65.0 * 0.08).abs() < 1e-9, "{right}");
    let worse = eval(&wrong);
    assert!(worse["one_step_mse"].as_f64().unwrap() > 1e3 * right["one_step_mse"].as_f64().unwrap().max(1e-15));
    assert!(worse["vpt_s"].as_f64().unwrap() < right["vpt_s"].as_f64().unwrap(), "{worse}");

    // Models and the vehicle in one table.
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/models/mpc_pinc.pinc");
    let both = json(&ok(
        pinc(&["eval", "--model", model, "--vehicle", BLUEROV2, "--data", &held_out, "--json", "--no-plot"]),
        "eval --model --vehicle",
    ));
    assert_eq!(both.as_array().unwrap().len(), 2);
    assert_eq!((both[0]["model"].as_str(), both[1]["vehicle"].as_str()), (Some(model), Some(BLUEROV2)));
    assert!(both[0]["physics_mse"].as_f64().is_some_and(f64::is_finite));
    assert_eq!(both[1], right);
    let text = ok(pinc(&["eval", "--model", model, "--vehicle", BLUEROV2, "--data", &held_out, "--no-plot"]), "table");
    assert!(text.contains("mpc_pinc.pinc") && text.contains("bluerov2.toml (analytic)") && text.contains("n/a"));
}

#[test]
fn splits_need_one_positive_fraction_and_eval_needs_test_windows() {
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let inputs = d("in.csv");
    ok(pinc(&["excitation", "--design", "generic", "--out", &inputs, "--duration", "12", "--seed", "3"]), "excitation");
    let csv = ok(pinc(&["simulate", "--x0", "0,0,1,0,0,0,0,0", "--inputs", &inputs, "--record"]), "simulate");
    let log = d("run.csv");
    std::fs::write(&log, csv).unwrap();
    let out = pinc(&["dataset", "import", "--out", &d("none"), "--split", "0,0,0", &log]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("summing to 1"));
    let train_only = d("train_only");
    ok(pinc(&["dataset", "import", "--out", &train_only, "--split", "1,0,0", "--dt", "0.08", &log]), "import");
    let out = pinc(&["eval", "--vehicle", BLUEROV2, "--data", &train_only]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no test windows"));
    let out = pinc(&["eval", "--data", &train_only]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("needs a --model or a --vehicle"));
}
