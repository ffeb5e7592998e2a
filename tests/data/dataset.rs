//! Dataset presets, reproducibility, and storage validation against corrupted copies.

use pinc::dataset::{self, Dataset, DatasetError, DatasetPreset, Excitation};
use pinc::vehicle::{Rk4Vehicle, to_network, to_simulator};
use std::fs;
use std::path::Path;

/// The paper preset with every set shrunk, for fast storage tests.
fn small_paper() -> DatasetPreset {
    let mut p = DatasetPreset::paper();
    for s in &mut p.sets {
        s.count = s.count.min(5);
    }
    p.sets[0].collocation_points = 4;
    p
}

#[test]
fn paper_preset_has_the_protocol_shapes() {
    let data = dataset::generate(&DatasetPreset::paper(), 0, || {});
    let expect = [
        ("train", 400, 0.08),
        ("dev", 80, 0.08),
        ("dev_eval", 1000, 0.08),
        ("interp", 1000, 0.06),
        ("extrap", 1000, 0.10),
        ("line", 1, 0.08),
        ("circle", 1, 0.08),
        ("figure8", 1, 0.08),
    ];
    assert_eq!(data.sets.len(), expect.len());
    for (set, (name, count, dt)) in data.sets.iter().zip(expect) {
        assert_eq!((set.name.as_str(), set.count, set.points, set.dt), (name, count, 66, dt));
        assert_eq!(set.states.len(), count * 66);
        assert_eq!(set.inputs.len(), count * 65);
    }
    let train = data.set("train").unwrap();
    assert_eq!(train.collocation.len(), 400 * 65);
    assert!(train.collocation.iter().all(|&t| t == 0.08), "single collocation point at t = T");
}

#[test]
fn paper_scaling_and_excitations_follow_the_protocol() {
    let data = dataset::generate(&DatasetPreset::paper(), 0, || {});
    for name in ["train", "dev", "dev_eval", "interp", "extrap"] {
        let set = data.set(name).unwrap();
        assert!(set.inputs.iter().all(|u| u[2] >= 0.0), "{name}: Z = 5|Z| >= 0");
    }
    // Sines: amplitude 3 before scaling, so |X| <= 3, |Y| <= 0.3, Z <= 15, |Mz| <= 0.15.
    for u in &data.set("interp").unwrap().inputs {
        assert!(u[0].abs() <= 3.0 && u[1].abs() <= 0.3 + 1e-12 && u[2] <= 15.0 + 1e-12 && u[3].abs() <= 0.15 + 1e-12);
    }
    // Ramps: X returns to its start value and moves by exactly +-1 at mid-trajectory.
    let train = data.set("train").unwrap();
    for i in 0..train.count {
        let (_, u) = train.trajectory(i);
        assert!((u[0][0] - u[64][0]).abs() < 1e-12);
        assert!(((u[32][0] - u[0][0]).abs() - 1.0).abs() < 1e-12, "ramp height");
        assert!((((u[32][1] - u[0][1]).abs()) - 0.1).abs() < 1e-12, "Y ramp scaled by 0.1");
    }
    // Test-set initial states: only yaw is random.
    for i in 0..100 {
        let s0 = to_simulator(&data.set("extrap").unwrap().trajectory(i).0[0]);
        assert!(s0.iter().enumerate().all(|(j, v)| j == 3 || *v == 0.0));
    }
    // Training initial states inside the stated half-widths, w >= 0.
    for i in 0..train.count {
        let s0 = to_simulator(&train.trajectory(i).0[0]);
        assert!(s0[0].abs() <= 1.0 && s0[2].abs() <= 1.0 && s0[4].abs() <= 1.0 && (0.0..=0.1).contains(&s0[6]));
        assert!(s0[5] == 0.0 && s0[7] == 0.0);
    }
}

