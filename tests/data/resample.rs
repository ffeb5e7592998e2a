//! The shared resampling of log streams: a 10 Hz log against a direct simulation, streams at
//! different rates, gaps, yaw across +-pi, NED velocity into body axes.

use pinc::dataset::import::{
    ImportOptions, LogFile, Recording, Series, StreamSet, import_logs, read_csv, resample, stream_set_of,
};
use pinc::vehicle::Rk4Vehicle;
use pinc::{Input, SimState};
use std::f64::consts::PI;
use std::io::Write;
use std::path::{Path, PathBuf};

const FINE: f64 = 0.01;

/// Inputs held over 0.1 s, changing every hold.
fn held_input(hold: usize) -> Input {
    let k = hold as f64;
    Input::from([6.0 * (0.7 * k).sin(), 3.0 * (0.43 * k).cos(), 5.0 + 6.0 * (0.31 * k).sin(), 0.6 * (0.53 * k).sin()])
}

/// A run simulated at 0.01 s for `holds` holds of 0.1 s: fine states and their inputs.
fn fine_run(holds: usize) -> (Vec<SimState>, Vec<Input>) {
    let sim = Rk4Vehicle { substeps: 2, ..Rk4Vehicle::with_dt(FINE) };
    let inputs: Vec<Input> = (0..holds * 10).map(|i| held_input(i / 10)).collect();
    let s0 = SimState::from([1.0, -2.0, 3.0, 2.9, 0.3, 0.1, 0.0, 0.2]);
    (sim.simulate(&s0, &inputs), inputs)
}

fn write_csv(path: &Path, t: &[f64], states: &[SimState], inputs: &[Input]) {
    let mut f = std::fs::File::create(path).unwrap();
    writeln!(f, "t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz").unwrap();
    for i in 0..t.len() {
        let (s, u) = (&states[i], &inputs[i]);
        writeln!(
            f,
            "{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
            t[i], s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], u[0], u[1], u[2], u[3]
        )
        .unwrap();
    }
}

pub(crate) fn options(dt: f64, window: usize, split: [f64; 3]) -> ImportOptions {
    ImportOptions {
        format: "streams".into(),
        dt,
        window,
        split,
        seed: 1,
        collocation_points: 1,
        topics: None,
        gap_tolerance: None,
        dt_from_log: false,
    }
}

#[test]
fn a_10_hz_log_imported_at_0_08_s_equals_a_direct_simulation_within_the_interpolation_error() {
    let holds = 300; // 30 s
    let (fine, fine_u) = fine_run(holds);
    // The log: every 10th fine state, the input held from each row to the next.
    let t: Vec<f64> = (0..=holds).map(|i| i as f64 * 0.1).collect();
    let states: Vec<SimState> = (0..=holds).map(|i| fine[10 * i]).collect();
    let inputs: Vec<Input> = (0..=holds).map(held_input).collect();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run10hz.csv");
    write_csv(&path, &t, &states, &inputs);
    let rec = read_csv(&path).unwrap();
    let (grid, report) = resample(&stream_set_of(&rec), 0.08, None, &path).unwrap();
    assert_eq!(grid.t.len(), 376, "30 s at 0.08 s");
    assert!((report.streams[0].rate_hz.unwrap() - 10.0).abs() < 1e-9 && report.streams[0].gaps == 0);

    // Linear interpolation between samples h = 0.1 s apart errs by at most h^2/8 max|x''| on
    // each interval (the inputs change only at the samples, so every state is smooth between
    // them). max|x''| per component from second differences of the fine run inside the
    // intervals; the bound gets 10 % for that estimate and 1e-12 for rounding.
    let h = 0.1;
    let mut bound = [0.0f64; 8];
    for i in 0..holds {
        for j in 1..10 {
            let k = 10 * i + j;
            let (a, b, c) = (fine[k - 1], fine[k], fine[k + 1]);
            for (c_, bd) in bound.iter_mut().enumerate() {
                let d2 = if c_ == 3 {
                    (pinc::vehicle::wrap_angle(c[3] - b[3]) - pinc::vehicle::wrap_angle(b[3] - a[3])) / (FINE * FINE)
                } else {
                    (c[c_] - 2.0 * b[c_] + a[c_]) / (FINE * FINE)
                };
                *bd = bd.max(d2.abs());
            }
        }
    }
    let bound = bound.map(|m| 1.1 * h * h / 8.0 * m + 1e-12);
    let mut worst = [0.0f64; 8];
    for (k, s) in grid.states.iter().enumerate() {
        // The direct simulation sampled at 0.08 s: every 8th fine state.
        let truth = fine[8 * k];
        for c in 0..8 {
            let e = if c == 3 { pinc::vehicle::wrap_angle(s[3] - truth[3]) } else { s[c] - truth[c] };
            worst[c] = worst[c].max(e.abs());
            assert!(e.abs() <= bound[c], "row {k} component {c}: error {e:e} > bound {:e}", bound[c]);
        }
        // Inputs: the exact time-average of the held input over the period (8 fine steps).
        if 8 * k + 8 <= fine_u.len() {
            let exact: Input = fine_u[8 * k..8 * k + 8].iter().sum::<Input>() / 8.0;
            assert!((grid.inputs[k] - exact).amax() < 1e-12, "row {k}: {} vs {exact}", grid.inputs[k]);
        }
    }
    // The bound is not vacuous: the interpolation error is a visible fraction of it (measured:
    // x 6.5e-4 m of 7.8e-4, psi 1.3e-3 rad of 3.4e-3, u 7.3e-4 m/s of 8.8e-4, r 1.2e-2 rad/s
    // of 3.1e-2).
    assert!((0..8).all(|c| worst[c] <= bound[c]) && worst[4] > 0.05 * bound[4], "{worst:?} vs {bound:?}");

    // Imported at 0.08 s the 10 Hz log is not refused: 375 intervals give 5 windows of 66.
    let data = pinc::dataset::import::import(&[rec], &["0".repeat(64)], &options(0.08, 66, [1.0, 0.0, 0.0])).unwrap();
    assert_eq!(data.set("train").unwrap().count, 5);
    assert!(data.set("test").unwrap().count == 0 && data.set("dev").unwrap().count == 0);
}

