//! The ArduPilot readers (`read_bin`, `read_tlog`) against files other tools wrote: a .tlog
//! packed by pymavlink with known values (tests/fixtures/ardusub/make_tlog.py), the real
//! ArduSub samples and the ArduSub simulator's logs, whose true state (`SIM_STATE`) fixes the
//! frames and signs; and every kind of bad file.

use mavlink::dialects::ardupilotmega::MavMessage;
use pinc::Input;
use pinc::dataset::import::{
    ArdupilotOptions, BLUEROV2_VECTORED_MIX, ImportError, InputSource, Series, StreamSet, read_bin, read_tlog,
};
use serde_json::Value;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ardusub").join(name)
}

/// A stand-in for the vehicle's thrusters: channels 1, 2, 3 and 8 as they are.
fn channels_1238() -> ArdupilotOptions {
    ArdupilotOptions {
        inputs: InputSource::ThrusterOutputs,
        thrusters: Some(Box::new(|p: &[f64]| Input::from([p[0], p[1], p[2], p[7]]))),
        ..ArdupilotOptions::default()
    }
}

fn rate<const N: usize>(s: &Series<N>) -> f64 {
    (s.len() - 1) as f64 / (s.t[s.len() - 1] - s.t[0])
}

fn has_note(set: &StreamSet, words: &str) -> bool {
    set.notes.iter().any(|n| n.contains(words))
}

fn angle_diff(a: f64, b: f64) -> f64 {
    (a - b + PI).rem_euclid(2.0 * PI) - PI
}

