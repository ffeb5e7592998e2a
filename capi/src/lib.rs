//! The C ABI of the pinc predictor (`include/pinc.h`).
//!
//! A `PincPredictor` is immutable and may be shared between threads; each thread calls it
//! with its own `PincWorkspace`. Every function that can fail returns `PINC_OK` (0) or a
//! negative `PINC_ERR_*` code and leaves a message for `pinc_last_error`; none panics across
//! the boundary (a panic inside is caught and returned as `PINC_ERR_INTERNAL`), and none
//! allocates after `pinc_workspace_new`.
//!
//! States are the network form `[x, y, z, cos psi, sin psi, u, v, w, r]`, inputs
//! `[X, Y, Z, Mz]`, matrices row-major.

use pinc::model::{ModelError, PincModel};
use pinc::runtime::{Predictor, RuntimeError, Workspace};
use pinc::{Input, InputMatrix, NU, NX, State, StateMatrix};
use std::cell::RefCell;
use std::ffi::{CStr, c_char, c_int};
use std::io::Write;
use std::panic::{AssertUnwindSafe, catch_unwind};

/// Success.
pub const PINC_OK: c_int = 0;
/// A required pointer argument was null.
pub const PINC_ERR_NULL: c_int = -1;
/// The model file could not be read (missing, unreadable, path not UTF-8).
pub const PINC_ERR_IO: c_int = -2;
/// The bytes are not a valid `.pinc` model (corrupt, truncated, unsupported version).
pub const PINC_ERR_MODEL: c_int = -3;
/// A state or input component is NaN or infinite.
pub const PINC_ERR_NON_FINITE: c_int = -4;
/// The model's prediction stopped being finite.
pub const PINC_ERR_DIVERGED: c_int = -5;
/// A length is unusable (zero where at least one is needed, or one whose buffer size
/// overflows).
pub const PINC_ERR_LENGTH: c_int = -6;
/// The workspace was made for another predictor.
pub const PINC_ERR_WORKSPACE: c_int = -7;
/// The time step is not a finite number.
pub const PINC_ERR_DT: c_int = -8;
/// A bug inside pinc (a caught panic); the message says where.
pub const PINC_ERR_INTERNAL: c_int = -9;

/// The frozen model, ready to run. Opaque; immutable; shareable between threads.
pub struct PincPredictor {
    predictor: Predictor,
}

/// Scratch memory for one thread's calls. Opaque.
pub struct PincWorkspace {
    ws: Workspace,
    /// Envelope exits of the last call (steps with a state or input outside the training
    /// envelope).
    exits: usize,
    /// Predictions of the last call whose heading vector was off the unit circle by more
    /// than 1 % before rescaling.
    heading_off_circle: usize,
}

/// Length of the message buffer; longer messages are cut at a character boundary.
const MESSAGE_BYTES: usize = 512;

thread_local! {
    /// The last failure's message on this thread, NUL-terminated; written without
    /// allocating.
    static LAST_ERROR: RefCell<[u8; MESSAGE_BYTES]> = const { RefCell::new([0; MESSAGE_BYTES]) };
}

/// Records `message` as this thread's last error and returns `code`.
fn fail(code: c_int, message: std::fmt::Arguments) -> c_int {
    LAST_ERROR.with_borrow_mut(|buf| {
        let mut cursor = &mut buf[..MESSAGE_BYTES - 1];
        // A message longer than the buffer is cut; the write error that says so is expected.
        let _ = cursor.write_fmt(message);
        let written = MESSAGE_BYTES - 1 - cursor.len();
        // Cut back to a whole UTF-8 character.
        let valid = std::str::from_utf8(&buf[..written]).map_or_else(|e| e.valid_up_to(), |s| s.len());
        buf[valid] = 0;
    });
    code
}

/// Runs an entry point's body: `PINC_OK`, its error code, or `PINC_ERR_INTERNAL` for a
/// panic.
fn guarded(name: &str, f: impl FnOnce() -> Result<(), c_int>) -> c_int {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => PINC_OK,
        Ok(Err(code)) => code,
        Err(_) => fail(PINC_ERR_INTERNAL, format_args!("{name}: internal error (panic)")),
    }
}

