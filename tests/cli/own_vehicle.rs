//! The whole "your own vehicle" path on a vehicle that is not the BlueROV2, through the
//! command line (a short training budget; docs/GUIDE_OWN_VEHICLE.md gives the numbers of the real one):
//! closed-loop oracle runs and an excitation run -> `pinc dataset import` -> `pinc identify`
//! -> `pinc train --data` -> `pinc eval --data` -> `mpc_track --model` against the vehicle.
#![cfg(all(feature = "train", feature = "mpc"))]

use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

const VEHICLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/example_vehicle.toml");

fn ok(out: Output, what: &str) -> String {
    assert!(out.status.success(), "{what} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

fn pinc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pinc")).args(args).output().expect("run pinc")
}

/// The `mpc_track` binary (built by `cargo test` beside `pinc`).
fn mpc_track() -> Command {
    Command::new(env!("CARGO_BIN_EXE_mpc_track"))
}

fn json(text: &str) -> Value {
    serde_json::from_str(text).unwrap_or_else(|e| panic!("{e}: {text}"))
}

#[test]
fn closed_loop_logs_and_an_excitation_run_identify_train_and_control_another_vehicle() {
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let logs = d("logs");
    let refs = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/references");
    // Two closed-loop runs of the oracle (the controller that knows the plant) on the vehicle.
    for reference in ["default", "zigzag"] {
        let r = format!("{refs}/{reference}.csv");
        let out = mpc_track()
            .args(["--oracle", "--vehicle", VEHICLE, "--reference", &r, "--out-dir", &logs, "--json"])
            .output()
            .unwrap();
        ok(out, "mpc_track --oracle");
    }
    // Two open-loop excitation runs, recorded as CSV.
    for seed in ["1", "2"] {
        let inputs = d(&format!("excitation{seed}.in.csv"));
        ok(
            pinc(&["excitation", "--design", "generic", "--out", &inputs, "--duration", "60", "--seed", seed]),
            "excitation",
        );
        let x0 = "0,0,1,0,0,0,0,0";
        let csv =
            ok(pinc(&["simulate", "--vehicle", VEHICLE, "--x0", x0, "--inputs", &inputs, "--record"]), "simulate");
        std::fs::write(format!("{logs}/excitation{seed}.csv"), csv).unwrap();
    }
    let mcaps = [format!("{logs}/mpc_default_oracle.mcap"), format!("{logs}/mpc_zigzag_oracle.mcap")];
    let csvs = [format!("{logs}/excitation1.csv"), format!("{logs}/excitation2.csv")];

    // Closed-loop logs alone: the controller never uses surge or sway, so those six
    // coefficients are reported, not guessed.
    let closed = d("closed_loop");
    let mut args = vec!["dataset", "import", "--format", "mcap", "--out", &closed, "--split", "0.5,0,0.5"];
    args.extend(mcaps.iter().map(String::as_str));
    ok(pinc(&args), "import mcap");
    let id = json(&ok(pinc(&["identify", "--data", &closed, "--json"]), "identify closed loop"));
    let mut missing: Vec<&str> =
        id["not_identifiable"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
    missing.sort();
    assert_eq!(missing, ["x_u", "x_ud", "x_uu", "y_v", "y_vd", "y_vv"]);

    // Everything, formats by extension; whole runs per split.
    let all = d("all");
    let mut args = vec!["dataset", "import", "--out", &all, "--split", "0.5,0.25,0.25", "--seed", "1", "--json"];
    args.extend(mcaps.iter().chain(&csvs).map(String::as_str));
    let import = json(&ok(pinc(&args), "import all"));
    assert_eq!(import["split_by"], "run");
    let split_of = |name: &str| {
        let files = import["files"].as_array().unwrap();
        files.iter().find(|f| f["path"].as_str().unwrap().ends_with(name)).unwrap()["split"]
            .as_str()
            .unwrap()
            .to_string()
    };
    assert_eq!(split_of("excitation1.csv"), "train", "{import}");
    // The base knows what a scale and a swing test give: mass and yaw inertia.
    let truth = pinc::vehicle::VehicleParams::load(VEHICLE).unwrap();
    let base = d("base.toml");
    std::fs::write(&base, format!("m = {}\nizz = {}\n", truth.m, truth.izz)).unwrap();
    let identified = d("identified.toml");
    let id = json(&ok(
        pinc(&["identify", "--data", &all, "--vehicle", &base, "--out", &identified, "--json"]),
        "identify all",
    ));
    assert_eq!(id["not_identifiable"].as_array().unwrap().len(), 0, "{id}");
    for (key, value) in truth.named() {
        let got = id[key].as_f64().unwrap();
        assert!((got / value - 1.0).abs() < 1e-3, "{key}: identified {got}, truth {value}");
    }
    assert!(id["std_err"]["z_wd"].as_f64().unwrap() > 0.0 && id["std_err"]["m"].is_null());
    assert_eq!(pinc::vehicle::VehicleParams::load(&identified).unwrap().z_wd, id["z_wd"].as_f64().unwrap());

    // A short training on the folder with the identified physics, then its held-out metrics.
    let model = d("own.pinc");
    let train = json(&ok(
        pinc(&[
            "train",
            "--data",
            &all,
            "--vehicle",
            &identified,
            "--out",
            &model,
            "--epochs",
            "2",
            "--position-free",
            "--json",
        ]),
        "train --data",
    ));
    assert!(train["test"]["vpt_s"].as_f64().unwrap().is_finite(), "{train}");
    let eval = json(&ok(pinc(&["eval", "--model", &model, "--data", &all, "--json", "--no-plot"]), "eval --data"));
    assert_eq!(eval["windows"], train["test"]["windows"]);
    for key in ["one_step_mse", "rollout10_mse", "physics_mse", "vpt_s"] {
        assert!(eval[key].as_f64().is_some_and(f64::is_finite), "{key}: {eval}");
    }
    let inspect = ok(pinc(&["inspect", &model]), "inspect");
    assert!(inspect.contains("pinc train --data"), "{inspect}");

    // The new model in the loop against the true vehicle (the short run the budget allows).
    let out = mpc_track()
        .args(["--model", &model, "--vehicle", VEHICLE, "--duration", "8", "--out-dir", &d("run"), "--json"])
        .output()
        .unwrap();
    let run = json(&ok(out, "mpc_track --model own.pinc"));
    assert_eq!(run["samples"], 100);
    assert_eq!(run["bound_violations"], 0);
}

#[test]
fn bad_input_on_the_path_is_a_one_line_error_and_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let fails = |out: Output, expect: &str| {
        assert_eq!(out.status.code(), Some(1), "{}", String::from_utf8_lossy(&out.stderr));
        let err = String::from_utf8(out.stderr).unwrap();
        assert_eq!(err.lines().count(), 1, "one line: {err}");
        assert!(err.starts_with("error: ") && err.contains(expect), "{expect:?} in {err}");
    };
    let inputs = d("in.csv");
    ok(pinc(&["excitation", "--design", "generic", "--out", &inputs, "--duration", "20"]), "excitation");
    let rec = ok(pinc(&["simulate", "--x0", "0,0,1,0,0,0,0,0", "--inputs", &inputs, "--record"]), "simulate");
    // A row cut short before the last line (a torn last line alone is skipped and noted).
    let cut = d("cut.csv");
    let mut lines: Vec<String> = rec.lines().map(str::to_string).collect();
    lines[40] = lines[40].split(',').take(5).collect::<Vec<_>>().join(",");
    std::fs::write(&cut, lines.join("\n") + "\n").unwrap();
    let out = d("out");
    fails(pinc(&["dataset", "import", "--out", &out, &cut]), &format!("{cut}: line 41: 5 fields"));
    assert!(!Path::new(&out).exists(), "nothing written");
    // A window longer than every run (20 s is 250 samples).
    let whole = d("whole.csv");
    std::fs::write(&whole, &rec).unwrap();
    fails(
        pinc(&["dataset", "import", "--out", &out, "--window", "400", &whole]),
        "no run holds a window of 400 points",
    );
    assert!(!Path::new(&out).exists(), "nothing written");
    // A log without the topics.
    let logs = d("logs");
    ok(mpc_track().args(["--oracle", "--duration", "2", "--out-dir", &logs, "--json"]).output().unwrap(), "mpc_track");
    let log = format!("{logs}/mpc_default_oracle.mcap");
    fails(
        pinc(&["dataset", "import", "--out", &out, "--state-topic", "/odometry", &log]),
        "no messages on topic /odometry (the file has: /log, /mpc/command",
    );
    // A file that is neither and no --format.
    fails(
        pinc(&["dataset", "import", "--out", &out, &inputs.replace(".csv", ".txt")]),
        "format not known from the extension",
    );
    // A vehicle file with a typo, for identification.
    ok(pinc(&["dataset", "import", "--out", &out, "--split", "0.5,0,0.5", &whole, &whole]), "import");
    let typo = d("typo.toml");
    std::fs::write(&typo, "m = 12\nz_ww_ = -70\n").unwrap();
    fails(pinc(&["identify", "--data", &out, "--vehicle", &typo]), &format!("{typo}: unknown key \"z_ww_\""));
    // And a reference file with a bad line for the controller.
    let r = d("ref.csv");
    std::fs::write(&r, "t,depth_m,heading_deg\n0,1,0\n5,x,0\n").unwrap();
    let out = mpc_track().args(["--reference", &r, "--out-dir", &logs]).output().unwrap();
    fails(out, &format!("{r}: line 3: depth_m: \"x\" is not a finite number"));
}
