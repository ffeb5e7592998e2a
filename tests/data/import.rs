//! Datasets from recorded runs: resampling, windows, splits by run and by time, and every
//! kind of bad input as an error naming the file and the place.

use pinc::dataset::import::{ImportOptions, Recording, import, read_csv};
use pinc::vehicle::{Rk4Vehicle, to_network};
use pinc::{Input, SimState};
use std::io::Write;
use std::path::{Path, PathBuf};

fn options(window: usize, split: [f64; 3]) -> ImportOptions {
    ImportOptions {
        format: "csv".into(),
        dt: 0.08,
        window,
        split,
        seed: 3,
        collocation_points: 1,
        topics: None,
        gap_tolerance: None,
        dt_from_log: false,
    }
}

/// A run simulated at `period` with inputs that change every 0.08 s, starting at `x0`.
fn run(path: &str, period: f64, rows: usize, x0: f64) -> Recording {
    let sim = Rk4Vehicle::with_dt(period);
    let per = (0.08 / period).round() as usize;
    let inputs: Vec<Input> = (0..rows)
        .map(|i| {
            let k = (i / per) as f64;
            Input::from([
                5.0 * (0.3 * k).sin(),
                2.0 * (0.17 * k).cos(),
                8.0 + 6.0 * (0.11 * k).sin(),
                0.4 * (0.23 * k).sin(),
            ])
        })
        .collect();
    let s0 = SimState::from([x0, 0.0, 1.0, 0.2, 0.1, 0.0, 0.0, 0.0]);
    let states = sim.simulate(&s0, &inputs[..rows - 1]);
    Recording {
        path: PathBuf::from(path),
        t: (0..rows).map(|i| i as f64 * period).collect(),
        states,
        inputs,
        notes: Vec::new(),
    }
}

fn write_csv(dir: &Path, name: &str, rec: &Recording) -> PathBuf {
    let path = dir.join(name);
    let mut f = std::fs::File::create(&path).unwrap();
    writeln!(f, "t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz").unwrap();
    for i in 0..rec.t.len() {
        let s = &rec.states[i];
        let u = &rec.inputs[i];
        writeln!(
            f,
            "{},{},{},{},{},{},{},{},{},{},{},{},{}",
            rec.t[i], s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], u[0], u[1], u[2], u[3]
        )
        .unwrap();
    }
    path
}

fn hashes(n: usize) -> Vec<String> {
    vec!["0".repeat(64); n]
}

#[test]
fn a_log_at_a_quarter_of_the_period_is_decimated_to_the_same_windows_as_a_direct_simulation() {
    let dir = tempfile::tempdir().unwrap();
    let fast = run("fast.csv", 0.02, 4 * 65 * 4 + 1, 0.0);
    let rec = read_csv(&write_csv(dir.path(), "fast.csv", &fast)).unwrap();
    let data = import(&[rec], &hashes(1), &options(66, [0.5, 0.0, 0.5])).unwrap();
    // 260 intervals at 0.08 s: four windows of 65; one run is split by time with one window
    // left out between train and test.
    let counts: Vec<usize> = data.sets.iter().map(|s| s.count).collect();
    assert_eq!(counts, [2, 0, 1]);
    // Every window equals the 0.08 s simulation from its first state with the held inputs.
    let slow = Rk4Vehicle::with_dt(0.08);
    for set in &data.sets {
        for i in 0..set.count {
            let (xs, us) = set.trajectory(i);
            let s0 = pinc::vehicle::to_simulator(&xs[0]);
            let truth = slow.simulate(&s0, us);
            for (a, b) in xs.iter().zip(&truth) {
                assert!((a - to_network(b)).amax() < 1e-9, "{a} vs {b}");
            }
        }
    }
}

#[test]
fn nan_rows_gaps_and_non_monotonic_stamps_end_windows_and_are_counted() {
    let mut rec = run("r.csv", 0.08, 400, 0.0);
    rec.states[100][2] = f64::NAN; // a NaN row
    for t in &mut rec.t[200..] {
        *t += 1.0; // a gap of 1 s
    }
    // A time stamp that does not advance; the step after it is then twice the period, a gap.
    rec.t[300] = rec.t[299];
    let (windows, skips) = pinc::dataset::import::cut_windows(&rec, 0.08, 66).unwrap();
    assert_eq!((skips.non_finite_rows, skips.gaps, skips.non_monotonic), (1, 2, 1));
    // Stretches [0, 100), [101, 200), [200, 300), [300, 301), [301, 400): one window (66 rows)
    // in each but the single row.
    assert_eq!(windows.len(), 4);
    assert_eq!(skips.tail_rows, (100 - 66) + (99 - 66) + (100 - 66) + 1 + (99 - 66));
    // The window after the NaN starts at row 101.
    assert_eq!(windows[1].states[0], rec.states[101]);
}

#[test]
fn windows_of_one_run_never_land_in_two_splits() {
    let runs: Vec<Recording> =
        (0..10).map(|r| run(&format!("run{r}.csv"), 0.08, 66 * (1 + r % 3) + 1, 100.0 * r as f64)).collect();
    let data = import(&runs, &hashes(10), &options(66, [0.7, 0.15, 0.15])).unwrap();
    let source = data.source.as_ref().unwrap();
    assert_eq!(source.split_by, "run");
    // Each window's run is recognisable by its x (runs start 100 m apart and move < 10 m).
    let run_of = |x: f64| (x / 100.0).round() as usize;
    let mut owner: Vec<Option<String>> = vec![None; 10];
    for set in &data.sets {
        assert!(set.count > 0, "{} empty", set.name);
        for i in 0..set.count {
            let r = run_of(set.trajectory(i).0[0][0]);
            assert!(owner[r].as_ref().is_none_or(|o| *o == set.name), "run {r} in {} and {:?}", set.name, owner[r]);
            owner[r] = Some(set.name.clone());
            assert_eq!(source.files[r].split, set.name);
        }
    }
    // Collocation times for the physics loss in the train split only, at t = T.
    let train = data.set("train").unwrap();
    assert_eq!(train.collocation.len(), train.count * 65);
    assert!(train.collocation.iter().all(|&t| t == 0.08));
}

