//! The C entry points called from Rust: every bad argument is a documented code with a
//! message (never a crash), a corrupted file is refused, a workspace of another predictor is
//! refused, results equal the Rust API's, and nothing allocates after `pinc_workspace_new`.

use pinc::model::PincModel;
use pinc_c::*;
use std::ffi::{CStr, CString};
use std::ptr::{null, null_mut};

#[path = "../../tests/common/counting_alloc.rs"]
mod counting_alloc;

use counting_alloc::allocations_during;

fn model_path() -> CString {
    CString::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../models/mpc_pinc.pinc")).unwrap()
}

fn last_error() -> String {
    // SAFETY: a NUL-terminated thread-local buffer.
    unsafe { CStr::from_ptr(pinc_last_error()) }.to_str().unwrap().to_string()
}

/// A predictor and its workspace, freed on drop.
struct Handles(*mut PincPredictor, *mut PincWorkspace);

impl Handles {
    fn load() -> Self {
        let (mut p, mut w) = (null_mut(), null_mut());
        // SAFETY: valid path and out pointers.
        unsafe {
            assert_eq!(pinc_predictor_load(model_path().as_ptr(), &mut p), PINC_OK);
            assert_eq!(pinc_workspace_new(p, &mut w), PINC_OK);
        }
        Self(p, w)
    }
}

impl Drop for Handles {
    fn drop(&mut self) {
        // SAFETY: handles from this library, freed once.
        unsafe {
            pinc_workspace_free(self.1);
            pinc_predictor_free(self.0);
        }
    }
}

const X0: [f64; 9] = [0.0, 0.0, 1.0, 1.0, 0.0, 0.2, 0.0, 0.0, 0.0];
const U: [f64; 4] = [2.0, 0.0, 5.0, 0.1];

#[test]
fn null_pointers_are_error_codes_with_messages() {
    let h = Handles::load();
    let mut out = [0.0; 9];
    let mut p = null_mut();
    // SAFETY: every non-null pointer is valid; the nulls are what is tested.
    unsafe {
        assert_eq!(pinc_predictor_load(null(), &mut p), PINC_ERR_NULL);
        assert_eq!(pinc_predictor_load(model_path().as_ptr(), null_mut()), PINC_ERR_NULL);
        assert_eq!(pinc_step(null(), h.1, X0.as_ptr(), U.as_ptr(), 0.0, out.as_mut_ptr()), PINC_ERR_NULL);
        assert_eq!(last_error(), "pinc_step: predictor is null");
        assert_eq!(pinc_step(h.0, h.1, null(), U.as_ptr(), 0.0, out.as_mut_ptr()), PINC_ERR_NULL);
        assert_eq!(last_error(), "pinc_step: x is null");
        assert_eq!(pinc_rollout(h.0, h.1, X0.as_ptr(), null(), 3, out.as_mut_ptr()), PINC_ERR_NULL);
        assert_eq!(last_error(), "pinc_rollout: u is null");
        let mut t = [0.0; 9];
        assert_eq!(
            pinc_linearise_horizon(h.0, h.1, X0.as_ptr(), U.as_ptr(), 1, t.as_mut_ptr(), null_mut(), null_mut()),
            PINC_ERR_NULL
        );
        assert_eq!(last_error(), "pinc_linearise_horizon: a is null");
        assert!(pinc_predictor_dt(null()).is_nan());
        assert_eq!(pinc_envelope_exits(null()), 0);
        pinc_predictor_free(null_mut());
        pinc_workspace_free(null_mut());
    }
}

