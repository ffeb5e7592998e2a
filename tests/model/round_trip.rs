//! Save -> load is exact, files stay small, and a loaded model predicts as the original.

use crate::common;
use pinc::model::PincModel;
use pinc::runtime::Predictor;
use pinc::vehicle::VehicleParams;
use pinc::{Input, State};

#[test]
fn round_trip_is_exact_and_small() {
    for (name, model) in common::variants() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.pinc");
        model.save(&path).unwrap();
        let loaded = PincModel::load(&path).unwrap();
        assert_eq!(loaded, model, "{name}");
        let size = std::fs::metadata(&path).unwrap().len();
        if name == "paper 4x32" {
            // 3,795 parameters as f32 plus header: about 15 KB.
            assert_eq!(model.parameter_count(), 14 * 32 + 32 + 3 * (32 * 32 + 32) + 4 + 2 * 64 + 9 * 32 + 9);
            assert!(size < 20_000, "4x32 file is {size} bytes");
        }
        let x = State::from([0.1, 0.2, 0.3, 0.6, 0.8, 0.1, 0.0, 0.05, 0.1]);
        let u = Input::new(1.0, 0.1, 3.0, 0.02);
        let (p, q) = (Predictor::new(&model), Predictor::new(&loaded));
        let (mut a, mut b) = (State::zeros(), State::zeros());
        p.step(&mut p.workspace(), &x, &u, &mut a).unwrap();
        q.step(&mut q.workspace(), &x, &u, &mut b).unwrap();
        assert_eq!(a, b);
    }
}

#[test]
fn the_vehicle_is_recorded_and_version_1_files_read_as_the_bluerov2() {
    // The shipped models were written in format version 1, before files recorded a vehicle.
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/models/mpc_pinc.pinc");
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 1);
    let old = PincModel::from_bytes(&bytes).unwrap();
    assert_eq!(old.vehicle, VehicleParams::default());
    // Written again, it is version 2 and keeps another vehicle exactly.
    let mut model = old;
    model.vehicle.m = 13.25;
    model.vehicle.z_ww = -61.0;
    let again = model.to_bytes().unwrap();
    assert_eq!(u32::from_le_bytes(again[8..12].try_into().unwrap()), pinc::model::FORMAT_VERSION);
    assert_eq!(PincModel::from_bytes(&again).unwrap(), model);
    // A vehicle that makes the physics meaningless is refused like any invalid field.
    model.vehicle.x_ud = 20.0;
    let err = model.to_bytes().unwrap_err().to_string();
    assert!(err.starts_with("vehicle: x_ud = 20: the effective mass"), "{err}");
}

/// `bytes` re-framed as another format version with the payload cut by `drop` bytes.
fn reframed(bytes: &[u8], version: u32, drop: usize) -> Vec<u8> {
    crate::errors::framed(&bytes[pinc::model::HEADER_SIZE..bytes.len() - drop], version)
}

#[test]
fn hybrid_files_keep_both_parts_and_older_versions_read_as_they_were() {
    let hybrid = common::hybrid(common::paper_4x32(4), 12);
    let bytes = hybrid.to_bytes().unwrap();
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 4);
    let back = PincModel::from_bytes(&bytes).unwrap();
    assert_eq!(back.hybrid, Some(pinc::model::HybridPhysics { substeps: 12, rest_anchored: false }));
    assert_eq!(back.vehicle, hybrid.vehicle);
    // Version 3 is version 4 without the anchoring flag (the hybrid's last byte) and the
    // fitted vehicle (the payload's last, absent: one byte): it reads as an unanchored hybrid.
    assert_eq!(bytes[bytes.len() - 2..], [0, 0], "unanchored, no fitted vehicle");
    assert_eq!(PincModel::from_bytes(&reframed(&bytes, 3, 2)).unwrap(), hybrid);
    // A version 2 file is a version 4 payload without the hybrid and fitted fields: it reads
    // as the same PINC.
    let mut pinc_model = hybrid.clone();
    pinc_model.hybrid = None;
    let v4 = pinc_model.to_bytes().unwrap();
    assert_eq!(v4[v4.len() - 2..], [0, 0], "absent parts are bincode's None");
    assert_eq!(PincModel::from_bytes(&reframed(&v4, 2, 2)).unwrap(), pinc_model);
    // A hybrid's bytes claimed as version 2 leave bytes over: refused, not misread.
    assert!(PincModel::from_bytes(&reframed(&bytes, 2, 0)).is_err());
    // A fitted vehicle and the anchoring come back whole.
    let mut fitted = common::anchored(common::random_model(
        {
            let mut a = pinc::model::Architecture::paper(2, 8);
            a.state_inputs = vec![5, 6, 7, 8];
            a
        },
        5,
    ));
    fitted.fitted = Some(pinc::model::FittedVehicle {
        thrusters_toml: "[[thruster]]\nname = \"t\"\n".into(),
        sensors: pinc::model::SensorModel { depth_std: 0.12, depth_delay: 0.1, heading_std: 0.003, yaw_rate_std: 0.02 },
        warnings: vec!["yaw: not determined".into()],
    });
    assert_eq!(PincModel::from_bytes(&fitted.to_bytes().unwrap()).unwrap(), fitted);
    // What a fitted vehicle and an anchored hybrid cannot be.
    let mut bad = fitted.clone();
    bad.fitted.as_mut().unwrap().sensors.depth_std = -0.1;
    assert!(bad.to_bytes().unwrap_err().to_string().contains("depth_std"));
    let mut sees_heading = pinc::model::Architecture::paper(2, 8);
    sees_heading.state_inputs = vec![3, 4, 5, 6, 7, 8];
    let mut bad = common::hybrid(common::random_model(sees_heading, 6), 8);
    bad.hybrid = Some(pinc::model::HybridPhysics { substeps: 8, rest_anchored: true });
    let err = bad.to_bytes().unwrap_err().to_string();
    assert!(err.contains("rest_anchored"), "{err}");
    // What a hybrid cannot be.
    let mut bad = hybrid.clone();
    bad.architecture.residual = false;
    let err = bad.to_bytes().unwrap_err().to_string();
    assert!(err.contains("architecture.residual") && err.contains("hybrid"), "{err}");
    let mut bad = hybrid;
    bad.hybrid = Some(pinc::model::HybridPhysics { substeps: 0, rest_anchored: false });
    let err = bad.to_bytes().unwrap_err().to_string();
    assert!(err.contains("hybrid.substeps"), "{err}");
}