/// The code and message of a runtime error.
fn runtime_error(name: &str, e: RuntimeError) -> c_int {
    let code = match e {
        RuntimeError::NonFiniteState { .. } | RuntimeError::NonFiniteInput { .. } => PINC_ERR_NON_FINITE,
        RuntimeError::NonFiniteOutput { .. } | RuntimeError::BatchDiverged { .. } => PINC_ERR_DIVERGED,
        RuntimeError::BadTimeStep(_) => PINC_ERR_DT,
        RuntimeError::WorkspaceMismatch { .. } => PINC_ERR_WORKSPACE,
        RuntimeError::LengthMismatch { .. } | RuntimeError::HorizonMismatch { .. } => PINC_ERR_LENGTH,
    };
    fail(code, format_args!("{name}: {e}"))
}

fn model_error(what: &str, e: ModelError) -> c_int {
    let code = if matches!(e, ModelError::Io { .. }) { PINC_ERR_IO } else { PINC_ERR_MODEL };
    fail(code, format_args!("{what}: {e}"))
}

/// `n` elements of `width` doubles at `ptr` as a slice, or the error code.
///
/// # Safety
/// Unless null, `ptr` must point to `n * width` readable doubles.
unsafe fn doubles<'a>(name: &str, arg: &str, ptr: *const f64, n: usize, width: usize) -> Result<&'a [f64], i32> {
    let Some(len) = n.checked_mul(width).filter(|&l| l <= isize::MAX as usize / 8) else {
        return Err(fail(PINC_ERR_LENGTH, format_args!("{name}: {arg}: {n} x {width} doubles overflow")));
    };
    if len == 0 {
        return Ok(&[]);
    }
    if ptr.is_null() {
        return Err(fail(PINC_ERR_NULL, format_args!("{name}: {arg} is null")));
    }
    // SAFETY: non-null, and the caller promises `len` readable doubles.
    Ok(unsafe { std::slice::from_raw_parts(ptr, len) })
}

/// As [`doubles`], writable.
///
/// # Safety
/// Unless null, `ptr` must point to `n * width` writable doubles that nothing else reads or
/// writes during the call.
unsafe fn doubles_mut<'a>(name: &str, arg: &str, ptr: *mut f64, n: usize, width: usize) -> Result<&'a mut [f64], i32> {
    // SAFETY: the caller's promise covers the shared view, which is dropped right away.
    let len = unsafe { doubles(name, arg, ptr, n, width) }?.len();
    if len == 0 {
        return Ok(&mut []);
    }
    // SAFETY: non-null (checked above), `len` writable doubles, not aliased (caller).
    Ok(unsafe { std::slice::from_raw_parts_mut(ptr, len) })
}

// `State` and `Input` are nalgebra column vectors: `#[repr(C)]` over one array of doubles,
// so a run of C doubles is a run of them.
const _: () = assert!(size_of::<State>() == NX * 8 && align_of::<State>() == 8);
const _: () = assert!(size_of::<Input>() == NU * 8 && align_of::<Input>() == 8);

fn as_states(v: &[f64]) -> &[State] {
    // SAFETY: `State` is `NX` doubles with the alignment of one (asserted above), and the
    // callers pass whole multiples of `NX`.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), v.len() / NX) }
}

fn as_states_mut(v: &mut [f64]) -> &mut [State] {
    // SAFETY: as in `as_states`.
    unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr().cast(), v.len() / NX) }
}

fn as_inputs(v: &[f64]) -> &[Input] {
    // SAFETY: `Input` is `NU` doubles with the alignment of one (asserted above).
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), v.len() / NU) }
}

/// The predictor and workspace behind the handles, or the error code.
///
/// # Safety
/// Non-null handles must come from this library and not be freed.
unsafe fn handles<'a>(
    name: &str,
    p: *const PincPredictor,
    w: *mut PincWorkspace,
) -> Result<(&'a Predictor, &'a mut PincWorkspace), i32> {
    if p.is_null() || w.is_null() {
        let which = if p.is_null() { "predictor" } else { "workspace" };
        return Err(fail(PINC_ERR_NULL, format_args!("{name}: {which} is null")));
    }
    // SAFETY: non-null handles from `pinc_predictor_*` and `pinc_workspace_new` (caller).
    Ok(unsafe { (&(*p).predictor, &mut *w) })
}

fn finish_predictor(model: PincModel, out: *mut *mut PincPredictor) {
    let predictor = Box::new(PincPredictor { predictor: Predictor::new(&model) });
    // SAFETY: `out` was checked non-null by the caller of this function.
    unsafe { *out = Box::into_raw(predictor) };
}

