//! Windows started from the estimator's state (`pinc::estimation::window_starts`), against the
//! simulator's truth: a run whose recorded body velocities are wrong the way a tank's are
//! (a third of the speed, correlated over half a second) and whose positions are right to a
//! few millimetres, imported as any recording is.

use pinc::dataset::import::{ImportOptions, Recording, import};
use pinc::estimation::window_starts::{StartError, StartSettings, check_positions, estimate_starts};
use pinc::eval::evaluate_set_discrete;
use pinc::vehicle::{Rk4Vehicle, to_simulator};
use pinc::{Input, SimState};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;

const DT: f64 = 0.1;
const WINDOW: usize = 66;

/// A 200 s run at 10 Hz under inputs that change every 1.5 s, its truth, and the recording of
/// it: positions, depth and heading with 3 mm / 3 mrad of noise, body velocities off by a
/// random error that stays for about 0.5 s (a first-order process, 0.1 m/s and 0.05 rad/s
/// in steady state).
fn recorded_run(seed: u64) -> (Vec<SimState>, Recording) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let rows = 2000;
    let mut inputs = Vec::with_capacity(rows);
    let mut u = Input::zeros();
    for i in 0..rows {
        if i % 15 == 0 {
            u = Input::from([
                rng.random_range(-30.0..30.0),
                rng.random_range(-20.0..20.0),
                rng.random_range(-15.0..25.0),
                rng.random_range(-4.0..4.0),
            ]);
        }
        inputs.push(u);
    }
    let truth = Rk4Vehicle::with_dt(DT)
        .simulate(&SimState::from([0.0, 0.0, 2.0, 0.3, 0.0, 0.0, 0.0, 0.0]), &inputs[..rows - 1]);
    let keep = (-DT / 0.5_f64).exp();
    let drive = (1.0 - keep * keep).sqrt();
    let mut error = [0.0_f64; 4];
    let gauss = |s: f64, rng: &mut ChaCha8Rng| {
        // Sum of 12 uniforms: unit variance, enough of a normal for noise.
        s * ((0..12).map(|_| rng.random::<f64>()).sum::<f64>() - 6.0)
    };
    let states = truth
        .iter()
        .map(|s| {
            for (k, e) in error.iter_mut().enumerate() {
                let size = if k == 3 { 0.05 } else { 0.1 };
                *e = keep * *e + drive * gauss(size, &mut rng);
            }
            let mut r = *s;
            for k in 0..3 {
                r[k] += gauss(0.003, &mut rng);
            }
            r[3] += gauss(0.003, &mut rng);
            for k in 0..4 {
                r[4 + k] += error[k];
            }
            r
        })
        .collect();
    let rec = Recording {
        path: PathBuf::from("tank_like.csv"),
        t: (0..rows).map(|i| i as f64 * DT).collect(),
        states,
        inputs,
        notes: Vec::new(),
    };
    (truth, rec)
}

fn options() -> ImportOptions {
    ImportOptions {
        format: "csv".into(),
        dt: DT,
        window: WINDOW,
        split: [0.0, 0.0, 1.0],
        seed: 1,
        collocation_points: 1,
        topics: None,
        gap_tolerance: None,
        dt_from_log: false,
    }
}