#[test]
fn bad_files_bad_values_and_foreign_workspaces_are_refused() {
    let h = Handles::load();
    let mut out = [0.0; 9];
    let mut p = null_mut();
    let missing = CString::new("no/such/file.pinc").unwrap();
    let bytes = std::fs::read(model_path().to_str().unwrap()).unwrap();
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 2] ^= 0x10;
    // SAFETY: valid pointers and lengths throughout.
    unsafe {
        assert_eq!(pinc_predictor_load(missing.as_ptr(), &mut p), PINC_ERR_IO);
        assert!(last_error().starts_with("no/such/file.pinc"), "{}", last_error());
        assert_eq!(pinc_predictor_from_bytes(flipped.as_ptr(), flipped.len(), &mut p), PINC_ERR_MODEL);
        assert!(last_error().contains("checksum"), "{}", last_error());
        assert_eq!(pinc_predictor_from_bytes(bytes.as_ptr(), 10, &mut p), PINC_ERR_MODEL);
        assert!(p.is_null(), "nothing handed out on failure");

        let mut nan = X0;
        nan[5] = f64::NAN;
        assert_eq!(pinc_step(h.0, h.1, nan.as_ptr(), U.as_ptr(), 0.0, out.as_mut_ptr()), PINC_ERR_NON_FINITE);
        assert_eq!(last_error(), "pinc_step: state[5] = NaN is not finite (step 0)");
        assert_eq!(pinc_step(h.0, h.1, X0.as_ptr(), U.as_ptr(), f64::NAN, out.as_mut_ptr()), PINC_ERR_DT);
        let u = [U, [1.0, 0.0, f64::INFINITY, 0.0]].concat();
        let (mut t, mut a, mut b) = ([0.0; 27], [0.0; 162], [0.0; 72]);
        let rc = pinc_linearise_horizon(
            h.0,
            h.1,
            X0.as_ptr(),
            u.as_ptr(),
            2,
            t.as_mut_ptr(),
            a.as_mut_ptr(),
            b.as_mut_ptr(),
        );
        assert_eq!(rc, PINC_ERR_NON_FINITE);
        assert_eq!(last_error(), "pinc_linearise_horizon: input[2] = inf is not finite (step 1)");
        assert_eq!(
            pinc_linearise_horizon(
                h.0,
                h.1,
                X0.as_ptr(),
                u.as_ptr(),
                0,
                t.as_mut_ptr(),
                a.as_mut_ptr(),
                b.as_mut_ptr()
            ),
            PINC_ERR_LENGTH
        );
        assert_eq!(pinc_rollout(h.0, h.1, X0.as_ptr(), u.as_ptr(), usize::MAX / 2, t.as_mut_ptr()), PINC_ERR_LENGTH);

        // A predictor with one hidden layer fewer: the first one's workspace does not fit it.
        let mut small = PincModel::from_bytes(&bytes).unwrap();
        small.weights.hidden.pop();
        small.architecture.hidden_layers -= 1;
        small.architecture.layer_norm.pop();
        let small = small.to_bytes().unwrap();
        let mut q = null_mut();
        assert_eq!(pinc_predictor_from_bytes(small.as_ptr(), small.len(), &mut q), PINC_OK);
        assert_eq!(pinc_step(q, h.1, X0.as_ptr(), U.as_ptr(), 0.0, out.as_mut_ptr()), PINC_ERR_WORKSPACE);
        assert!(last_error().contains("another predictor"), "{}", last_error());
        pinc_predictor_free(q);
    }
}

#[test]
fn results_equal_the_rust_api_and_dt_defaults_to_the_model_period() {
    let h = Handles::load();
    let model = PincModel::load(model_path().to_str().unwrap()).unwrap();
    let p = pinc::runtime::Predictor::new(&model);
    let (x, u) = (pinc::State::from(X0), pinc::Input::from(U));
    let mut want = pinc::State::zeros();
    p.step_dt(&mut p.workspace(), &x, &u, 0.06, &mut want).unwrap();
    let (mut at_06, mut own, mut default) = ([0.0; 9], [0.0; 9], [0.0; 9]);
    // SAFETY: valid pointers throughout.
    unsafe {
        assert_eq!(pinc_step(h.0, h.1, X0.as_ptr(), U.as_ptr(), 0.06, at_06.as_mut_ptr()), PINC_OK);
        assert_eq!(pinc_step(h.0, h.1, X0.as_ptr(), U.as_ptr(), 0.08, own.as_mut_ptr()), PINC_OK);
        assert_eq!(pinc_step(h.0, h.1, X0.as_ptr(), U.as_ptr(), 0.0, default.as_mut_ptr()), PINC_OK);
        assert_eq!(pinc_predictor_dt(h.0), 0.08);
    }
    assert_eq!(at_06.as_slice(), want.as_slice());
    assert_eq!(own, default);
    assert_ne!(own, at_06);
}

