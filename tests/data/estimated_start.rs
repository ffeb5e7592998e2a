//! Windows started from the estimator's state (`pinc::estimation::window_starts`), against the
//! simulator's truth: a run whose recorded body velocities are wrong the way a tank's are
//! (a third of the speed, correlated over half a second) and whose positions are right to a
//! few millimetres, imported as any recording is.

use pinc::dataset::import::{ImportOptions, Recording, import};
use pinc::estimation::window_starts::{
    StartError, StartSettings, Targets, check_positions, estimate_point_starts, with_estimated_starts,
    with_estimated_starts_and_targets,
};
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
    crate::resample::options(DT, WINDOW, [0.0, 0.0, 1.0])
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
    let points = estimate_point_starts(&model, set, &settings).unwrap();
    // The first 4 s of the run have no estimate (the first window's first 40 points); every
    // later point has one.
    let first_estimated = points.iter().position(Option::is_some).unwrap();
    assert_eq!(first_estimated, 40);
    assert!(points[first_estimated..].iter().all(Option::is_some));

    // Point k of window i is row 65 i + k; the first and the last point of consecutive
    // windows are the same row, and have the same estimate.
    let (mut recorded_err, mut estimated_err, mut n) = (0.0, 0.0, 0.0);
    for i in 1..set.count {
        for k in 0..WINDOW {
            let truth = truth[i * (WINDOW - 1) + k];
            let recorded = to_simulator(&set.trajectory(i).0[k]);
            let estimated = to_simulator(&points[i * WINDOW + k].unwrap());
            for c in 4..6 {
                recorded_err += (recorded[c] - truth[c]).powi(2);
                estimated_err += (estimated[c] - truth[c]).powi(2);
            }
            n += 2.0;
        }
        assert_eq!(points[i * WINDOW], points[i * WINDOW - 1]);
    }
    let (recorded_err, estimated_err) = ((recorded_err / n).sqrt(), (estimated_err / n).sqrt());
    eprintln!("u, v error RMS: estimated {estimated_err:.4} m/s, recorded {recorded_err:.4}");
    assert!(estimated_err < 0.4 * recorded_err, "u, v error: estimated {estimated_err} m/s, recorded {recorded_err}");

    // The model that made the run predicts longer from there (VPT on positions).
    let starts = with_estimated_starts(&model, set, &settings).unwrap();
    assert_eq!(starts.without_history, 1);
    let (recorded_set, estimated_set) = (&starts.recorded, &starts.estimated);
    assert_eq!((recorded_set.count, estimated_set.count), (29, 29));
    let from_recorded = evaluate_set_discrete(&model, recorded_set).unwrap();
    let from_estimated = evaluate_set_discrete(&model, estimated_set).unwrap();
    eprintln!(
        "VPT {:.2} s from estimates, {:.2} s from the record; one-step MSE {:.2e} against {:.2e}",
        from_estimated.vpt_s, from_recorded.vpt_s, from_estimated.one_step_mse, from_recorded.one_step_mse
    );
    assert!(
        from_estimated.vpt_s > 1.3 * from_recorded.vpt_s,
        "VPT {} s from estimates, {} s from the record",
        from_estimated.vpt_s,
        from_recorded.vpt_s
    );
    // Not asserted: the one-step MSE against the record rises (measured 3.56e-3 against
    // 2.21e-3), since a recorded velocity's error persists into the next recorded sample: the
    // record agrees with itself, and the estimate does not share its error.
    // The targets are the recording's, untouched.
    assert_eq!((&estimated_set.states, &estimated_set.inputs), (&recorded_set.states, &recorded_set.inputs));
    assert_eq!(estimated_set.starts.len(), estimated_set.states.len());
}

#[test]
fn an_estimate_uses_nothing_of_its_own_point_or_after() {
    let (_, rec) = recorded_run(3);
    let data = import(&[rec], &["0".repeat(64)], &options()).unwrap();
    let set = data.set("test").unwrap().clone();
    let model = Rk4Vehicle::with_dt(DT);
    let settings = StartSettings::from_set(&set, 4.0);
    let before = estimate_point_starts(&model, &set, &settings).unwrap();
    // Change window 10 from its point 5 on (the states, and the inputs held from there).
    let mut changed = set.clone();
    let p = set.points;
    for x in &mut changed.states[10 * p + 5..11 * p] {
        x[5] += 0.5;
        x[0] += 1.0;
    }
    // Window 11's first state is window 10's last: keep them shared.
    changed.states[11 * p] = changed.states[11 * p - 1];
    for u in &mut changed.inputs[10 * (p - 1) + 5..11 * (p - 1)] {
        u[0] += 10.0;
    }
    let after = estimate_point_starts(&model, &changed, &settings).unwrap();
    assert_eq!(before[..10 * p + 6], after[..10 * p + 6], "up to point 5 of window 10");
    assert_ne!(before[10 * p + 6], after[10 * p + 6]);
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
    assert!(matches!(&e, StartError::NoPositions { file } if file == "tank_like.csv"), "{e}");
    assert!(e.to_string().contains("tank_like.csv has no position stream"), "{e}");
}

#[test]
fn smoothed_targets_agree_with_the_truth_where_the_record_does_not() {
    let (truth, rec) = recorded_run(11);
    let data = import(&[rec], &["0".repeat(64)], &options()).unwrap();
    let set = data.set("test").unwrap();
    let model = Rk4Vehicle::with_dt(DT);
    let settings = StartSettings::from_set(set, 4.0);
    let plain = with_estimated_starts(&model, set, &settings).unwrap();
    let smoothed = with_estimated_starts_and_targets(&model, set, &settings, Targets::Smoothed).unwrap();
    // The same windows and starts; only the targets' u v w r differ from the record.
    assert_eq!(smoothed.estimated.starts, plain.estimated.starts);
    let (mut recorded_err, mut smoothed_err, mut start_err) = (0.0, 0.0, 0.0);
    for j in 0..smoothed.estimated.count {
        // Kept window j is window j + 1 of the set (the first has no history).
        for k in 0..WINDOW {
            let at = j * WINDOW + k;
            let truth = truth[(j + 1) * (WINDOW - 1) + k];
            let (r, s) = (to_simulator(&plain.estimated.states[at]), to_simulator(&smoothed.estimated.states[at]));
            let start = to_simulator(&smoothed.estimated.starts[at]);
            assert_eq!((s[0], s[1], s[2], s[3]), (r[0], r[1], r[2], r[3]), "positions, depth, heading as recorded");
            for c in 4..6 {
                recorded_err += (r[c] - truth[c]).powi(2);
                smoothed_err += (s[c] - truth[c]).powi(2);
                start_err += (start[c] - truth[c]).powi(2);
            }
        }
    }
    // Measured: 0.0191 m/s smoothed, 0.0203 filtered, 0.101 recorded (RMS of u and v): the
    // filter's process noise lets the positions set the velocities already, and the smoother
    // adds the samples after each point.
    let n = (2 * smoothed.estimated.count * WINDOW) as f64;
    let [recorded_err, smoothed_err, start_err] = [recorded_err, smoothed_err, start_err].map(|e| (e / n).sqrt());
    eprintln!("u, v RMS error: smoothed {smoothed_err:.4}, filtered {start_err:.4}, recorded {recorded_err:.4} m/s");
    assert!(smoothed_err < start_err && start_err < 0.4 * recorded_err, "{smoothed_err} {start_err} {recorded_err}");
}