#[test]
fn a_single_run_is_split_by_time_with_one_window_left_out_between_splits() {
    let rec = run("one.csv", 0.08, 65 * 12 + 1, 0.0);
    let data = import(std::slice::from_ref(&rec), &hashes(1), &options(66, [0.7, 0.15, 0.15])).unwrap();
    assert_eq!(data.source.as_ref().unwrap().split_by, "time");
    let counts: Vec<usize> = data.sets.iter().map(|s| s.count).collect();
    assert_eq!(counts.iter().sum::<usize>() + 2, 12, "{counts:?}");
    // Train ends, one window is skipped, dev starts.
    let last_train = data.set("train").unwrap().trajectory(counts[0] - 1).0[65];
    let first_dev = data.set("dev").unwrap().trajectory(0).0[0];
    let row = |x: &pinc::State| rec.states.iter().position(|s| (to_network(s) - x).amax() == 0.0).unwrap();
    assert_eq!(row(&first_dev) - row(&last_train), 65);
}

#[test]
fn bad_input_is_an_error_naming_the_file_and_the_place() {
    let dir = tempfile::tempdir().unwrap();
    let good = write_csv(dir.path(), "good.csv", &run("good.csv", 0.08, 100, 0.0));
    let text = std::fs::read_to_string(&good).unwrap();
    let write = |name: &str, body: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, body).unwrap();
        p
    };
    let err = |p: &Path| read_csv(p).unwrap_err().to_string();
    // Cut in the middle of its last row (a logger that lost power): every complete row is
    // read, the torn one skipped and noted.
    let cut = write("cut.csv", &text[..text.len() - 40]);
    let torn = read_csv(&cut).unwrap();
    assert_eq!(torn.t.len(), 99);
    assert!(
        torn.notes.iter().any(|n| n.starts_with("line 101: ") && n.contains("fields") && n.contains("last line")),
        "{:?}",
        torn.notes
    );
    // The same damage before the last line is an error naming its line.
    let lines: Vec<&str> = text.lines().collect();
    let short_row: String = lines[50].split(',').take(9).collect::<Vec<_>>().join(",");
    let mut damaged: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    damaged[50] = short_row;
    let middle = write("middle.csv", &(damaged.join("\n") + "\n"));
    let e = err(&middle);
    assert!(e.starts_with(&format!("{}: line 51: 9 fields, the header has 13", middle.display())), "{e}");
    let header = write("header.csv", &text.replacen("psi", "yaw", 1));
    assert!(err(&header).contains("line 1: header must be t,x,y,z,psi"), "{}", err(&header));
    let word = write("word.csv", &text.replacen("\n0.08,", "\nlater,", 1));
    assert!(err(&word).ends_with("line 3: column t: \"later\" is not a number"), "{}", err(&word));
    assert!(err(&write("empty.csv", "t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz\n")).ends_with("no rows after the header"));
    assert!(err(&dir.path().join("missing.csv")).contains("missing.csv: "));
    // A log at 0.03 s, neither 0.08 s nor an integer fraction of it, is resampled (it was
    // refused before the shared resampling): 200 rows span 5.97 s, 75 periods of 0.08 s.
    let odd = read_csv(&write_csv(dir.path(), "odd.csv", &run("odd.csv", 0.03, 200, 0.0))).unwrap();
    let data = import(&[odd], &hashes(1), &options(66, [1.0, 0.0, 0.0])).unwrap();
    assert_eq!(data.source.as_ref().unwrap().files[0].rows, 75);
    // A window longer than every run.
    let short = read_csv(&good).unwrap();
    let e = import(&[short], &hashes(1), &options(200, [0.7, 0.15, 0.15])).unwrap_err().to_string();
    assert!(e.starts_with("no run holds a window of 200 points"), "{e}");
    // Options checked first.
    assert!(options(66, [0.7, 0.2, 0.2]).check().unwrap_err().to_string().contains("summing to 1"));
}

#[test]
fn an_imported_folder_round_trips_with_its_source_and_is_written_whole() {
    let dir = tempfile::tempdir().unwrap();
    let runs: Vec<Recording> = (0..4).map(|r| run(&format!("r{r}.csv"), 0.08, 200, 100.0 * r as f64)).collect();
    let data = import(&runs, &hashes(4), &options(66, [0.5, 0.25, 0.25])).unwrap();
    let out = dir.path().join("set");
    pinc::dataset::save(&data, &out).unwrap();
    let back = pinc::dataset::load(&out).unwrap();
    assert_eq!(back, data);
    // No partial folder is left beside it, and a folder that is not a dataset is never replaced.
    let names: Vec<String> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into()).collect();
    assert_eq!(names, ["set"]);
    let other = dir.path().join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("notes.txt"), "mine").unwrap();
    let e = pinc::dataset::save(&data, &other).unwrap_err().to_string();
    assert!(e.contains("is not a dataset folder"), "{e}");
    assert_eq!(std::fs::read_to_string(other.join("notes.txt")).unwrap(), "mine");
}