/// Loads and validates the `.pinc` file at `path` (UTF-8, NUL-terminated) into `*out`.
/// Free it with `pinc_predictor_free`.
///
/// # Safety
/// `path` must be NUL-terminated; `out` must be writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_predictor_load(path: *const c_char, out: *mut *mut PincPredictor) -> c_int {
    guarded("pinc_predictor_load", || {
        if path.is_null() || out.is_null() {
            return Err(fail(PINC_ERR_NULL, format_args!("pinc_predictor_load: path or out is null")));
        }
        // SAFETY: non-null and NUL-terminated (caller).
        let Ok(path) = unsafe { CStr::from_ptr(path) }.to_str() else {
            return Err(fail(PINC_ERR_IO, format_args!("pinc_predictor_load: path is not UTF-8")));
        };
        finish_predictor(PincModel::load(path).map_err(|e| model_error(path, e))?, out);
        Ok(())
    })
}

/// Validates the `.pinc` file held in `bytes[0..len]` into `*out`.
///
/// # Safety
/// `bytes` must point to `len` readable bytes; `out` must be writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_predictor_from_bytes(
    bytes: *const u8,
    len: usize,
    out: *mut *mut PincPredictor,
) -> c_int {
    const NAME: &str = "pinc_predictor_from_bytes";
    guarded(NAME, || {
        if bytes.is_null() || out.is_null() {
            return Err(fail(PINC_ERR_NULL, format_args!("{NAME}: bytes or out is null")));
        }
        // SAFETY: non-null, `len` readable bytes (caller).
        let bytes = unsafe { std::slice::from_raw_parts(bytes, len) };
        finish_predictor(PincModel::from_bytes(bytes).map_err(|e| model_error(NAME, e))?, out);
        Ok(())
    })
}

/// Frees a predictor (null is ignored). Its workspaces must not be used with another one.
///
/// # Safety
/// `p` must come from `pinc_predictor_load` or `pinc_predictor_from_bytes`, freed once.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_predictor_free(p: *mut PincPredictor) {
    if !p.is_null() {
        // SAFETY: from `Box::into_raw` in this library, not yet freed (caller).
        drop(unsafe { Box::from_raw(p) });
    }
}

/// A workspace for calls into `p`, into `*out`: the last allocation the calls need.
///
/// # Safety
/// `p` must be a live predictor; `out` must be writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_workspace_new(p: *const PincPredictor, out: *mut *mut PincWorkspace) -> c_int {
    guarded("pinc_workspace_new", || {
        if p.is_null() || out.is_null() {
            return Err(fail(PINC_ERR_NULL, format_args!("pinc_workspace_new: predictor or out is null")));
        }
        // SAFETY: a live predictor (caller).
        let predictor = unsafe { &(*p).predictor };
        let w = Box::new(PincWorkspace { ws: predictor.workspace(), exits: 0, heading_off_circle: 0 });
        // SAFETY: non-null (checked).
        unsafe { *out = Box::into_raw(w) };
        Ok(())
    })
}

/// Frees a workspace (null is ignored).
///
/// # Safety
/// `w` must come from `pinc_workspace_new`, freed once.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_workspace_free(w: *mut PincWorkspace) {
    if !w.is_null() {
        // SAFETY: from `Box::into_raw` in this library, not yet freed (caller).
        drop(unsafe { Box::from_raw(w) });
    }
}

/// The model's sample period (s); NaN for a null predictor.
///
/// # Safety
/// `p` must be null or a live predictor.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_predictor_dt(p: *const PincPredictor) -> f64 {
    // SAFETY: null or live (caller).
    unsafe { p.as_ref() }.map_or(f64::NAN, |p| p.predictor.dt())
}

/// 1 when the model is a hybrid (its vehicle's RK4 step plus the network's correction), 0
/// when it is a PINC, -1 for a null predictor. Every call serves both kinds alike.
///
/// # Safety
/// `p` must be null or a live predictor.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_predictor_is_hybrid(p: *const PincPredictor) -> c_int {
    // SAFETY: null or live (caller).
    unsafe { p.as_ref() }.map_or(-1, |p| c_int::from(p.predictor.is_hybrid()))
}

