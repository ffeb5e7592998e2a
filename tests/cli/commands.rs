//! The `pinc` command line: CSV contracts, exit codes and one-line errors.

use pinc::vehicle::Rk4Vehicle;
use pinc::{Input, SimState};
use std::path::Path;
use std::process::{Command, Output};

fn pinc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pinc")).args(args).output().expect("run pinc")
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn simulate_reproduces_the_library_trajectory_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let mut csv = String::from("X,Y,Z,Mz\n");
    let inputs: Vec<Input> =
        (0..40).map(|k| Input::new(5.0, 0.1 * k as f64, 2.5, if k < 20 { 0.5 } else { -0.25 })).collect();
    for u in &inputs {
        csv += &format!("{},{},{},{}\n", u[0], u[1], u[2], u[3]);
    }
    let path = write(dir.path(), "in.csv", &csv);
    let out = pinc(&["simulate", "--x0", "0.5,-1,2,3.0,0.1,0,-0.05,0.2", "--inputs", &path, "--dt", "0.1"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("t,x,y,z,psi,u,v,w,r"));
    let rows: Vec<Vec<f64>> = lines.map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect();
    assert_eq!(rows.len(), inputs.len() + 1);
    let s0 = SimState::from([0.5, -1.0, 2.0, 3.0, 0.1, 0.0, -0.05, 0.2]);
    let expected = Rk4Vehicle::with_dt(0.1).simulate(&s0, &inputs);
    for (k, (row, s)) in rows.iter().zip(&expected).enumerate() {
        assert_eq!(row[0], k as f64 * 0.1);
        assert_eq!(&row[1..], s.as_slice(), "row {k} must round-trip exactly");
    }
    // Yaw is wrapped to (-pi, pi]: starting at 3.0 rad with positive r it wraps negative.
    assert!(rows.iter().any(|r| r[4] < 0.0) && rows.iter().all(|r| r[4] > -std::f64::consts::PI));
}

#[test]
fn simulate_constant_surge_matches_hand_computed_first_step() {
    // From rest with Z balancing buoyancy and only X: u(t) obeys (m - Xud) u' = X + Xu u + Xuu u|u|,
    // so over one small step u ~ X dt / (m - Xud).
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "in.csv", "Mz,Z,Y,X\n0,-3.9126,0,2\n");
    let out = pinc(&["simulate", "--x0", "0,0,0,0,0,0,0,0", "--inputs", &path, "--dt", "0.001"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    let last: Vec<f64> = text.lines().last().unwrap().split(',').map(|v| v.parse().unwrap()).collect();
    let u = last[5];
    assert!((u - 2.0 * 0.001 / 14.0).abs() < 1e-8, "u after 1 ms = {u}");
}

fn assert_csv_error(csv: &str, needle: &str) {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "bad.csv", csv);
    let out = pinc(&["simulate", "--x0", "0,0,0,0,0,0,0,0", "--inputs", &path]);
    assert_eq!(out.status.code(), Some(1), "csv {csv:?}");
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "one-line error, got {err:?}");
    assert!(err.contains(needle), "error {err:?} should mention {needle:?}");
    assert!(!err.contains("panicked"));
    assert!(out.stdout.is_empty(), "no partial output");
}

#[test]
fn malformed_csv_gives_one_line_errors_naming_the_line() {
    assert_csv_error("", "empty");
    assert_csv_error("X,Y,Z\n1,2,3\n", "missing column \"Mz\"");
    assert_csv_error("X,Y,Z,Mz\n1,2,3,4\n1,2,abc,4\n", "line 3: column Z: \"abc\" is not a number");
    assert_csv_error("X,Y,Z,Mz\n1,2,3,4\n1,2,3,4\nNaN,0,0,0\n", "line 4: column X: NaN is not finite");
    assert_csv_error("X,Y,Z,Mz\n1,2,3\n", "line 2: 3 fields, header has 4");
    assert_csv_error("X,Y,Z,Mz\n", "no input rows");
    assert_csv_error("X,Y,Z,Mz\n1,2,3,inf\n", "line 2: column Mz: inf is not finite");
}