#[test]
fn envelope_exits_count_the_steps_outside() {
    let h = Handles::load();
    // X = 50 N is outside the controller model's envelope on every step.
    let u = [[50.0, 0.0, 0.0, 0.0]; 5].concat();
    let (mut t, mut a, mut b) = ([0.0; 54], [0.0; 405], [0.0; 180]);
    // SAFETY: valid pointers and lengths.
    unsafe {
        assert_eq!(
            pinc_linearise_horizon(
                h.0,
                h.1,
                X0.as_ptr(),
                u.as_ptr(),
                5,
                t.as_mut_ptr(),
                a.as_mut_ptr(),
                b.as_mut_ptr()
            ),
            PINC_OK
        );
        assert_eq!(pinc_envelope_exits(h.1), 5);
        assert_eq!(pinc_rollout(h.0, h.1, X0.as_ptr(), U.as_ptr(), 1, t.as_mut_ptr()), PINC_OK);
        assert_eq!(pinc_envelope_exits(h.1), 0);
    }
}

#[test]
fn no_entry_point_allocates_after_the_workspace_exists() {
    let h = Handles::load();
    let n = 20;
    let u: Vec<f64> = (0..n).flat_map(|k| [1.0 + 0.1 * k as f64, 0.0, 3.0, 0.05]).collect();
    let (mut t, mut a, mut b) = (vec![0.0; 9 * (n + 1)], vec![0.0; 81 * n], vec![0.0; 36 * n]);
    let mut out = [0.0; 9];
    let mut nan = X0;
    nan[0] = f64::NAN;
    let count = allocations_during(|| {
        // SAFETY: valid pointers and lengths; the null and NaN calls test the error paths.
        unsafe {
            assert_eq!(pinc_step(h.0, h.1, X0.as_ptr(), U.as_ptr(), 0.0, out.as_mut_ptr()), PINC_OK);
            assert_eq!(pinc_rollout(h.0, h.1, X0.as_ptr(), u.as_ptr(), n, t.as_mut_ptr()), PINC_OK);
            assert_eq!(
                pinc_linearise_horizon(
                    h.0,
                    h.1,
                    X0.as_ptr(),
                    u.as_ptr(),
                    n,
                    t.as_mut_ptr(),
                    a.as_mut_ptr(),
                    b.as_mut_ptr()
                ),
                PINC_OK
            );
            assert_eq!(pinc_step(h.0, h.1, nan.as_ptr(), U.as_ptr(), 0.0, out.as_mut_ptr()), PINC_ERR_NON_FINITE);
            assert_eq!(pinc_step(h.0, null_mut(), X0.as_ptr(), U.as_ptr(), 0.0, out.as_mut_ptr()), PINC_ERR_NULL);
            std::hint::black_box((pinc_envelope_exits(h.1), pinc_predictor_dt(h.0), pinc_last_error()));
        }
    });
    assert_eq!(count, 0, "the C entry points allocated {count} times");
}

