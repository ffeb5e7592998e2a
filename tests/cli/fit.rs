//! `pinc fit` on a stock vehicle's recording from ArduSub's firmware
//! (tests/fixtures/ardusub/stock_band_600s.mcap, see trim_recording.py): the same inputs give
//! the same bytes, the report says what the data determined, a damaged recording writes
//! nothing.
#![cfg(all(feature = "train", feature = "vehicle"))]

use pinc::model::PincModel;
use std::path::Path;
use std::process::{Command, Output};

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/ardusub/stock_band_600s.mcap");
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
    // No position source: surge and sway are the starting file's, said so; heave is fitted
    // (its added mass is not determined on this recording: the simulator's vehicle has none,
    // and the fit says so).
    for k in ["x_ud", "y_vd", "x_uu", "y_vv"] {
        assert_eq!(status(k), "no_position_source", "{k}");
    }
    for k in ["volume", "z_w", "z_ww"] {
        assert_eq!(status(k), "identified", "{k}");
    }
    // The simulator's depth sensor has 0.12 m of noise (its README): the fit measures it
    // from the readings within a third.
    let depth_std = report["sensors"]["depth_std_m"].as_f64().unwrap();
    assert!((0.08..=0.16).contains(&depth_std), "{depth_std}");
    // The recording holds the autopilot's vertical velocity: the depth lag is measured against
    // it. The simulator's readings at their own stamps lag its truth by 0.02-0.04 s.
    assert_eq!(report["sensors"]["lag_method"], "vertical_velocity");
    let lag = report["sensors"]["depth_delay_s"].as_f64().unwrap();
    assert!((0.02..=0.06).contains(&lag), "{lag}");
    // The held-out comparison and the plot are there.
    assert!(report["held_out"]["windows"].as_u64().unwrap() > 10);
    for name in ["report.md", "report.png", "training.csv"] {
        assert!(a.join(name).metadata().unwrap().len() > 100, "{name}");
    }
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
}

#[test]
fn a_damaged_recording_is_named_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(FIXTURE).unwrap();
    let torn = dir.path().join("torn.mcap");
    std::fs::write(&torn, &bytes[..bytes.len() / 3]).unwrap();
    let out = dir.path().join("out");
    let r = fit(torn.to_str().unwrap(), &out);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("torn.mcap"), "{err}");
    assert!(!out.exists() && !out.with_extension("partial").exists());
}