fn series<const N: usize>(name: &str, rate: f64, end: f64, f: impl Fn(f64) -> [f64; N]) -> Series<N> {
    let mut s = Series::new(name);
    let n = (end * rate).round() as usize;
    for k in 0..=n {
        let t = k as f64 / rate;
        s.push(t, f(t));
    }
    s
}

/// A slow steady turn: position at 25 Hz, attitude and body velocity at 10 Hz, the input at
/// 3 Hz, over 30 s.
fn multi_rate() -> StreamSet {
    StreamSet {
        position: Some(series("pos", 25.0, 30.0, |t| [t.sin(), t.cos(), 0.1 * t])),
        attitude: Some(series("att", 10.0, 30.0, |t| [0.0, 0.0, pinc::vehicle::wrap_angle(0.2 * t)])),
        velocity_body: Some(series("vel", 10.0, 30.0, |t| [0.5 + 0.01 * t, 0.0, 0.1])),
        input: Some(series("cmd", 3.0, 30.0, |t| [t.floor(), 0.0, 1.0, 0.0])),
        ..StreamSet::default()
    }
}

#[test]
fn streams_at_25_10_and_3_hz_merge_on_one_time_base_and_a_gap_in_one_ends_a_window() {
    let path = PathBuf::from("multi");
    let set = multi_rate();
    let (rec, report) = resample(&set, 0.1, None, &path).unwrap();
    assert_eq!(rec.t.len(), 301);
    let rates: Vec<f64> = report.streams.iter().map(|s| s.rate_hz.unwrap()).collect();
    assert_eq!(rates.len(), 4);
    for (r, want) in rates.iter().zip([25.0, 10.0, 10.0, 3.0]) {
        assert!((r - want).abs() < 1e-6, "{rates:?}");
    }
    // Yaw rate derived from the yaw: 0.2 rad/s.
    assert!(rec.states.iter().all(|s| (s[7] - 0.2).abs() < 1e-9));
    for (k, s) in rec.states.iter().enumerate() {
        let t = k as f64 * 0.1;
        // Position at 25 Hz interpolated: error under (0.04)^2/8 max|sin''| = 2e-4.
        assert!((s[0] - t.sin()).abs() < 2e-4 && (s[2] - 0.1 * t).abs() < 1e-12, "row {k}");
        // The 3 Hz input is held: over [t, t + 0.1] the time-average of floor(t') sampled at k/3.
        let held = |x: f64| ((x * 3.0 + 1e-9).floor() / 3.0).floor();
        let exact: f64 = (0..1000).map(|i| held(t + (i as f64 + 0.5) * 1e-4)).sum::<f64>() / 1000.0;
        assert!((rec.inputs[k][0] - exact).abs() < 2e-3, "row {k}: {} vs {exact}", rec.inputs[k][0]);
    }
    let log = |set: StreamSet| LogFile { path: path.clone(), sha256: "0".repeat(64), streams: set };
    let data = import_logs(&[log(set.clone())], &options(0.1, 21, [1.0, 0.0, 0.0])).unwrap();
    assert_eq!(data.set("train").unwrap().count, 15, "300 intervals, windows of 20");

    // The attitude stream loses 10.1..10.9 s: a 1 s step, over the default tolerance
    // max(3 x 0.1 s, 2 dt) = 0.3 s. Stretches 0..10 s (100 intervals, 5 windows) and 11..30 s
    // (190 intervals, 9 windows).
    let mut gappy = set;
    let att = gappy.attitude.as_mut().unwrap();
    let keep: Vec<usize> = (0..att.len()).filter(|&i| !(101..110).contains(&i)).collect();
    att.t = keep.iter().map(|&i| att.t[i]).collect();
    att.v = keep.iter().map(|&i| att.v[i]).collect();
    let data = import_logs(&[log(gappy.clone())], &options(0.1, 21, [1.0, 0.0, 0.0])).unwrap();
    let source = data.source.as_ref().unwrap();
    assert_eq!(data.set("train").unwrap().count, 14);
    assert_eq!(source.skipped.gaps, 1);
    let att_info = &source.files[0].report.streams[1];
    assert_eq!((att_info.name.as_str(), att_info.gaps), ("attitude", 1));
    assert!((att_info.longest_step_s - 1.0).abs() < 1e-9);
    // A tolerance of 1.5 s bridges it.
    let o = ImportOptions { gap_tolerance: Some(1.5), ..options(0.1, 21, [1.0, 0.0, 0.0]) };
    assert_eq!(import_logs(&[log(gappy)], &o).unwrap().set("train").unwrap().count, 15);
}

