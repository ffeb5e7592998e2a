//! `examples/c`: the C program and the C++ wrapper's example, built with the system `cc` and
//! `c++` against the static library, print the same rollout and Jacobians as the Rust API,
//! to the last bit, and the documented error codes.

use pinc::model::PincModel;
use pinc::runtime::{HorizonLinearisation, Predictor};
use pinc::{Input, State};
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The static library, built once per test run by a nested `cargo build` into its own
/// target directory (`cargo test` builds the library as an rlib only, and the outer build's
/// directory is locked while the tests run).
fn static_lib() -> PathBuf {
    static BUILT: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    BUILT
        .get_or_init(|| {
            let exe = std::env::current_exe().unwrap();
            let target = exe.parent().unwrap().parent().unwrap().join("capi-static");
            let status = Command::new(env!("CARGO"))
                .args(["build", "--release", "--locked", "-p", "pinc-capi", "--lib", "--target-dir"])
                .arg(&target)
                .current_dir(root())
                .status()
                .expect("run cargo");
            assert!(status.success(), "building libpinc_c.a failed");
            target.join("release/libpinc_c.a")
        })
        .clone()
}

/// Compiles `source` with `compiler` and runs it on the shipped controller model.
fn build_and_run(compiler: &str, source: &str, extra: &[&str]) -> String {
    let dir = tempfile_dir(source);
    let exe = dir.join("example");
    let examples = root().join("examples/c");
    let status = Command::new(compiler)
        .args(extra)
        .arg("-O2")
        .arg(examples.join(source))
        .arg(format!("-I{}", root().join("include").display()))
        .arg(format!("-I{}", examples.display()))
        .arg(static_lib())
        .args(["-lm", "-lpthread", "-ldl", "-lgcc_s", "-o"])
        .arg(&exe)
        .status()
        .unwrap_or_else(|e| panic!("{compiler}: {e}"));
    assert!(status.success(), "{compiler} {source} failed");
    let out = Command::new(&exe).arg(root().join("models/mpc_pinc.pinc")).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

fn tempfile_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pinc-capi-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The rows tagged `tag`, parsed back to exact doubles.
fn rows(out: &str, tag: &str) -> Vec<Vec<f64>> {
    out.lines()
        .filter(|l| l.split(' ').next() == Some(tag))
        .map(|l| l.split(' ').skip(2).map(|v| v.parse().unwrap()).collect())
        .collect()
}

fn line<'a>(out: &'a str, tag: &str) -> &'a str {
    out.lines().find(|l| l.starts_with(tag)).unwrap_or_else(|| panic!("no {tag} line in {out}"))
}

/// The Rust API's rollout and linearisation of the examples' case.
fn expected() -> (Vec<State>, HorizonLinearisation) {
    let model = PincModel::load(root().join("models/mpc_pinc.pinc")).unwrap();
    let p = Predictor::new(&model);
    let mut ws = p.workspace();
    let x0 = State::from([0.0, 0.0, 1.0, 0.5f64.cos(), 0.5f64.sin(), 0.3, 0.0, 0.05, 0.0]);
    let u: Vec<Input> = (0..20)
        .map(|k| {
            let k = k as f64;
            Input::new(4.0 * (0.3 * k).sin(), 0.5, 3.0 + 0.1 * k, 0.2 * (0.2 * k).cos())
        })
        .collect();
    let mut traj = vec![State::zeros(); 21];
    p.rollout(&mut ws, &x0, &u, &mut traj).unwrap();
    let mut lin = HorizonLinearisation::new(20);
    p.linearise_horizon(&mut ws, &x0, &u, &mut lin).unwrap();
    (traj, lin)
}

fn assert_bitwise(out: &str, language: &str) {
    let (traj, lin) = expected();
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let rollout = rows(out, "rollout");
    assert_eq!(rollout.len(), 21, "{language}");
    for (k, row) in rollout.iter().enumerate() {
        assert_eq!(bits(row), bits(traj[k].as_slice()), "{language} rollout step {k}");
    }
    for (k, row) in rows(out, "traj").iter().enumerate() {
        assert_eq!(bits(row), bits(lin.trajectory()[k].as_slice()), "{language} linearised trajectory {k}");
    }
    let (a, b) = (rows(out, "a"), rows(out, "b"));
    assert_eq!((a.len(), b.len()), (20, 20), "{language}");
    for k in 0..20 {
        // Row-major on the C side, column-major in nalgebra.
        let a_rows: Vec<f64> =
            (0..9).flat_map(|i| (0..9).map(move |j| (i, j))).map(|(i, j)| lin.a()[k][(i, j)]).collect();
        let b_rows: Vec<f64> =
            (0..9).flat_map(|i| (0..4).map(move |j| (i, j))).map(|(i, j)| lin.b()[k][(i, j)]).collect();
        assert_eq!(bits(&a[k]), bits(&a_rows), "{language} A_{k}");
        assert_eq!(bits(&b[k]), bits(&b_rows), "{language} B_{k}");
    }
    assert!(line(out, "nan_state").starts_with("nan_state -4 pinc_step: state[2] = NaN is not finite"), "{out}");
}

#[test]
fn the_c_example_prints_the_rust_results_to_the_last_bit() {
    let out = build_and_run("cc", "example.c", &["-std=c99"]);
    assert_bitwise(&out, "C");
    assert_eq!(line(&out, "dt"), "dt 0.080000000000000002");
    assert!(line(&out, "null_workspace").starts_with("null_workspace -1 pinc_step: workspace is null"), "{out}");
}

#[test]
fn the_cpp_wrapper_example_prints_the_rust_results_to_the_last_bit() {
    let out = build_and_run("c++", "example.cpp", &["-std=c++17"]);
    assert_bitwise(&out, "C++");
    let missing = line(&out, "missing_file");
    assert!(missing.starts_with("missing_file -2 no/such/model.pinc"), "{missing}");
}