#[test]
fn heading_rescaling_is_on_by_default_can_be_turned_off_and_drift_is_counted() {
    let path = CString::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../models/mpc_pinc_thrust.pinc")).unwrap();
    let model = PincModel::load(path.to_str().unwrap()).unwrap();
    // A hard turn while surging and diving: the raw heading vector drifts off the circle.
    let x0 = [0.0, 0.0, 1.0, 1.0, 0.0, 0.3, 0.0, 0.1, 0.5];
    let inputs: Vec<pinc::Input> =
        (0..40).map(|k| pinc::Input::new(60.0, 0.0, 30.0, if k < 20 { 20.0 } else { -20.0 })).collect();
    let flat: Vec<f64> = inputs.iter().flat_map(|u| u.iter().copied()).collect();
    for on in [1, 0] {
        let rust = pinc::runtime::Predictor::new(&model).with_yaw_renormalisation(on == 1);
        let mut ws = rust.workspace();
        let mut want = vec![pinc::State::zeros(); 41];
        rust.rollout(&mut ws, &pinc::State::from(x0), &inputs, &mut want).unwrap();
        let (mut p, mut w) = (null_mut(), null_mut());
        let mut got = vec![0.0; 41 * 9];
        // SAFETY: valid pointers and lengths.
        unsafe {
            assert_eq!(pinc_predictor_load(path.as_ptr(), &mut p), PINC_OK);
            if on == 0 {
                assert_eq!(pinc_predictor_set_yaw_renormalisation(p, 0), PINC_OK);
            }
            assert_eq!(pinc_workspace_new(p, &mut w), PINC_OK);
            assert_eq!(pinc_rollout(p, w, x0.as_ptr(), flat.as_ptr(), 40, got.as_mut_ptr()), PINC_OK);
            let count = ws.envelope_status().heading_off_circle;
            assert!(on == 1 || count > 0, "the bare network drifts in this case");
            assert_eq!(pinc_heading_off_circle(w), i32::try_from(count).unwrap());
            pinc_workspace_free(w);
            pinc_predictor_free(p);
        }
        let want: Vec<f64> = want.iter().flat_map(|x| x.iter().copied()).collect();
        assert_eq!(got, want, "renormalisation {on}");
        let last = &got[40 * 9..];
        assert_eq!((last[3].hypot(last[4]) - 1.0).abs() < 1e-12, on == 1);
    }
    // SAFETY: a null predictor is an error code, not a crash.
    assert_eq!(unsafe { pinc_predictor_set_yaw_renormalisation(null_mut(), 1) }, PINC_ERR_NULL);
    assert_eq!(last_error(), "pinc_predictor_set_yaw_renormalisation: p is null");
}

#[test]
fn a_hybrid_model_runs_through_the_same_entry_points() {
    // The shipped controller network as the correction of a heavier, more damped vehicle.
    let mut model = PincModel::load(model_path().to_str().unwrap()).unwrap();
    model.vehicle = model.vehicle.with_damping_scaled(1.2);
    model.vehicle.m = 12.5;
    model.hybrid = Some(pinc::model::HybridPhysics { substeps: 16, rest_anchored: false });
    let bytes = model.to_bytes().unwrap();
    let p = pinc::runtime::Predictor::new(&model);
    let n = 6;
    let u: Vec<pinc::Input> = (0..n).map(|k| pinc::Input::new(2.0 + 0.5 * k as f64, 0.3, 4.0, 0.1)).collect();
    let mut lin = pinc::runtime::HorizonLinearisation::new(n);
    p.linearise_horizon(&mut p.workspace(), &pinc::State::from(X0), &u, &mut lin).unwrap();
    let flat: Vec<f64> = u.iter().flat_map(|u| u.iter().copied()).collect();
    let (mut t, mut a, mut b) = (vec![0.0; 9 * (n + 1)], vec![0.0; 81 * n], vec![0.0; 36 * n]);
    let (mut q, mut w) = (null_mut(), null_mut());
    // SAFETY: valid pointers and lengths; the handles are freed below.
    unsafe {
        assert_eq!(pinc_predictor_from_bytes(bytes.as_ptr(), bytes.len(), &mut q), PINC_OK);
        assert_eq!(pinc_predictor_is_hybrid(q), 1);
        assert_eq!(pinc_predictor_is_hybrid(Handles::load().0), 0);
        assert_eq!(pinc_predictor_is_hybrid(null()), -1);
        assert_eq!(pinc_workspace_new(q, &mut w), PINC_OK);
        let rc =
            pinc_linearise_horizon(q, w, X0.as_ptr(), flat.as_ptr(), n, t.as_mut_ptr(), a.as_mut_ptr(), b.as_mut_ptr());
        assert_eq!(rc, PINC_OK, "{}", last_error());
        pinc_workspace_free(w);
        pinc_predictor_free(q);
    }
    for k in 0..=n {
        assert_eq!(&t[9 * k..9 * (k + 1)], lin.trajectory()[k].as_slice(), "state {k}");
    }
    // Row-major A_k and B_k, as pinc.h documents.
    for k in 0..n {
        for r in 0..9 {
            for c in 0..9 {
                assert_eq!(a[81 * k + 9 * r + c], lin.a()[k][(r, c)]);
            }
            for c in 0..4 {
                assert_eq!(b[36 * k + 4 * r + c], lin.b()[k][(r, c)]);
            }
        }
    }
}
