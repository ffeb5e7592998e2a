//! `pinc fit` on a stock vehicle's recording from ArduSub's firmware
//! (tests/fixtures/ardusub/stock_designed_60s.mcap, see RECORDINGS.md there): the same inputs
//! give the same bytes, the report says what the data determined, a recording cut off is fitted
//! from what it holds, a damaged one writes nothing.
#![cfg(all(feature = "train", feature = "vehicle"))]

use pinc::model::PincModel;
use std::path::Path;
use std::process::{Command, Output};

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/ardusub/stock_designed_60s.mcap");
const VEHICLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/ardusub/sitl_vectored.toml");

fn fit(recording: &str, out: &Path) -> Output {
    let out = out.to_str().unwrap();
    Command::new(env!("CARGO_BIN_EXE_pinc"))
        .args(["fit", "--recording", recording, "--vehicle", VEHICLE, "--out", out, "--epochs", "3", "--json"])
        .output()
        .expect("run pinc")
}

#[test]
fn a_stock_recording_fits_the_same_model_twice_and_says_what_it_determined() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    for out in [&a, &b] {
        let r = fit(FIXTURE, out);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    // Bit for bit: the model, and the vehicle file below its first line (the command, whose
    // --out differs).
    assert!(std::fs::read(a.join("model.pinc")).unwrap() == std::fs::read(b.join("model.pinc")).unwrap());
    let body = |dir: &Path| {
        std::fs::read_to_string(dir.join("vehicle.toml")).unwrap().lines().skip(1).collect::<Vec<_>>().join("\n")
    };
    assert!(body(&a) == body(&b), "the vehicle files differ");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(a.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["position_source"], false);
    let status = |name: &str| {
        report["coefficients"].as_array().unwrap().iter().find(|c| c["name"] == name).unwrap()["status"].clone()
    };
    // No position source: surge and sway are the starting file's, said so; heave and yaw are
    // determined from the 60 s of the designed excitation, and the report passes.
    for k in ["x_ud", "y_vd", "x_uu", "y_vv"] {
        assert_eq!(status(k), "no_position_source", "{k}");
    }
    for k in ["volume", "z_wd", "z_w", "z_ww", "n_rd", "n_r", "n_rr"] {
        assert_eq!(status(k), "identified", "{k}");
    }
    assert_eq!(report["passed"], true, "{}", report["warnings"]);
    // The simulator's yaw: quadratic damping 7.08 N m/(rad/s)^2 and no linear term (its
    // README); the fit finds both within 5 % of the quadratic term.
    let coefficient = |name: &str| {
        report["coefficients"].as_array().unwrap().iter().find(|c| c["name"] == name).unwrap()["fitted"]
            .as_f64()
            .unwrap()
    };
    assert!((coefficient("n_rr") + 7.08).abs() < 0.35, "{}", coefficient("n_rr"));
    assert!(coefficient("n_r").abs() < 0.35, "{}", coefficient("n_r"));
    // And its yaw inertia, 0.268 kg m^2 with no added inertia (a sphere's, its source): the
    // effective inertia izz - n_rd within 5 %. With each output change dated at the report that
    // first showed it, half a 50 Hz report period late, this recording gave 0.177.
    let izz: f64 = std::fs::read_to_string(a.join("vehicle.toml"))
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("izz = "))
        .and_then(|v| v.trim().parse().ok())
        .expect("izz in the fitted vehicle file");
    let inertia = izz - coefficient("n_rd");
    assert!((inertia / 0.268 - 1.0).abs() < 0.05, "effective yaw inertia {inertia}");
    // The simulator's depth sensor has 0.12 m of noise (its README): the fit measures it
    // from the readings within a third.
    let depth_std = report["sensors"]["depth_std_m"].as_f64().unwrap();
    assert!((0.08..=0.16).contains(&depth_std), "{depth_std}");
    // The recording holds the autopilot's vertical velocity: the depth lag is measured against
    // it. The simulator's readings at their own stamps lag its truth by 0.02-0.04 s; on these
    // 60 s the scan's best is 0 (under its 0.02 s step).
    assert_eq!(report["sensors"]["lag_method"], "vertical_velocity");
    let lag = report["sensors"]["depth_delay_s"].as_f64().unwrap();
    assert!((0.0..=0.06).contains(&lag), "{lag}");
    // The held-out comparison (15 % of 60 s: 4 windows of 2 s) and the plot are there.
    assert!(report["held_out"]["windows"].as_u64().unwrap() >= 3);
    for name in ["report.md", "report.png", "training.csv"] {
        assert!(a.join(name).metadata().unwrap().len() > 100, "{name}");
    }
    let md = std::fs::read_to_string(a.join("report.md")).unwrap();
    assert!(md.contains("windows of 2.0 s, rolled out from each window's smoothed first state"), "{md}");
    assert!(md.contains("| heave | ") && md.contains("| yaw | "), "{md}");
    // The model carries what flies it: the thrusters (inline, parsed), the sensor model, the
    // report's warnings; its correction is anchored at rest.
    let model = PincModel::load(a.join("model.pinc")).unwrap();
    let fitted = model.fitted.as_ref().unwrap();
    let thrusters = pinc::vehicle::Thrusters::from_toml(&fitted.thrusters_toml, Path::new("model")).unwrap().unwrap();
    assert_eq!(thrusters.allocation_matrix().ncols(), 6);
    assert_eq!(fitted.sensors.depth_std, depth_std);
    assert_eq!(fitted.warnings.len(), report["warnings"].as_array().unwrap().len());
    assert!(model.hybrid.unwrap().rest_anchored);
    // The vehicle file stands alone: it loads with its thrusters from anywhere.
    pinc::vehicle::Thrusters::load(a.join("vehicle.toml")).unwrap();
    // The depth rolled out open loop from the recorded thrust against the readings (not the
    // estimate): judged, within, and in the Markdown beside the held-out table.
    let depth = &report["open_loop_depth"]["identified"];
    assert_eq!((depth["judged"].as_bool(), depth["biased"].as_bool()), (Some(true), Some(false)), "{depth}");
    assert!(depth["segments"].as_u64().unwrap() >= 4 && depth["gain_error"].as_f64().unwrap().abs() < 0.05, "{depth}");
    assert!(md.contains("## Depth open loop") && md.contains("| identified | "), "{md}");
    // Three epochs on 60 s: no correction beat the physics, so the model is its physics (the
    // network's output zero), and the MPC is bounded by the thrusters it carries, not by the
    // forces the excitation happened to use (a fifth of the heave's reach).
    assert!(report["notes"].to_string().contains("the model is its physics"), "{}", report["notes"]);
    assert!(model.correction_is_zero());
    let campaign = pinc::closed_loop::campaign::Campaign::new(&pinc::closed_loop::campaign::Settings {
        model: a.join("model.pinc"),
        ..Default::default()
    })
    .unwrap();
    assert_eq!(campaign.bounds, thrusters.input_bounds());
    let envelope = model.envelope.as_ref().unwrap();
    assert!(campaign.bounds.1[2] > 4.0 * envelope.input_max[2], "{:?} {:?}", campaign.bounds, envelope.input_max);
}