#[test]
fn mpc_preset_stays_in_its_envelope() {
    let preset = DatasetPreset::mpc();
    let Excitation::Mixed { lo, hi } = preset.sets[0].excitation.clone() else { panic!("mpc uses mixed excitation") };
    // The BlueROV2's thrust: 9 kgf surge and sway, 7 kgf heave, 9 kgf on a 0.1888 m yaw arm.
    assert_eq!((lo, hi), ([-88.3, -88.3, -68.7, -23.6], [88.3, 88.3, 68.7, 23.6]));
    let kgf = 9.80665;
    assert!((hi[0] - 9.0 * kgf).abs() < 0.06 && (hi[2] - 7.0 * kgf).abs() < 0.06);
    assert!((hi[3] - hi[0] * 0.1888 / std::f64::consts::FRAC_1_SQRT_2).abs() < 0.05);
    let data = dataset::generate(&preset, 3, || {});
    let train = data.set("train").unwrap();
    assert_eq!((train.count, train.points), (2000, 66));
    for u in &train.inputs {
        for c in 0..4 {
            assert!(u[c] >= lo[c] && u[c] <= hi[c]);
        }
    }
    // Excitation reaches the corners of the envelope (depth and heading manoeuvres).
    let max_z = train.inputs.iter().map(|u| u[2]).fold(f64::MIN, f64::max);
    let max_mz = train.inputs.iter().map(|u| u[3].abs()).fold(0.0, f64::max);
    assert!(max_z > 0.95 * hi[2] && max_mz > 0.95 * hi[3]);
    let v = dataset::reachable_velocities(&Default::default(), lo, hi);
    for i in 0..train.count {
        let s0 = to_simulator(&train.trajectory(i).0[0]);
        for j in 0..4 {
            assert!(s0[4 + j] >= v.lo[j] && s0[4 + j] <= v.hi[j]);
        }
    }
}

#[test]
fn stored_states_are_the_simulator_trajectories() {
    let data = dataset::generate(&small_paper(), 0, || {});
    for set in &data.sets {
        let veh = Rk4Vehicle::with_dt(set.dt);
        for i in 0..set.count {
            let (states, inputs) = set.trajectory(i);
            let sim = veh.simulate(&to_simulator(&states[0]), inputs);
            for (a, b) in states.iter().zip(&sim) {
                assert!((a - to_network(b)).amax() < 1e-12, "{} trajectory {i}", set.name);
            }
        }
    }
}

#[test]
fn latin_hypercube_puts_one_time_in_each_stratum() {
    let data = dataset::generate(&small_paper(), 0, || {});
    let train = data.set("train").unwrap();
    for chunk in train.collocation.chunks(4) {
        let mut strata: Vec<usize> = chunk.iter().map(|t| ((t / 0.08) * 4.0).floor() as usize).collect();
        strata.sort();
        assert_eq!(strata, vec![0, 1, 2, 3]);
    }
}

#[test]
fn seeds_reproduce_bit_for_bit_and_differ_between_seeds() {
    let a = dataset::generate(&small_paper(), 7, || {});
    let b = dataset::generate(&small_paper(), 7, || {});
    let c = dataset::generate(&small_paper(), 8, || {});
    assert_eq!(a, b);
    for (x, y) in a.sets.iter().zip(&c.sets) {
        if x.name == "line" || x.name == "circle" || x.name == "figure8" {
            assert_eq!(x.states, y.states, "deterministic sets do not depend on the seed");
        } else {
            assert_ne!(x.states, y.states, "{} must change with the seed", x.name);
        }
    }
}

fn saved(dir: &Path) -> Dataset {
    let data = dataset::generate(&small_paper(), 1, || {});
    dataset::save(&data, dir).unwrap();
    data
}

#[test]
fn write_read_round_trip_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    let data = saved(dir.path());
    assert_eq!(dataset::load(dir.path()).unwrap(), data);
}

#[test]
fn rejects_missing_file() {
    let dir = tempfile::tempdir().unwrap();
    saved(dir.path());
    fs::remove_file(dir.path().join("dev/inputs.npy")).unwrap();
    let err = dataset::load(dir.path()).unwrap_err();
    assert!(matches!(&err, DatasetError::MissingFile { path } if path.ends_with("dev/inputs.npy")), "{err}");
    fs::remove_file(dir.path().join("manifest.json")).unwrap();
    assert!(matches!(dataset::load(dir.path()), Err(DatasetError::MissingFile { .. })));
}

/// Writes a little-endian float64 .npy by hand, independently of the crate's writer.
fn write_raw_npy(path: &Path, shape: &[usize], values: &[f64]) {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = if shape.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape_text}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in values {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    fs::write(path, bytes).unwrap();
}