/// One step from `x` under `u` over `dt` seconds (`dt <= 0`: the model's sample period)
/// into `out`.
///
/// # Safety
/// `x`: 9 readable doubles, `u`: 4, `out`: 9 writable; live handles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_step(
    p: *const PincPredictor,
    w: *mut PincWorkspace,
    x: *const f64,
    u: *const f64,
    dt: f64,
    out: *mut f64,
) -> c_int {
    const NAME: &str = "pinc_step";
    guarded(NAME, || {
        // SAFETY: the pointer contracts above (caller).
        let ((predictor, w), x, u, out) = unsafe {
            (
                handles(NAME, p, w)?,
                doubles(NAME, "x", x, 1, NX)?,
                doubles(NAME, "u", u, 1, NU)?,
                doubles_mut(NAME, "out", out, 1, NX)?,
            )
        };
        if dt.is_nan() {
            return Err(fail(PINC_ERR_DT, format_args!("{NAME}: dt is NaN")));
        }
        let dt = if dt <= 0.0 { predictor.dt() } else { dt };
        let next = &mut as_states_mut(out)[0];
        let result = predictor.step_dt(&mut w.ws, &as_states(x)[0], &as_inputs(u)[0], dt, next);
        w.exits = w.ws.envelope_status().exits;
        w.heading_off_circle = w.ws.envelope_status().heading_off_circle;
        result.map_err(|e| runtime_error(NAME, e))
    })
}

/// The arguments every horizon call shares, checked.
struct Horizon<'a> {
    predictor: &'a Predictor,
    w: &'a mut PincWorkspace,
    x0: State,
    inputs: &'a [Input],
    /// `n + 1` states.
    traj: &'a mut [State],
}

/// The handles, `x0` (9 doubles), `u` (`n` rows of 4) and `traj` (`n + 1` rows of 9),
/// checked, or the error code.
///
/// # Safety
/// As for the callers' pointer arguments.
unsafe fn horizon<'a>(
    name: &str,
    p: *const PincPredictor,
    w: *mut PincWorkspace,
    x0: *const f64,
    u: *const f64,
    n: usize,
    traj: *mut f64,
) -> Result<Horizon<'a>, c_int> {
    // SAFETY: the caller's pointer contracts.
    unsafe {
        let (predictor, w) = handles(name, p, w)?;
        let x0 = as_states(doubles(name, "x0", x0, 1, NX)?)[0];
        let inputs = as_inputs(doubles(name, "u", u, n, NU)?);
        let traj = as_states_mut(doubles_mut(name, "traj", traj, n.saturating_add(1), NX)?);
        Ok(Horizon { predictor, w, x0, inputs, traj })
    }
}

/// Rolls out `n` steps from `x0` under `u` (`n` rows of 4) into `traj` (`n + 1` rows of 9,
/// the first `x0`), at the model's sample period.
///
/// # Safety
/// `x0`: 9 readable doubles, `u`: `4 n`, `traj`: `9 (n + 1)` writable; live handles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_rollout(
    p: *const PincPredictor,
    w: *mut PincWorkspace,
    x0: *const f64,
    u: *const f64,
    n: usize,
    traj: *mut f64,
) -> c_int {
    const NAME: &str = "pinc_rollout";
    guarded(NAME, || {
        // SAFETY: the pointer contracts above (caller).
        let h = unsafe { horizon(NAME, p, w, x0, u, n, traj) }?;
        let result = h.predictor.rollout(&mut h.w.ws, &h.x0, h.inputs, h.traj);
        h.w.exits = h.w.ws.envelope_status().exits;
        h.w.heading_off_circle = h.w.ws.envelope_status().heading_off_circle;
        result.map_err(|e| runtime_error(NAME, e))
    })
}