/// Cut at two thirds (a session killed), the recording is fitted from its whole chunks, and
/// the report says where it ended; the same cut with bytes of a whole chunk overwritten is
/// refused, naming the file, and writes nothing.
#[test]
fn a_cut_recording_is_fitted_from_what_it_holds_and_a_damaged_one_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(FIXTURE).unwrap();
    let cut = dir.path().join("pool.mcap.partial");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let out = dir.path().join("cut");
    let r = fit(cut.to_str().unwrap(), &out);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let report: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let note = report["notes"][0].as_str().unwrap();
    assert!(note.contains("pool.mcap.partial: the file was cut off: read up to byte"), "{note}");
    let held = report["recordings"][0]["estimated_s"].as_f64().unwrap();
    // The writer closes a chunk every second: two thirds of the bytes are about two thirds of
    // the 60 s.
    assert!((30.0..45.0).contains(&held), "{held} s");

    // Damage inside the compressed records of the chunk that holds the file's middle (found by
    // the records' framing: an opcode byte and a little-endian u64 length after the 8-byte
    // magic; 0x06 is a chunk).
    let mut damaged = bytes[..bytes.len() * 2 / 3].to_vec();
    let mut at = 8;
    let chunk = loop {
        let length = u64::from_le_bytes(damaged[at + 1..at + 9].try_into().unwrap()) as usize;
        if damaged[at] == 0x06 && at + 9 + length > damaged.len() / 2 {
            break at;
        }
        at += 9 + length;
    };
    damaged[chunk + 100..chunk + 164].fill(0xff);
    let torn = dir.path().join("torn.mcap");
    std::fs::write(&torn, &damaged).unwrap();
    let out = dir.path().join("out");
    let r = fit(torn.to_str().unwrap(), &out);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("torn.mcap"), "{err}");
    assert!(!out.exists() && !out.with_extension("partial").exists());
}