#[test]
fn bad_arguments_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "in.csv", "X,Y,Z,Mz\n1,2,3,4\n");
    assert_eq!(pinc(&["simulate", "--inputs", &path]).status.code(), Some(2), "missing --x0");
    assert_eq!(pinc(&["frobnicate"]).status.code(), Some(2));
    let out = pinc(&["simulate", "--x0", "1,2,3", "--inputs", &path]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("expected 8"));
    let out = pinc(&["simulate", "--x0", "0,0,0,0,0,0,0,0", "--inputs", "/nonexistent/in.csv"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/in.csv"));
}

#[test]
fn gen_data_writes_a_loadable_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("paper");
    let out = pinc(&["gen-data", "--preset", "paper", "--out", out_dir.to_str().unwrap(), "--seed", "4"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let data = pinc::dataset::load(&out_dir).unwrap();
    assert_eq!(data.seed, 4);
    assert_eq!(data, pinc::dataset::generate(&pinc::dataset::DatasetPreset::paper(), 4, || {}));
    assert_eq!(pinc(&["gen-data", "--preset", "nope", "--out", "x"]).status.code(), Some(2));
}

fn fixture_path(name: &str) -> String {
    format!("{}/tests/fixtures/{name}", env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn import_inspect_predict_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let model_path = dir.path().join("m.pinc");
    let model = model_path.to_str().unwrap();
    let out = pinc(&["import-torch", "--weights", &fixture_path("random_4x32.safetensors"), "--out", model]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let size = std::fs::metadata(&model_path).unwrap().len();
    assert!(size < 20_000, "4x32 model file is {size} bytes");

    let out = pinc(&["inspect", model, "--json"]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["hidden_layers"], 4);
    assert_eq!(v["width"], 32);
    assert_eq!(v["layer_norm_after"], serde_json::json!([1, 3]));
    assert_eq!(v["file_bytes"], size);
    assert_eq!(v["betas"][1].as_f64().unwrap() as f32, -0.9_f32); // a negative beta survives import
    let text = String::from_utf8(pinc(&["inspect", model]).stdout).unwrap();
    assert!(text.contains("4 x 32 softplus") && text.contains("envelope        none recorded"));

    // predict = the library's rollout, converted to the simulator form.
    let inputs = write(dir.path(), "in.csv", "X,Y,Z,Mz\n1,0.1,2,0.05\n0.5,0,3,-0.05\n0,0,1,0\n");
    let out = pinc(&["predict", "--model", model, "--x0", "0.1,-0.2,0.3,2.5,0.1,0,0.05,0.1", "--inputs", &inputs]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let rows: Vec<Vec<f64>> =
        text.lines().skip(1).map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect();
    let m = pinc::model::PincModel::load(&model_path).unwrap();
    let p = pinc::runtime::Predictor::new(&m);
    let x0 = pinc::vehicle::to_network(&SimState::from([0.1, -0.2, 0.3, 2.5, 0.1, 0.0, 0.05, 0.1]));
    let us = [Input::new(1.0, 0.1, 2.0, 0.05), Input::new(0.5, 0.0, 3.0, -0.05), Input::new(0.0, 0.0, 1.0, 0.0)];
    let mut traj = vec![pinc::State::zeros(); 4];
    p.rollout(&mut p.workspace(), &x0, &us, &mut traj).unwrap();
    for (row, x) in rows.iter().zip(&traj) {
        assert_eq!(&row[1..], pinc::vehicle::to_simulator(x).as_slice());
    }
}

#[test]
fn bad_model_files_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let inputs = write(dir.path(), "in.csv", "X,Y,Z,Mz\n1,0,2,0\n");
    let garbage = write(dir.path(), "garbage.pinc", "this is not a model");
    for args in [
        vec!["inspect", garbage.as_str()],
        vec!["predict", "--model", garbage.as_str(), "--x0", "0,0,0,0,0,0,0,0", "--inputs", inputs.as_str()],
        vec!["inspect", "/nonexistent/m.pinc"],
        vec!["import-torch", "--weights", garbage.as_str(), "--out", "/tmp/never.pinc"],
    ] {
        let out = pinc(&args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let err = String::from_utf8(out.stderr).unwrap();
        assert_eq!(err.lines().count(), 1, "{err:?}");
        assert!(err.contains(".pinc") || err.contains("garbage"), "{err:?} names the file");
    }
}

/// Flags of a training run of seconds: two epochs on eight trajectories.
#[cfg(feature = "train")]
const TINY_TRAINING: &[&str] = &[
    "--epochs",
    "2",
    "--batch",
    "4",
    "--train-count",
    "8",
    "--dev-count",
    "4",
    "--eval-count",
    "5",
    "--rollout-steps",
    "5",
    "--rollout-stride",
    "8",
    "--backend",
    "flex",
];

/// A tiny end-to-end `train` + `eval`: every output file exists, the JSON carries the
/// contract's keys, and the architecture switches reach the frozen file.
#[cfg(feature = "train")]
#[test]
fn train_then_eval_writes_model_metrics_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("tiny.pinc");
    let m = model.to_str().unwrap();
    let vehicle = write(dir.path(), "v.toml", "y_vd = -15.5\n");
    let args = ["--preset", "paper", "--position-free", "--json", "--vehicle", &vehicle, "--out", m];
    let out = pinc(&[&["train"], TINY_TRAINING, &args[..]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["epochs_run"], 2);
    for ext in ["csv", "png"] {
        assert!(model.with_extension(ext).exists(), "{ext} missing");
    }
    let frozen = pinc::model::PincModel::load(&model).unwrap();
    assert_eq!(frozen.architecture.state_inputs, vec![3, 4, 5, 6, 7, 8]);
    assert_eq!(frozen.vehicle.y_vd, -15.5, "the physics loss's vehicle is recorded");
    let csv = std::fs::read_to_string(model.with_extension("csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "header and one row per epoch");
    // The curves can be redrawn from the CSV alone; a damaged CSV is a one-line error.
    let png = dir.path().join("again.png");
    let out = pinc(&["plot-training", model.with_extension("csv").to_str().unwrap(), "--out", png.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8(out.stdout).unwrap().starts_with("2 epochs -> "));
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000, "a drawn figure");
    let damaged = write(dir.path(), "damaged.csv", &csv.replacen("\n1,", "\nx,", 1));
    let out = pinc(&["plot-training", &damaged]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("damaged.csv: line 2: column epoch: \"x\" is not a number") && err.lines().count() == 1,
        "{err}"
    );

    let plot = dir.path().join("eval.png");
    let out = pinc(&["eval", "--model", m, "--count", "5", "--json", "--plot", plot.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in ["l1", "l2", "l3", "l4", "l5", "vpt1", "vpt2", "vpt3"] {
        assert!(v[key].is_number(), "{key}: {}", v[key]);
    }
    assert!(plot.exists());
    assert_eq!(pinc(&["train", "--out", m, "--grad", "nope"]).status.code(), Some(2));
}

/// `--members 2`: both members' curves, the kept one's as the run's CSV, and the kept
/// member's index and count in the JSON and the frozen file.
#[cfg(feature = "train")]
#[test]
fn train_with_two_members_keeps_the_better_on_dev_and_writes_both_curves() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("two.pinc");
    let m = model.to_str().unwrap();
    let out = pinc(&[&["train"], TINY_TRAINING, &["--members", "2", "--json", "--out", m]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let dev: Vec<f64> = serde_json::from_value(v["members"].clone()).unwrap();
    let kept = v["member_kept"].as_u64().unwrap() as usize;
    assert!(dev.len() == 2 && dev[kept] >= dev[1 - kept], "{v}");
    let frozen = pinc::model::PincModel::load(&model).unwrap();
    assert_eq!((frozen.provenance.metrics["members"], frozen.provenance.metrics["member_kept"]), (2.0, kept as f64));
    assert_eq!(frozen.provenance.metrics["dev_vpt_s"], dev[kept]);
    let read = |name: &str| std::fs::read_to_string(dir.path().join(name)).unwrap();
    assert_eq!(read("two.csv"), read(&format!("two.member{kept}.csv")), "the run's CSV is the kept member's");
    assert_eq!(read("two.member0.csv").lines().count(), 3);
    assert_eq!(read("two.member1.csv").lines().count(), 3);
    let out = pinc(&["train", "--epochs", "1", "--members", "0", "--out", m]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("members: need at least one"));
}

#[test]
fn predict_warns_of_every_component_outside_the_envelope_farthest_first() {
    let dir = tempfile::tempdir().unwrap();
    let model = format!("{}/models/mpc_pinc.pinc", env!("CARGO_MANIFEST_DIR"));
    // Heading 0 ((cos, sin) = (1, 0), inside by construction) and a surge force nine orders
    // of magnitude past the envelope, with a yaw moment just past it.
    let inputs = write(dir.path(), "in.csv", "X,Y,Z,Mz\n1e9,0,0,1.5\n");
    let out = pinc(&["predict", "--model", &model, "--x0", "0,0,0,0,0,0,0,0", "--inputs", &inputs]);
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(out.status.success(), "{err}");
    assert!(!err.contains("cos_psi"), "{err}");
    let (x, mz) = (err.find("X = 1000000000").expect(&err), err.find("Mz = 1.5").expect(&err));
    assert!(x < mz, "the farthest exit first: {err}");
}

#[test]
fn vehicle_files_reach_simulate_and_gen_data_and_bad_ones_are_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let vehicle = write(dir.path(), "heavy.toml", "# a heavier, more damped vehicle\nm = 14.0\nz_ww = -90\n");
    let inputs = write(dir.path(), "in.csv", "X,Y,Z,Mz\n5,0,4,0.2\n5,0,4,0.2\n");
    let out = pinc(&["simulate", "--x0", "0,0,0,0,0,0,0,0", "--inputs", &inputs, "--vehicle", &vehicle]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows: Vec<Vec<f64>> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    let params = pinc::vehicle::VehicleParams { m: 14.0, z_ww: -90.0, ..Default::default() };
    let u = [Input::new(5.0, 0.0, 4.0, 0.2); 2];
    let expected = Rk4Vehicle { params, ..Rk4Vehicle::default() }.simulate(&SimState::zeros(), &u);
    for (row, s) in rows.iter().zip(&expected) {
        assert_eq!(&row[1..], s.as_slice());
    }
    assert_ne!(expected, Rk4Vehicle::default().simulate(&SimState::zeros(), &u), "the file changed the vehicle");

    // gen-data records the vehicle in the manifest.
    let data = dir.path().join("data");
    let out = pinc(&["gen-data", "--preset", "paper", "--out", data.to_str().unwrap(), "--vehicle", &vehicle]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["preset"]["vehicle"]["m"], 14.0);

    for (text, expected) in [
        ("mass = 14\n", "unknown key \"mass\""),
        ("m = -1\n", "m = -1: must be positive"),
        ("n_rr = 0.5\n", "n_rr = 0.5: positive damping"),
    ] {
        let bad = write(dir.path(), "bad.toml", text);
        let out = pinc(&["simulate", "--x0", "0,0,0,0,0,0,0,0", "--inputs", &inputs, "--vehicle", &bad]);
        assert_eq!(out.status.code(), Some(1), "{text}");
        let err = String::from_utf8(out.stderr).unwrap();
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains("bad.toml") && err.contains(expected), "{err}");
    }
}

#[test]
fn vpt_sweep_measures_every_period_against_its_cap_and_refuses_bad_ranges() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("sweep.png");
    let dnn = format!("{}/models/paper_dnn.pinc", env!("CARGO_MANIFEST_DIR"));
    let pinc_model = format!("{}/models/paper_pinc.pinc", env!("CARGO_MANIFEST_DIR"));
    let args = ["--t-min", "0.06", "--t-max", "0.1", "--t-step", "0.02", "--count", "40", "--seed", "9"];
    let out = pinc(
        &[&["vpt-sweep", "--model", &dnn, "--model", &pinc_model, "--json", "--out", png.to_str().unwrap()], &args[..]]
            .concat(),
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let periods: Vec<f64> = serde_json::from_value(v["periods_s"].clone()).unwrap();
    assert_eq!(periods, vec![0.06, 0.08, 0.1]);
    let cap: Vec<f64> = serde_json::from_value(v["max_vpt_s"].clone()).unwrap();
    let dnn_vpt: Vec<f64> = serde_json::from_value(v["vpt_s"]["paper_dnn"].clone()).unwrap();
    let pinc_vpt: Vec<f64> = serde_json::from_value(v["vpt_s"]["paper_pinc"].clone()).unwrap();
    for i in 0..3 {
        assert!((cap[i] - 65.0 * periods[i]).abs() < 1e-9);
        assert!(dnn_vpt[i] > 0.0 && dnn_vpt[i] <= cap[i] && pinc_vpt[i] > 0.0 && pinc_vpt[i] <= cap[i]);
    }
    // The data-only network only knows its training period: its VPT peaks there, and the
    // PINC keeps more of it at the periods either side.
    assert!(dnn_vpt[1] > 2.0 * dnn_vpt[0] && dnn_vpt[1] > 2.0 * dnn_vpt[2], "{dnn_vpt:?}");
    assert!(pinc_vpt[0] > dnn_vpt[0] && pinc_vpt[2] > dnn_vpt[2], "{pinc_vpt:?} vs {dnn_vpt:?}");
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
    for bad in [["--t-min", "0.1", "--t-max", "0.05"], ["--t-step", "0", "--t-max", "0.1"]] {
        let out = pinc(&[&["vpt-sweep", "--model", &dnn], &bad[..]].concat());
        assert_eq!(out.status.code(), Some(1));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("need 0 < t-min <= t-max"), "{err}");
    }
}

/// Runs pinc with its stdout on a pipe whose reader has already gone (`pinc ... | head` once
/// head has exited): every write fails with EPIPE.
fn pinc_into_closed_pipe(args: &[&str]) -> Output {
    let (reader, writer) = std::io::pipe().expect("pipe");
    drop(reader);
    Command::new(env!("CARGO_BIN_EXE_pinc")).args(args).stdout(writer).output().expect("run pinc")
}

#[test]
fn writing_into_a_closed_pipe_exits_quietly_with_status_0() {
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/models/mpc_pinc.pinc");
    // `inspect` prints with println! (a panic on EPIPE without the hook), `simulate` writes
    // through an io::Write and returns the error.
    let dir = tempfile::tempdir().unwrap();
    let inputs = write(dir.path(), "in.csv", &format!("X,Y,Z,Mz\n{}", "1,0,0,0\n".repeat(2000)));
    for args in [vec!["inspect", model], vec!["simulate", "--x0", "0,0,0,0,0,0,0,0", "--inputs", &inputs]] {
        let out = pinc_into_closed_pipe(&args);
        assert!(out.status.success(), "{args:?}: {:?}", out.status);
        assert_eq!(String::from_utf8_lossy(&out.stderr), "", "{args:?} must print nothing on a closed pipe");
    }
    // An ordinary error still reports and fails.
    let out = pinc_into_closed_pipe(&["inspect", "no/such/model.pinc"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).starts_with("error: "));
}

/// `pinc estimate` on a real ArduSub simulator log with its position source left out (a stock
/// vehicle's view: depth, heading, yaw rate, thruster outputs), against the same log's own
/// EKF velocities (GPS-aided) as the reference: heave and yaw rate follow them closely.
#[test]
fn estimate_without_the_position_recovers_heave_and_yaw_rate_of_a_simulator_log() {
    let dir = tempfile::tempdir().unwrap();
    let root = env!("CARGO_MANIFEST_DIR");
    let log = format!("{root}/tests/fixtures/ardusub/sitl_excite_1_head.tlog");
    let vehicle = format!("{root}/tests/fixtures/ardusub/sitl_truth.toml");
    let run = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec!["estimate", "--log", &log, "--vehicle", &vehicle, "--json", "--out", out.to_str().unwrap()];
        args.extend_from_slice(extra);
        let o = pinc(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let rows: Vec<Vec<f64>> = std::fs::read_to_string(&out)
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| l.split(',').map(|f| f.parse().unwrap()).collect())
            .collect();
        (report, rows)
    };
    let (with, reference) = run("with.csv", &[]);
    let (without, blind) = run("without.csv", &["--ignore-position"]);
    assert_eq!(with["position_source"], true);
    assert_eq!(without["position_source"], false);
    assert!(without["not_identifiable"].as_array().unwrap().iter().any(|k| k == "x_uu"));
    // Compare where both have rows at the same times (the position starts later in the log).
    let mut err = [0.0f64; 2];
    let mut n = 0usize;
    for b in &blind {
        if let Some(r) = reference.iter().find(|r| (r[0] - b[0]).abs() < 1e-6) {
            err[0] += (b[7] - r[7]).powi(2);
            err[1] += (b[8] - r[8]).powi(2);
            n += 1;
        }
    }
    assert!(n > 100, "{n} common samples");
    let rms = err.map(|e| (e / n as f64).sqrt());
    eprintln!("without the position against with it, {n} samples: RMS w {:.3} m/s, r {:.4} rad/s", rms[0], rms[1]);
    assert!(rms[0] < 0.1 && rms[1] < 0.05, "RMS w, r: {rms:?}");
}

/// `--hybrid` on a preset: the file is a hybrid of the --vehicle, and a run whose correction
/// cannot beat the physics on dev (here the data's plant, given by `--plant`, is the
/// physics itself: no correction can predict better) is its physics exactly, and says so.
#[cfg(feature = "train")]
#[test]
fn a_hybrid_that_cannot_beat_its_physics_is_its_physics() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("hybrid.pinc");
    let m = model.to_str().unwrap();
    let plant = write(dir.path(), "plant.toml", "x_uu = -34.96\n");
    let args = ["--preset", "mpc", "--plant", &plant, "--hybrid", "--heading-free", "--json", "--out", m];
    let out = pinc(&[&["train"], TINY_TRAINING, &args[..]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (v["hybrid"].as_bool(), v["hybrid_physics_kept"].as_bool(), v["best_epoch"].as_u64()),
        (Some(true), Some(true), Some(0))
    );
    let frozen = pinc::model::PincModel::load(&model).unwrap();
    assert_eq!(frozen.hybrid, Some(pinc::model::HybridPhysics { substeps: 16, rest_anchored: true }));
    assert_eq!(frozen.vehicle, pinc::vehicle::VehicleParams::default());
    assert_eq!(frozen.architecture.state_inputs, vec![5, 6, 7, 8]);
    // Its rollout is the BlueROV2's.
    let p = pinc::runtime::Predictor::reference(&frozen);
    let s0 = pinc::SimState::from([0.0, 0.0, 1.0, 0.3, 0.5, 0.0, 0.1, 0.2]);
    let u = vec![pinc::Input::new(20.0, -5.0, 10.0, 2.0); 30];
    let mut traj = vec![pinc::State::zeros(); 31];
    p.rollout(&mut p.workspace(), &pinc::vehicle::to_network(&s0), &u, &mut traj).unwrap();
    let truth = pinc::vehicle::Rk4Vehicle::default().simulate(&s0, &u);
    let worst = traj.iter().zip(&truth).map(|(x, s)| (x - pinc::vehicle::to_network(s)).amax()).fold(0.0, f64::max);
    assert!(worst < 1e-9, "{worst:e}");
    let text = String::from_utf8(pinc(&["inspect", m]).stdout).unwrap();
    assert!(text.contains("hybrid: the vehicle below (RK4, 16 sub-steps per step)"), "{text}");
    assert!(text.contains("x_uu = -34.96"), "every coefficient of the physics: {text}");
}