#[test]
fn rejects_wrong_shape() {
    let dir = tempfile::tempdir().unwrap();
    saved(dir.path());
    write_raw_npy(&dir.path().join("dev/states.npy"), &[5, 65, 9], &vec![0.0; 5 * 65 * 9]);
    let err = dataset::load(dir.path()).unwrap_err();
    assert!(
        matches!(&err, DatasetError::ShapeMismatch { path, expected, found }
            if path.ends_with("dev/states.npy") && expected == &[5, 66, 9] && found == &[5, 65, 9]),
        "{err}"
    );
}

#[test]
fn rejects_nan() {
    let dir = tempfile::tempdir().unwrap();
    let data = saved(dir.path());
    let set = data.set("interp").unwrap();
    let mut flat: Vec<f64> = set.inputs.iter().flat_map(|u| u.iter().copied()).collect();
    flat[17] = f64::NAN;
    write_raw_npy(&dir.path().join("interp/inputs.npy"), &[5, 65, 4], &flat);
    let err = dataset::load(dir.path()).unwrap_err();
    assert!(
        matches!(&err, DatasetError::NonFinite { path, index: 17, .. } if path.ends_with("interp/inputs.npy")),
        "{err}"
    );
    assert!(err.to_string().contains("interp/inputs.npy"));
}

#[test]
fn rejects_truncated_array_and_wrong_dtype() {
    let dir = tempfile::tempdir().unwrap();
    saved(dir.path());
    let path = dir.path().join("train/states.npy");
    let bytes = fs::read(&path).unwrap();
    fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
    assert!(
        matches!(dataset::load(dir.path()), Err(DatasetError::BadArray { path, .. }) if path.ends_with("train/states.npy"))
    );
    let text = String::from_utf8_lossy(&bytes).replace("<f8", "<f4").into_bytes();
    fs::write(&path, text).unwrap();
    assert!(matches!(dataset::load(dir.path()), Err(DatasetError::BadArray { .. })));
}

#[test]
fn rejects_manifest_that_disagrees() {
    let dir = tempfile::tempdir().unwrap();
    saved(dir.path());
    let manifest_path = dir.path().join("manifest.json");
    let original = fs::read_to_string(&manifest_path).unwrap();
    let mut m: serde_json::Value = serde_json::from_str(&original).unwrap();
    // The listed count disagrees with the preset and with the arrays.
    m["sets"][1]["count"] = 6.into();
    fs::write(&manifest_path, m.to_string()).unwrap();
    let err = dataset::load(dir.path()).unwrap_err();
    assert!(matches!(&err, DatasetError::Inconsistent { path, .. } if path.ends_with("manifest.json")), "{err}");
    // Preset and set agree, but the declared shape does not match the array on disk.
    let mut m: serde_json::Value = serde_json::from_str(&original).unwrap();
    m["sets"][1]["count"] = 6.into();
    m["preset"]["sets"][1]["count"] = 6.into();
    for (k, dims) in [("states", [6, 66, 9]), ("inputs", [6, 65, 4])] {
        m["sets"][1][k]["shape"] = serde_json::json!(dims);
    }
    fs::write(&manifest_path, m.to_string()).unwrap();
    assert!(matches!(dataset::load(dir.path()), Err(DatasetError::ShapeMismatch { .. })));
    // A path escaping the folder and plain garbage.
    fs::write(&manifest_path, original.replace("\"dev/states.npy\"", "\"../dev/states.npy\"")).unwrap();
    assert!(matches!(dataset::load(dir.path()), Err(DatasetError::BadManifest { .. })));
    fs::write(&manifest_path, "{ not json").unwrap();
    assert!(matches!(dataset::load(dir.path()), Err(DatasetError::BadManifest { .. })));
}

#[test]
fn rejects_collocation_outside_the_interval() {
    let dir = tempfile::tempdir().unwrap();
    saved(dir.path());
    let mut times = vec![0.04; 5 * 65 * 4];
    times[3] = 0.2;
    write_raw_npy(&dir.path().join("train/collocation.npy"), &[5, 65, 4], &times);
    assert!(
        matches!(dataset::load(dir.path()), Err(DatasetError::Inconsistent { path, .. }) if path.ends_with("train/collocation.npy"))
    );
}