fn minimal(yaw: [f64; 2], velocity_ned: Option<[f64; 3]>, roll_pitch: [f64; 2]) -> StreamSet {
    let mut att = Series::new("att");
    att.push(0.0, [roll_pitch[0], roll_pitch[1], yaw[0]]);
    att.push(1.0, [roll_pitch[0], roll_pitch[1], yaw[1]]);
    let two = |v: [f64; 3]| {
        let mut s = Series::new("s");
        s.push(0.0, v);
        s.push(1.0, v);
        s
    };
    let mut input = Series::new("cmd");
    input.push(0.0, [0.0; 4]);
    input.push(1.0, [0.0; 4]);
    StreamSet {
        position: Some(two([0.0; 3])),
        attitude: Some(att),
        velocity_ned: velocity_ned.map(two),
        velocity_body: velocity_ned.is_none().then(|| two([0.0; 3])),
        input: Some(input),
        ..StreamSet::default()
    }
}

#[test]
fn yaw_across_pi_interpolates_the_short_way() {
    let (rec, _) = resample(&minimal([3.1, -3.1], None, [0.0; 2]), 0.5, Some(2.0), Path::new("y")).unwrap();
    // Half way from 3.1 to -3.1 the short way (through pi, 0.083 rad) is pi, not 0.
    assert_eq!(rec.t, [0.0, 0.5, 1.0]);
    assert!((rec.states[1][3].abs() - PI).abs() < 1e-12, "{}", rec.states[1][3]);
    assert_eq!((rec.states[0][3], rec.states[2][3]), (3.1, -3.1));
    // The derived yaw rate: +0.083 rad over 1 s.
    assert!((rec.states[1][7] - (2.0 * PI - 6.2)).abs() < 1e-12);
}

#[test]
fn ned_velocity_is_rotated_into_body_axes() {
    let body = |yaw: f64, v: [f64; 3], rp: [f64; 2]| {
        let (rec, report) = resample(&minimal([yaw, yaw], Some(v), rp), 0.5, Some(2.0), Path::new("v")).unwrap();
        assert!(report.notes.iter().any(|n| n.contains("NED velocity rotated")));
        [rec.states[1][4], rec.states[1][5], rec.states[1][6]]
    };
    let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|i| (a[i] - b[i]).abs() < 1e-12);
    // Heading east (yaw pi/2) moving east: surge, no sway.
    assert!(close(body(PI / 2.0, [0.0, 1.0, 0.0], [0.0; 2]), [1.0, 0.0, 0.0]));
    // Heading east moving north: the vehicle slides to its left (negative sway).
    assert!(close(body(PI / 2.0, [1.0, 0.0, 0.0], [0.0; 2]), [0.0, -1.0, 0.0]));
    // Nose up 0.3 rad heading north, climbing along the nose: pure surge.
    assert!(close(body(0.0, [0.3f64.cos(), 0.0, -0.3f64.sin()], [0.0, 0.3]), [1.0, 0.0, 0.0]));
    // Rolled 90 degrees right: the right axis points down, so sinking is positive sway.
    assert!(close(body(0.0, [0.0, 0.0, 1.0], [PI / 2.0, 0.0]), [0.0, 1.0, 0.0]));
}

#[test]
fn a_recording_at_the_period_goes_through_unchanged_and_the_period_can_come_from_the_log() {
    let sim = Rk4Vehicle::with_dt(0.08);
    let inputs: Vec<Input> = (0..100).map(|k| held_input(k / 3)).collect();
    let s0 = SimState::from([0.0, 0.0, 1.0, 3.0, 0.2, 0.0, 0.0, 0.3]);
    let states = sim.simulate(&s0, &inputs[..99]);
    let rec = Recording {
        path: "r".into(),
        t: (0..100).map(|i| i as f64 * 0.08).collect(),
        states,
        inputs,
        notes: Vec::new(),
    };
    let set = stream_set_of(&rec);
    assert_eq!(pinc::dataset::import::log_dt(&set), Some(0.08));
    let (grid, _) = resample(&set, 0.08, None, &rec.path).unwrap();
    assert_eq!((grid.states, grid.inputs), (rec.states, rec.inputs));
}