/// Rolls out `n >= 1` steps from `x0` under `u` into `traj` (as `pinc_rollout`) and writes
/// the exact Jacobians of every step: `a` gets `n` row-major 9 x 9 matrices
/// `d x_{k+1} / d x_k`, `b` `n` row-major 9 x 4 matrices `d x_{k+1} / d u_k`.
///
/// # Safety
/// `x0`: 9 readable doubles, `u`: `4 n`, `traj`: `9 (n + 1)`, `a`: `81 n`, `b`: `36 n`
/// writable; live handles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_linearise_horizon(
    p: *const PincPredictor,
    w: *mut PincWorkspace,
    x0: *const f64,
    u: *const f64,
    n: usize,
    traj: *mut f64,
    a: *mut f64,
    b: *mut f64,
) -> c_int {
    const NAME: &str = "pinc_linearise_horizon";
    guarded(NAME, || {
        if n == 0 {
            return Err(fail(PINC_ERR_LENGTH, format_args!("{NAME}: n = 0 (a horizon has at least one step)")));
        }
        // SAFETY: the pointer contracts above (caller).
        let (Horizon { predictor, w, x0, inputs, traj }, a, b) = unsafe {
            (
                horizon(NAME, p, w, x0, u, n, traj)?,
                doubles_mut(NAME, "a", a, n, NX * NX)?,
                doubles_mut(NAME, "b", b, n, NX * NU)?,
            )
        };
        traj[0] = x0;
        w.exits = 0;
        w.heading_off_circle = 0;
        // Step by step, so that the Jacobians go straight into the caller's row-major
        // buffers: the same arithmetic as `Predictor::linearise_horizon`.
        let (mut ak, mut bk) = (StateMatrix::zeros(), InputMatrix::zeros());
        for k in 0..n {
            let x = traj[k];
            let result = predictor.linearise(&mut w.ws, &x, &inputs[k], &mut traj[k + 1], &mut ak, &mut bk);
            w.exits += w.ws.envelope_status().exits;
            w.heading_off_circle += w.ws.envelope_status().heading_off_circle;
            result.map_err(|e| runtime_error(NAME, shift_step(e, k)))?;
            for i in 0..NX {
                for j in 0..NX {
                    a[k * NX * NX + i * NX + j] = ak[(i, j)];
                }
                for j in 0..NU {
                    b[k * NX * NU + i * NU + j] = bk[(i, j)];
                }
            }
        }
        Ok(())
    })
}

/// A one-step call's error as step `k` of the horizon.
fn shift_step(e: RuntimeError, k: usize) -> RuntimeError {
    match e {
        RuntimeError::NonFiniteState { index, value, .. } => RuntimeError::NonFiniteState { step: k, index, value },
        RuntimeError::NonFiniteInput { index, value, .. } => RuntimeError::NonFiniteInput { step: k, index, value },
        RuntimeError::NonFiniteOutput { .. } => RuntimeError::NonFiniteOutput { step: k },
        other => other,
    }
}

/// Steps of the last call on `w` at which a state or input was outside the training
/// envelope (0 for a null workspace).
///
/// # Safety
/// `w` must be null or a live workspace.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_envelope_exits(w: *const PincWorkspace) -> c_int {
    // SAFETY: null or live (caller).
    unsafe { w.as_ref() }.map_or(0, |w| i32::try_from(w.exits).unwrap_or(i32::MAX))
}

/// Predictions of the last call on `w` whose `(cos psi, sin psi)` was off unit length by
/// more than 1 % before the runtime rescaled it (0 for a null workspace): a warning of its
/// own, apart from envelope exits.
///
/// # Safety
/// `w` must be null or a live workspace.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_heading_off_circle(w: *const PincWorkspace) -> c_int {
    // SAFETY: null or live (caller).
    unsafe { w.as_ref() }.map_or(0, |w| i32::try_from(w.heading_off_circle).unwrap_or(i32::MAX))
}

/// Whether `p` rescales each predicted `(cos psi, sin psi)` to unit length (`on` non-zero,
/// the default) or returns the bare network's output (`on` zero: what PyTorch computes, to
/// reproduce the paper). Set it before `p` is shared between threads.
///
/// # Safety
/// `p` must be null or a live predictor not in use by another thread.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinc_predictor_set_yaw_renormalisation(p: *mut PincPredictor, on: c_int) -> c_int {
    // SAFETY: null or live and not shared at this moment (caller).
    let Some(p) = (unsafe { p.as_mut() }) else {
        return fail(PINC_ERR_NULL, format_args!("pinc_predictor_set_yaw_renormalisation: p is null"));
    };
    p.predictor = p.predictor.clone().with_yaw_renormalisation(on != 0);
    PINC_OK
}

/// The message of this thread's last failure (empty if none); valid until the next failing
/// call on this thread.
#[unsafe(no_mangle)]
pub extern "C" fn pinc_last_error() -> *const c_char {
    LAST_ERROR.with_borrow(|buf| buf.as_ptr().cast())
}