#[test]
fn the_estimated_start_is_closer_to_the_truth_than_the_recorded_one_and_predicts_longer() {
    let (truth, rec) = recorded_run(7);
    let data = import(&[rec], &["0".repeat(64)], &options()).unwrap();
    let set = data.set("test").unwrap();
    assert_eq!(set.count, 30, "back-to-back windows of 65 intervals");
    let model = Rk4Vehicle::with_dt(DT);
    let settings = StartSettings::from_set(set, 4.0);
    // The noise the set shows: the 3 mm put in, within 25 %; the heading's 3 mrad with the
    // turns' own curvature over two samples on top (measured 4.2 mrad).
    for (name, got, most) in [
        ("position", settings.noise.position_std, 0.00375),
        ("depth", settings.noise.depth_std, 0.00375),
        ("heading", settings.noise.heading_std, 0.005),
    ] {
        assert!(got > 0.00225 && got < most, "{name} noise {got}");
    }
    let starts = estimate_starts(&model, set, &settings).unwrap();
    // The first window has nothing before it; every other has 6.5 s.
    assert_eq!(starts.without_history, 1);
    assert!(starts.starts[0].is_none() && starts.starts[1..].iter().all(Option::is_some));

    // Window i starts at row 65 i.
    let (mut recorded_err, mut estimated_err) = (0.0, 0.0);
    for i in 1..set.count {
        let true_start = truth[i * (WINDOW - 1)];
        let recorded = to_simulator(&set.trajectory(i).0[0]);
        let estimated = to_simulator(&starts.starts[i].unwrap());
        for k in 4..6 {
            recorded_err += (recorded[k] - true_start[k]).powi(2);
            estimated_err += (estimated[k] - true_start[k]).powi(2);
        }
    }
    let n = 2.0 * (set.count - 1) as f64;
    let (recorded_err, estimated_err) = ((recorded_err / n).sqrt(), (estimated_err / n).sqrt());
    assert!(
        estimated_err < 0.4 * recorded_err,
        "u, v start error: estimated {estimated_err} m/s, recorded {recorded_err}"
    );

    // The model that made the run predicts longer from there (VPT on positions).
    let (recorded_set, estimated_set) = starts.split_sets(set);
    assert_eq!((recorded_set.count, estimated_set.count), (29, 29));
    let from_recorded = evaluate_set_discrete(&model, &recorded_set).unwrap();
    let from_estimated = evaluate_set_discrete(&model, &estimated_set).unwrap();
    eprintln!("VPT {:.2} s from estimates, {:.2} s from the record", from_estimated.vpt_s, from_recorded.vpt_s);
    assert!(
        from_estimated.vpt_s > 1.3 * from_recorded.vpt_s,
        "VPT {} s from estimates, {} s from the record",
        from_estimated.vpt_s,
        from_recorded.vpt_s
    );
    // The windows themselves are untouched but for their first state.
    assert_eq!(estimated_set.states[1..WINDOW], recorded_set.states[1..WINDOW]);
    assert_eq!(estimated_set.inputs, recorded_set.inputs);
}

#[test]
fn a_start_uses_nothing_of_its_own_window() {
    let (_, rec) = recorded_run(3);
    let data = import(&[rec], &["0".repeat(64)], &options()).unwrap();
    let set = data.set("test").unwrap().clone();
    let model = Rk4Vehicle::with_dt(DT);
    let settings = StartSettings::from_set(&set, 4.0);
    let before = estimate_starts(&model, &set, &settings).unwrap();
    // Change everything of window 10 but its first state (the last of window 9, which the
    // filter does not see either): its own start is the same; the next window's changes.
    let mut changed = set.clone();
    let points = set.points;
    for x in &mut changed.states[10 * points + 1..11 * points] {
        x[5] += 0.5;
        x[0] += 1.0;
    }
    // Window 11's first state is window 10's last: keep them shared.
    changed.states[11 * points] = changed.states[11 * points - 1];
    for u in &mut changed.inputs[10 * (points - 1)..11 * (points - 1)] {
        u[0] += 10.0;
    }
    let after = estimate_starts(&model, &changed, &settings).unwrap();
    assert_eq!(before.starts[10], after.starts[10]);
    assert_ne!(before.starts[11], after.starts[11]);
}

#[test]
fn a_recording_without_positions_is_refused_by_name() {
    let (_, rec) = recorded_run(5);
    let mut data = import(&[rec], &["0".repeat(64)], &options()).unwrap();
    check_positions(&data, "test").unwrap();
    // What a log without a position source imports as: x, y integrated from its velocities.
    let source = data.source.as_mut().unwrap();
    source.files[0].report.streams.retain(|s| s.name != "position");
    let e = check_positions(&data, "test").unwrap_err();
    assert_eq!(e, StartError::NoPositions { file: "tank_like.csv".into() });
    assert!(e.to_string().contains("tank_like.csv has no position stream"), "{e}");
}