#[test]
fn pymavlink_tlog_reads_back_every_written_value() {
    let expected: Value = serde_json::from_str(&std::fs::read_to_string(fixture("pymavlink.json")).unwrap()).unwrap();
    let set = read_tlog(&fixture("pymavlink.tlog"), &channels_1238()).unwrap();
    let f = |v: &Value, k: &str| v[k].as_f64().unwrap();

    // Attitude: boot time in s, radians as written (f32), yaw across +-pi untouched; the
    // damaged frame and the second vehicle's messages are not in it.
    let want = expected["attitude"].as_array().unwrap();
    let att = set.attitude.as_ref().unwrap();
    let rate = set.yaw_rate.as_ref().unwrap();
    assert_eq!(att.len(), want.len());
    for (i, w) in want.iter().enumerate() {
        assert!((att.t[i] - f(w, "time_boot_ms") * 1e-3).abs() < 1e-12);
        assert_eq!(att.v[i], [f(w, "roll"), f(w, "pitch"), f(w, "yaw")]);
        assert_eq!(rate.t[i], att.t[i]);
        assert_eq!(rate.v[i], [f(w, "yawspeed")]);
    }
    let damaged = f(&expected, "damaged_attitude_time_boot_ms") * 1e-3;
    assert!(att.t.iter().all(|t| (t - damaged).abs() > 1e-9));
    assert!(att.v.iter().any(|v| v[2] > 3.0) && att.v.iter().any(|v| v[2] < -3.0), "the yaw crosses +-pi");
    assert!(has_note(&set, "1 damaged frames"), "{:?}", set.notes);

    // Position and velocity, NED as written.
    let want = expected["local_position_ned"].as_array().unwrap();
    let (pos, vel) = (set.position.as_ref().unwrap(), set.velocity_ned.as_ref().unwrap());
    assert_eq!(pos.len(), want.len());
    for (i, w) in want.iter().enumerate() {
        assert!((pos.t[i] - f(w, "time_boot_ms") * 1e-3).abs() < 1e-12);
        assert_eq!(pos.v[i], [f(w, "x"), f(w, "y"), f(w, "z")]);
        assert_eq!(vel.v[i], [f(w, "vx"), f(w, "vy"), f(w, "vz")]);
    }
    // With a position, the pressure depth is not used.
    assert!(set.depth.is_none());

    // Inputs: SERVO_OUTPUT_RAW on its own time_usec, through the conversion.
    let want = expected["servo_output_raw"].as_array().unwrap();
    let input = set.input.as_ref().unwrap();
    assert_eq!(input.len(), want.len());
    for (i, w) in want.iter().enumerate() {
        assert!((input.t[i] - f(w, "time_usec") * 1e-6).abs() < 1e-12);
        let s: Vec<f64> = w["servo"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        assert_eq!(input.v[i], [s[0], s[1], s[2], s[7]]);
    }
}

#[test]
fn pymavlink_tlog_manual_control_through_ardusub_map() {
    let expected: Value = serde_json::from_str(&std::fs::read_to_string(fixture("pymavlink.json")).unwrap()).unwrap();
    let gain = 0.5;
    let opts = ArdupilotOptions {
        inputs: InputSource::ManualControl { gain, mix: BLUEROV2_VECTORED_MIX.to_vec() },
        // Thrusters 1, 2, 5 and 6's PWM.
        thrusters: Some(Box::new(|p: &[f64]| Input::from([p[0], p[1], p[4], p[5]]))),
        ..ArdupilotOptions::default()
    };
    let set = read_tlog(&fixture("pymavlink.tlog"), &opts).unwrap();
    let input = set.input.as_ref().unwrap();
    let want = expected["manual_control"].as_array().unwrap();
    assert_eq!(input.len(), want.len());
    for (i, w) in want.iter().enumerate() {
        let g = |k: &str| w[k].as_f64().unwrap();
        // No time of its own: the newest boot time plus the receive time since.
        let t = g("latest_boot_usec") * 1e-6 + (g("recv_usec") - g("latest_recv_usec")) * 1e-6;
        assert!((input.t[i] - t).abs() < 1e-9, "{} vs {t}", input.t[i]);
        // ArduSub: axis = gain * stick / 1000 (z: gain * (z - 500) / 500); thruster 1 is
        // -forward + lateral + yaw, 2 is -forward - lateral - yaw, 5 and 6 are -throttle.
        let (x, y, z, r) =
            (g("x") * gain / 1000.0, g("y") * gain / 1000.0, (g("z") - 500.0) * gain / 500.0, g("r") * gain / 1000.0);
        let pwm = |s: f64| 1500.0 + 400.0 * s.clamp(-1.0, 1.0);
        let want = [pwm(-x + y + r), pwm(-x - y - r), pwm(-z), pwm(-z)];
        for c in 0..4 {
            assert!((input.v[i][c] - want[c]).abs() < 1e-9, "sample {i} thruster {c}: {:?} vs {want:?}", input.v[i]);
        }
    }
}

#[test]
fn pymavlink_tlog_without_position_gives_pressure_depth() {
    let expected: Value = serde_json::from_str(&std::fs::read_to_string(fixture("pymavlink.json")).unwrap()).unwrap();
    let set = read_tlog(&fixture("pymavlink_nopos.tlog"), &ArdupilotOptions::default()).unwrap();
    assert!(set.position.is_none());
    let depth = set.depth.as_ref().unwrap();
    let want = expected["scaled_pressure2"].as_array().unwrap();
    assert_eq!(depth.len(), want.len());
    let p0 = want[0]["press_abs_hpa"].as_f64().unwrap() * 100.0;
    for (i, w) in want.iter().enumerate() {
        assert!((depth.t[i] - w["time_boot_ms"].as_f64().unwrap() * 1e-3).abs() < 1e-12);
        let d = (w["press_abs_hpa"].as_f64().unwrap() * 100.0 - p0) / (1000.0 * 9.80665);
        assert!((depth.v[i][0] - d).abs() < 1e-9);
        // The writer put the vehicle 0.01 m deeper every sample (below the first).
        assert!((depth.v[i][0] - 0.02 * i as f64).abs() < 1e-3, "{}", depth.v[i][0]);
    }
    // A surface pressure given: depth from it.
    let opts = ArdupilotOptions { surface_pressure: Some(101325.0), ..ArdupilotOptions::default() };
    let set = read_tlog(&fixture("pymavlink_nopos.tlog"), &opts).unwrap();
    assert!((set.depth.unwrap().v[0][0] - 0.5).abs() < 1e-3);
}

#[test]
fn real_ardusub_bin_streams_and_rates() {
    let set = read_bin(&fixture("small.BIN"), &channels_1238()).unwrap();
    let att = set.attitude.as_ref().unwrap();
    // The first ATT record: TimeUS 265738465, Roll -0.08, Pitch -0.63, Yaw 213.93 (centidegrees).
    assert!((att.t[0] - 265.738465).abs() < 1e-9);
    let want = [-0.08f64.to_radians(), -0.63f64.to_radians(), (213.93f64 - 360.0).to_radians()];
    for c in 0..3 {
        assert!((att.v[0][c] - want[c]).abs() < 1e-9, "{:?} vs {want:?}", att.v[0]);
    }
    assert_eq!(att.len(), 237);
    assert!((rate(att) - 10.0).abs() < 0.5, "ATT at {} Hz", rate(att));
    assert!(att.v.iter().all(|v| v[0].abs() < 0.5 && v[1].abs() < 0.5 && v[2] > -PI && v[2] <= PI));
    let (pos, vel) = (set.position.as_ref().unwrap(), set.velocity_ned.as_ref().unwrap());
    assert_eq!(pos.len(), 237, "XKF1 of core 0 only");
    assert!((rate(pos) - 10.0).abs() < 0.5);
    // First XKF1: TimeUS 265738263, PD 0.008687, VD 0.000509.
    assert!((pos.t[0] - 265.738263).abs() < 1e-9);
    assert!((pos.v[0][2] - 0.008687335).abs() < 1e-7 && (vel.v[0][2] - 0.00050854578).abs() < 1e-9);
    assert!(pos.v.iter().all(|p| p.iter().all(|x| x.abs() < 100.0)));
    assert!(vel.v.iter().all(|v| v.iter().all(|x| x.abs() < 3.0)));
    let input = set.input.as_ref().unwrap();
    assert!((rate(input) - 10.0).abs() < 0.5);
    // The thrusters are idle in this log: 1500 on channels 1-3, channel 8 off.
    assert!(input.v.iter().all(|u| u[0] >= 1100.0 && u[0] <= 1900.0 && u[3] == 0.0));
    assert!(has_note(&set, "time base: the autopilot's boot clock"));
    assert!(has_note(&set, "no ORGN record"));
}

#[test]
fn real_ardusub_tlog_streams_and_rates() {
    let set = read_tlog(&fixture("small.tlog"), &channels_1238()).unwrap();
    // pymavlink also finds 4 bad frames (BAD_DATA) in this file.
    assert!(has_note(&set, "4 damaged frames"), "{:?}", set.notes);
    let att = set.attitude.as_ref().unwrap();
    // First ATTITUDE: time_boot_ms 689235, yaw -2.348.
    assert!((att.t[0] - 689.235).abs() < 1e-9 && (att.v[0][2] + 2.3479996).abs() < 1e-6);
    assert!((rate(att) - 20.0).abs() < 1.5, "ATTITUDE at {} Hz", rate(att));
    let pos = set.position.as_ref().unwrap();
    assert!((rate(pos) - 3.0).abs() < 0.5, "LOCAL_POSITION_NED at {} Hz", rate(pos));
    let input = set.input.as_ref().unwrap();
    assert!((rate(input) - 2.0).abs() < 0.3, "SERVO_OUTPUT_RAW at {} Hz", rate(input));
    assert!(att.v.iter().all(|v| v[0].abs() < 0.5 && v[1].abs() < 0.5));
    assert!(set.velocity_ned.as_ref().unwrap().v.iter().all(|v| v.iter().all(|x| x.abs() < 3.0)));
    // MANUAL_CONTROL, as inputs through the map.
    let opts = ArdupilotOptions {
        inputs: InputSource::ManualControl { gain: 1.0, mix: BLUEROV2_VECTORED_MIX.to_vec() },
        thrusters: Some(Box::new(|p: &[f64]| Input::from([p[0], p[1], p[2], p[4]]))),
        ..ArdupilotOptions::default()
    };
    let set = read_tlog(&fixture("small.tlog"), &opts).unwrap();
    let pilot = set.input.as_ref().unwrap();
    assert!(pilot.len() > 1000 && rate(pilot) > 4.0 && rate(pilot) < 40.0, "{} at {} Hz", pilot.len(), rate(pilot));
    assert!(pilot.v.iter().all(|u| u.iter().all(|p| (1100.0..=1900.0).contains(p))));
}

/// The simulator's true state, relative to the EKF's origin (`GPS_GLOBAL_ORIGIN`): from `SIMSTATE`
/// `(t, [north, east], yaw)` at the boot time of the `GLOBAL_POSITION_INT` sent just before
/// it, from `SIM_STATE` `(t, down, [vn, ve, vd])` at that of the `ATTITUDE` before it (the
/// firmware sends each right after those: their yaws agree to 0.01 rad at 1.3 rad/s).
type Horizontal = (f64, [f64; 2], f64);
type Vertical = (f64, f64, [f64; 3]);
fn sim_truth(bytes: &[u8]) -> (Vec<Horizontal>, Vec<Vertical>) {
    let mut reader = mavlink::MavlinkReader::new(bytes);
    let (mut origin, mut t_gpi, mut t_att) = (None, None, None);
    let (mut hor, mut ver) = (Vec::new(), Vec::new());
    while let Ok((_, msg)) = reader.read_any_message::<MavMessage>() {
        match msg {
            MavMessage::GPS_GLOBAL_ORIGIN(o) => {
                origin = Some((o.latitude as f64 * 1e-7, o.longitude as f64 * 1e-7, o.altitude as f64 * 1e-3))
            }
            MavMessage::GLOBAL_POSITION_INT(p) => t_gpi = Some(p.time_boot_ms as f64 * 1e-3),
            MavMessage::ATTITUDE(a) => t_att = Some(a.time_boot_ms as f64 * 1e-3),
            MavMessage::SIMSTATE(s) => {
                if let (Some((lat0, lon0, _)), Some(t)) = (origin, t_gpi) {
                    let r = 6378137.0;
                    let n = (s.lat as f64 * 1e-7 - lat0).to_radians() * r;
                    let e = (s.lng as f64 * 1e-7 - lon0).to_radians() * r * lat0.to_radians().cos();
                    hor.push((t, [n, e], s.yaw as f64));
                }
            }
            MavMessage::SIM_STATE(s) => {
                if let (Some((_, _, alt0)), Some(t)) = (origin, t_att) {
                    ver.push((t, -(s.alt as f64 - alt0), [s.vn as f64, s.ve as f64, s.vd as f64]));
                }
            }
            _ => {}
        }
    }
    (hor, ver)
}

#[test]
fn simulator_tlog_frames_and_signs_match_the_true_state() {
    let path = fixture("sitl_excite_1_head.tlog");
    let set = read_tlog(&path, &ArdupilotOptions::default()).unwrap();
    // The file was cut mid-frame: read up to there, and said.
    assert!(has_note(&set, "ends inside a frame"), "{:?}", set.notes);
    let (att, pos) = (set.attitude.as_ref().unwrap(), set.position.as_ref().unwrap());
    // The EKF's position starts long after the attitude (about 20 s after arming, when it
    // fuses the simulated GPS; 52 s after boot here).
    assert!(pos.t[0] - att.t[0] > 15.0, "position from {} s, attitude from {} s", pos.t[0], att.t[0]);
    assert!(has_note(&set, "the EKF's position starts"), "{:?}", set.notes);
    assert!((rate(att) - 25.0).abs() < 2.0 && (rate(pos) - 10.0).abs() < 1.0);

    let (hor, ver) = sim_truth(&std::fs::read(&path).unwrap());
    let compared = compare_to_truth(&set, &hor, &ver, &[0, 1, 2, 3, 4, 5], true);
    assert!(compared > 300, "{compared} true samples compared");
}

/// Checks the EKF's streams of `set` (the `axes` of north, east, down, vn, ve, vd, and the
/// yaw) against the true state where they overlap, and returns
/// how many true positions it compared. Signs: each EKF stream follows its true counterpart
/// (a flipped axis would correlate at -1); sizes: the typical error is small. The EKF lags
/// the true state at the steps, so medians, not maxima.
fn compare_to_truth(
    set: &StreamSet,
    hor: &[Horizontal],
    ver: &[Vertical],
    axes: &[usize],
    all_axes_move: bool,
) -> usize {
    let (att, pos, vel) =
        (set.attitude.as_ref().unwrap(), set.position.as_ref().unwrap(), set.velocity_ned.as_ref().unwrap());
    let inside = |t: f64| t > pos.t[0] && t < pos.t[pos.len() - 1];
    // Pairs (EKF, truth) per axis: north, east, down, vn, ve, vd; and the yaw errors.
    let mut pairs: [Vec<(f64, f64)>; 6] = Default::default();
    let mut yaw_err = Vec::new();
    for (t, ne, yaw) in hor.iter().filter(|h| inside(h.0)) {
        let pe = interpolate(pos, *t);
        pairs[0].push((pe[0], ne[0]));
        pairs[1].push((pe[1], ne[1]));
        yaw_err.push(angle_diff(yaw_at(att, *t), *yaw).abs());
    }
    for (t, down, v) in ver.iter().filter(|h| inside(h.0)) {
        pairs[2].push((interpolate(pos, *t)[2], *down));
        let ve = interpolate(vel, *t);
        for c in 0..3 {
            pairs[3 + c].push((ve[c], v[c]));
        }
    }
    let names = ["north", "east", "down", "vn", "ve", "vd"];
    for (c, p) in pairs.iter().enumerate().filter(|(c, _)| axes.contains(c)) {
        assert!(p.len() > 20, "{}: {} samples", names[c], p.len());
        let err = median(p.iter().map(|(a, b)| (a - b).abs()).collect());
        let tol = if c < 3 { 0.5 } else { 0.2 };
        assert!(err < tol, "{}: median error {err}", names[c]);
        let (lo, hi) = p.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x.1), hi.max(x.1)));
        if hi - lo > 0.5 {
            let r = correlation(p);
            assert!(r > 0.9, "{}: correlation {r} with the truth", names[c]);
        } else {
            assert!(!all_axes_move, "{}: the truth hardly moves ({lo}..{hi})", names[c]);
        }
    }
    let yaw = median(yaw_err);
    assert!(yaw < 0.05, "yaw off the truth by {yaw} rad (median)");
    pairs[0].len()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn correlation(p: &[(f64, f64)]) -> f64 {
    let n = p.len() as f64;
    let (ma, mb) = (p.iter().map(|x| x.0).sum::<f64>() / n, p.iter().map(|x| x.1).sum::<f64>() / n);
    let cov: f64 = p.iter().map(|(a, b)| (a - ma) * (b - mb)).sum();
    let va: f64 = p.iter().map(|(a, _)| (a - ma).powi(2)).sum();
    let vb: f64 = p.iter().map(|(_, b)| (b - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

/// The yaw of `att` linearly interpolated at `t`, the short way round.
fn yaw_at(att: &Series<3>, t: f64) -> f64 {
    let i = att.t.partition_point(|&x| x < t).clamp(1, att.len() - 1);
    let w = (t - att.t[i - 1]) / (att.t[i] - att.t[i - 1]);
    att.v[i - 1][2] + w * angle_diff(att.v[i][2], att.v[i - 1][2])
}

/// `s` linearly interpolated at `t` (inside its span).
fn interpolate<const N: usize>(s: &Series<N>, t: f64) -> [f64; N] {
    let i = s.t.partition_point(|&x| x < t).clamp(1, s.len() - 1);
    let w = (t - s.t[i - 1]) / (s.t[i] - s.t[i - 1]);
    std::array::from_fn(|c| s.v[i - 1][c] + w * (s.v[i][c] - s.v[i - 1][c]))
}

#[test]
fn simulator_bin_agrees_with_its_tlog_and_tolerates_a_torn_record() {
    let bin = read_bin(&fixture("sitl_excite_1_head.BIN"), &ArdupilotOptions::default()).unwrap();
    assert!(has_note(&bin, "the file ends inside a"), "{:?}", bin.notes);
    // The same run's telemetry holds the simulator's true state, on the same boot clock.
    let (hor, ver) = sim_truth(&std::fs::read(fixture("sitl_excite_1_head.tlog")).unwrap());
    // The EKF logs zeros until it has an origin (ORGN at 19.28 s): the position starts there.
    let set = bin;
    let pos = set.position.as_ref().unwrap();
    assert!(
        (pos.t[0] - 19.28).abs() < 0.11 && pos.v[0].iter().any(|x| *x != 0.0),
        "position from {} s: {:?}",
        pos.t[0],
        pos.v[0]
    );
    assert!(has_note(&set, "origin was set (ORGN)"));
    // Down, its rate and the yaw only: in these first 29 s the EKF's horizontal estimate is
    // still converging after the GPS was first fused (0.5 m/s off the truth; it agrees to
    // 0.05 m/s after 55 s, where the tlog test compares it).
    let compared = compare_to_truth(&set, &hor, &ver, &[2, 5], false);
    assert!(compared > 50, "{compared} true samples compared");
}

fn cut(name: &str, len: usize, dir: &Path) -> PathBuf {
    let bytes = std::fs::read(fixture(name)).unwrap();
    let out = dir.join(format!("cut_{len}_{name}"));
    std::fs::write(&out, &bytes[..len]).unwrap();
    out
}

fn malformed(r: Result<StreamSet, ImportError>, path: &Path, words: &str) {
    match r {
        Err(e @ ImportError::Malformed { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains(&path.display().to_string()) && msg.contains(words), "{msg}");
            assert_eq!(msg.lines().count(), 1);
        }
        other => panic!("expected an error naming {} and {words:?}, got {other:?}", path.display()),
    }
}

#[test]
fn bad_files_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let opts = ArdupilotOptions::default();
    // A .BIN cut inside its first FMT record, and one cut after the formats, before any ATT.
    let p = cut("small.BIN", 50, dir.path());
    malformed(read_bin(&p, &opts), &p, "no FMT record");
    let p = cut("small.BIN", 8000, dir.path());
    malformed(read_bin(&p, &opts), &p, "truncated before any ATT record");
    // A .tlog cut inside its first frame.
    let p = cut("small.tlog", 20, dir.path());
    malformed(read_tlog(&p, &opts), &p, "not a MAVLink telemetry log");
    // Not logs at all: text, and each format read as the other.
    let p = fixture("LICENSE-ardusub_log_tools");
    malformed(read_bin(&p, &opts), &p, "not an ArduPilot dataflash log");
    malformed(read_tlog(&p, &opts), &p, "not a MAVLink telemetry log");
    let p = fixture("small.tlog");
    malformed(read_bin(&p, &opts), &p, "not an ArduPilot dataflash log");
    let p = fixture("small.BIN");
    malformed(read_tlog(&p, &opts), &p, "not a MAVLink telemetry log");
    // A missing file.
    let p = dir.path().join("missing.BIN");
    assert!(matches!(read_bin(&p, &opts), Err(ImportError::Io { .. })));
    // Inputs asked for without the thrusters to convert them.
    let opts = ArdupilotOptions { inputs: InputSource::ThrusterOutputs, ..ArdupilotOptions::default() };
    assert!(matches!(read_bin(&fixture("small.BIN"), &opts), Err(ImportError::Unusable(_))));
}

#[test]
fn bin_pilot_axes_from_rcin() {
    // The simulator's RCIN holds the pilot's axes (gain applied); through the BlueROV2 mix
    // they give the thruster outputs the firmware logged in RCOU wherever the sticks were
    // held (the same RCIN one record before), no thruster saturates and the vertical command
    // is near zero (the vectored mixer then also redistributes saturated thrust and couples
    // forward with vertical thrust: docs/LOGS_ARDUPILOT.md).
    let read = |inputs: InputSource, conv: fn(&[f64]) -> Input| {
        let opts = ArdupilotOptions { inputs, thrusters: Some(Box::new(conv)), ..ArdupilotOptions::default() };
        read_bin(&fixture("sitl_excite_1_head.BIN"), &opts).unwrap().input.unwrap()
    };
    let pilot = || InputSource::ManualControl { gain: 1.0, mix: BLUEROV2_VECTORED_MIX.to_vec() };
    let horizontal = |p: &[f64]| Input::from([p[0], p[1], p[2], p[3]]);
    let vertical = |p: &[f64]| Input::from([p[4], p[5], 0.0, 0.0]);
    let (a, av) = (read(pilot(), horizontal), read(pilot(), vertical));
    let b = read(InputSource::ThrusterOutputs, horizontal);
    let mut compared = 0;
    for (t, out) in b.t.iter().zip(&b.v) {
        let j = a.t.partition_point(|x| x <= t);
        if j < 2 || a.v[j - 2] != a.v[j - 1] {
            continue;
        }
        let pwm = a.v[j - 1];
        if pwm.iter().chain(&av.v[j - 1][..2]).any(|p| (p - 1500.0).abs() >= 399.0)
            || (av.v[j - 1][0] - 1500.0).abs() > 20.0
        {
            continue;
        }
        compared += 1;
        for c in 0..4 {
            assert!((pwm[c] - out[c]).abs() <= 1.0, "t {t}: {pwm:?} vs {out:?}");
        }
    }
    assert!(compared > 50, "{compared} records compared");
}

#[test]
fn tlog_reboot_ends_the_series() {
    // The pymavlink log twice in one file: the second copy's boot times start again at 5 s.
    let dir = tempfile::tempdir().unwrap();
    let once = std::fs::read(fixture("pymavlink.tlog")).unwrap();
    let twice = dir.path().join("twice.tlog");
    std::fs::write(&twice, [once.clone(), once].concat()).unwrap();
    let single = read_tlog(&fixture("pymavlink.tlog"), &ArdupilotOptions::default()).unwrap();
    let set = read_tlog(&twice, &ArdupilotOptions::default()).unwrap();
    assert!(has_note(&set, "rebooted"), "{:?}", set.notes);
    assert_eq!(set.attitude, single.attitude);
    assert_eq!(set.position, single.position);
}

/// The .BIN's gyro (IMU instance 0, `GyrZ`) is its yaw rate: on the same run it agrees with
/// the telemetry's `ATTITUDE.yawspeed` (the autopilot's body yaw rate) to 0.03 rad/s RMS
/// (measured 0.020), where the run turns at up to 2.2 rad/s.
#[test]
fn a_bin_gives_its_gyro_as_the_yaw_rate() {
    let bin = read_bin(&fixture("sitl_excite_1_head.BIN"), &ArdupilotOptions::default()).unwrap();
    let tlog = read_tlog(&fixture("sitl_excite_1_head.tlog"), &ArdupilotOptions::default()).unwrap();
    let (gyro, attitude) = (bin.yaw_rate.as_ref().unwrap(), tlog.yaw_rate.as_ref().unwrap());
    assert!(gyro.source.contains("IMU[I=0].GyrZ"), "{}", gyro.source);
    let (lo, hi) = (gyro.t[0].max(attitude.t[0]), gyro.t[gyro.len() - 1].min(attitude.t[attitude.len() - 1]));
    let pairs: Vec<(f64, f64)> = attitude
        .t
        .iter()
        .zip(&attitude.v)
        .filter(|(t, _)| (lo..=hi).contains(*t))
        .map(|(&t, r)| (interpolate(gyro, t)[0], r[0]))
        .collect();
    assert!(pairs.len() > 100, "{} common samples", pairs.len());
    let rms = (pairs.iter().map(|(a, b)| (a - b).powi(2)).sum::<f64>() / pairs.len() as f64).sqrt();
    let fastest = pairs.iter().map(|(_, b)| b.abs()).fold(0.0, f64::max);
    assert!(rms < 0.03 && fastest > 1.0, "RMS {rms}, fastest {fastest}");
}
