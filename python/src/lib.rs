//! `pinc._pinc`: the predictor and the analytic vehicle for Python, on numpy arrays.
//!
//! Every array argument accepts any array-like convertible to float64; shapes and
//! finiteness are checked here and a failure is a `ValueError` naming the argument. Model
//! files that cannot be loaded and predictions that stop being finite raise `PincError`
//! (a `ValueError`).

use numpy::ndarray::{Array1, Array2, Array3, ArrayViewD, Dimension};
use numpy::npyffi::{NPY_ARRAY_WRITEABLE, NPY_TYPES};
use numpy::{
    AllowTypeChange, IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayDescrMethods, PyArrayLikeDyn, PyArrayMethods,
    PyUntypedArray, PyUntypedArrayMethods,
};
use pinc::closed_loop::campaign::{Campaign, Controller, Settings, histogram, table};
use pinc::closed_loop::monte_carlo::{Outcome, robustness};
use pinc::model::PincModel;
use pinc::runtime::{BatchWorkspace, HorizonLinearisation, Predictor as RustPredictor, Workspace};
use pinc::vehicle::{Rk4Vehicle, VehicleParams};
use pinc::{INPUT_NAMES, Input, NS, NU, NX, STATE_NAMES, SimState, State};
use pyo3::create_exception;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use std::ffi::c_int;
use std::sync::Mutex;

create_exception!(
    _pinc,
    PincError,
    PyValueError,
    "A model file pinc cannot use, or a prediction that stopped being finite."
);

type Array<'py> = PyArrayLikeDyn<'py, f64, AllowTypeChange>;

/// `arg` as a view of `shape` (`None`: any length on that axis), all finite.
fn checked<'a>(arg: &str, a: &'a Array<'_>, shape: &[Option<usize>]) -> PyResult<ArrayViewD<'a, f64>> {
    let v = a.as_array();
    let fits = v.ndim() == shape.len() && v.shape().iter().zip(shape).all(|(&n, s)| s.is_none_or(|s| s == n));
    if !fits {
        let want: Vec<String> = shape.iter().map(|s| s.map_or("N".to_string(), |n| n.to_string())).collect();
        return Err(PyValueError::new_err(format!("{arg}: expected shape ({}), got {:?}", want.join(", "), v.shape())));
    }
    // Scan plainly first (indexing a dynamic-rank array is slow); find the index on failure.
    let all_finite = match v.as_slice() {
        Some(flat) => flat.iter().all(|x| x.is_finite()),
        None => v.iter().all(|x| x.is_finite()),
    };
    if !all_finite && let Some((i, x)) = v.indexed_iter().find(|(_, x)| !x.is_finite()) {
        return Err(PyValueError::new_err(format!("{arg}{:?} = {x} is not finite", i.slice())));
    }
    Ok(v)
}

/// A contiguous 1-D argument of `N` finite values (`N` from the expected length).
fn vector<'a, const N: usize>(arg: &str, v: &'a [f64]) -> PyResult<&'a [f64]> {
    if v.len() != N {
        return Err(PyValueError::new_err(format!("{arg}: expected shape ({N}), got ({})", v.len())));
    }
    if let Some((i, x)) = v.iter().enumerate().find(|(_, x)| !x.is_finite()) {
        return Err(PyValueError::new_err(format!("{arg}[{i}] = {x} is not finite")));
    }
    Ok(v)
}

/// `obj` as a 1-D numpy array of native-order float64, checked by the descriptor's type number
/// and byte order: extracting a `PyArray1<f64>` builds a float64 descriptor and asks numpy
/// whether the two are equivalent, a tenth of a `step_into` call here.
fn float64_vector<'a, 'py>(arg: &str, obj: &'a Bound<'py, PyAny>) -> PyResult<&'a Bound<'py, PyArray1<f64>>> {
    let refused = || PyTypeError::new_err(format!("{arg}: expected a 1-D numpy array of float64"));
    let a = obj.cast::<PyUntypedArray>().map_err(|_| refused())?;
    let d = a.dtype();
    if a.ndim() != 1 || d.num() != NPY_TYPES::NPY_DOUBLE as c_int || d.is_native_byteorder() != Some(true) {
        return Err(refused());
    }
    // SAFETY: a 1-D array whose elements are native float64, checked above.
    Ok(unsafe { a.cast_unchecked::<PyArray1<f64>>() })
}

fn state(arg: &str, a: &Array<'_>) -> PyResult<State> {
    let v = checked(arg, a, &[Some(NX)])?;
    Ok(State::from_fn(|i, _| v[[i]]))
}

fn input(arg: &str, a: &Array<'_>) -> PyResult<Input> {
    let v = checked(arg, a, &[Some(NU)])?;
    Ok(Input::from_fn(|i, _| v[[i]]))
}

fn inputs(arg: &str, a: &Array<'_>) -> PyResult<Vec<Input>> {
    let v = checked(arg, a, &[None, Some(NU)])?;
    Ok((0..v.shape()[0]).map(|k| Input::from_fn(|i, _| v[[k, i]])).collect())
}

fn runtime_err(e: impl std::fmt::Display) -> PyErr {
    PincError::new_err(e.to_string())
}

fn trajectory<'py>(py: Python<'py>, traj: &[State]) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((traj.len(), NX), |(k, i)| traj[k][i]).into_pyarray(py)
}

/// A frozen PINC model: `Predictor(path)`.
#[pyclass(frozen, module = "pinc")]
struct Predictor {
    inner: RustPredictor,
    /// One workspace; calls from several Python threads take turns.
    ws: Mutex<Workspace>,
}

#[pymethods]
impl Predictor {
    /// `renormalise_yaw=False` returns the bare network's `(cos psi, sin psi)` (what PyTorch
    /// computes); by default each prediction's heading vector is rescaled to unit length.
    #[new]
    #[pyo3(signature = (path, renormalise_yaw = true))]
    fn new(path: std::path::PathBuf, renormalise_yaw: bool) -> PyResult<Self> {
        let model = PincModel::load(&path).map_err(|e| PincError::new_err(format!("{}: {e}", path.display())))?;
        let inner = RustPredictor::new(&model).with_yaw_renormalisation(renormalise_yaw);
        let ws = Mutex::new(inner.workspace());
        Ok(Self { inner, ws })
    }

    /// The sample period the model was trained for (s).
    #[getter]
    fn dt(&self) -> f64 {
        self.inner.dt()
    }

    /// Whether the model is a hybrid: its vehicle's RK4 step plus the network's correction
    /// (steps, rollouts and Jacobians include the physics).
    #[getter]
    fn is_hybrid(&self) -> bool {
        self.inner.is_hybrid()
    }

    /// What the last `step`, `rollout` or `linearise` saw: `{"envelope_exits": steps with a state or input outside the
    /// training envelope, "heading_off_circle": predictions whose heading vector was off unit
    /// length by more than 1 % before rescaling}`.
    #[getter]
    fn last_warnings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let status = self.ws.lock().expect("workspace lock").envelope_status();
        let d = PyDict::new(py);
        d.set_item("envelope_exits", status.exits)?;
        d.set_item("heading_off_circle", status.heading_off_circle)?;
        Ok(d)
    }

    /// The training envelope: `{component: (min, max)}` for the 9 state and 4 input
    /// components, or None for a model without one.
    #[getter]
    fn envelope<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(e) = self.inner.envelope() else { return Ok(None) };
        let d = PyDict::new(py);
        for (i, name) in STATE_NAMES.iter().enumerate() {
            d.set_item(name, (e.state_min[i], e.state_max[i]))?;
        }
        for (i, name) in INPUT_NAMES.iter().enumerate() {
            d.set_item(name, (e.input_min[i], e.input_max[i]))?;
        }
        Ok(Some(d))
    }

    /// One step: `x` (9,), `u` (4,), `dt` (s; None: the model's) -> (9,).
    #[pyo3(signature = (x, u, dt = None))]
    fn step<'py>(
        &self,
        py: Python<'py>,
        x: Array<'py>,
        u: Array<'py>,
        dt: Option<f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (x, u) = (state("x", &x)?, input("u", &u)?);
        let dt = dt.unwrap_or(self.inner.dt());
        let mut out = State::zeros();
        let mut ws = self.ws.lock().expect("workspace lock");
        self.inner.step_dt(&mut ws, &x, &u, dt, &mut out).map_err(runtime_err)?;
        Ok(Array1::from_iter(out.iter().copied()).into_pyarray(py))
    }

    /// One step into a caller's array: `x` (9,) and `u` (4,) float64 arrays, `out` a writable
    /// contiguous float64 array (9,) that receives the next state; `dt` as in `step`. Nothing
    /// is allocated and no argument is converted: the call for a controller's loop (`step`
    /// takes any array-like and returns a new array).
    #[pyo3(signature = (x, u, out, dt = None))]
    fn step_into(
        &self,
        x: &Bound<'_, PyAny>,
        u: &Bound<'_, PyAny>,
        out: &Bound<'_, PyAny>,
        dt: Option<f64>,
    ) -> PyResult<()> {
        let (x, u, out) = (float64_vector("x", x)?, float64_vector("u", u)?, float64_vector("out", out)?);
        // The arrays are read and written without numpy's borrow tracking, which cost about as
        // much as the step itself here (three borrows, each a lookup and a release). SAFETY:
        // the GIL is held throughout and no Python code runs while a slice lives, and each
        // slice ends before the next begins, so nothing else reads or writes the data
        // meanwhile (`out` may even be `x`).
        let x = State::from_column_slice(vector::<NX>("x", unsafe { x.as_slice() }?)?);
        let u = Input::from_column_slice(vector::<NU>("u", unsafe { u.as_slice() }?)?);
        // SAFETY: a field read of the array object the GIL keeps alive.
        if unsafe { (*out.as_array_ptr()).flags } & NPY_ARRAY_WRITEABLE == 0 {
            return Err(PyValueError::new_err("out: the array is read-only"));
        }
        if out.len() != NX {
            return Err(PyValueError::new_err(format!("out: expected shape ({NX}), got ({})", out.len())));
        }
        let mut next = State::zeros();
        let mut ws = self.ws.lock().expect("workspace lock");
        self.inner.step_dt(&mut ws, &x, &u, dt.unwrap_or(self.inner.dt()), &mut next).map_err(runtime_err)?;
        // SAFETY: as above; the slice is the only reference to `out`'s data while it lives.
        unsafe { out.as_slice_mut() }?.copy_from_slice(next.as_slice());
        Ok(())
    }

    /// Rollout: `x0` (9,), `U` (N, 4) -> (N + 1, 9), the first row `x0`.
    #[allow(non_snake_case)]
    fn rollout<'py>(&self, py: Python<'py>, x0: Array<'py>, U: Array<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (x0, u) = (state("x0", &x0)?, inputs("U", &U)?);
        let mut traj = vec![State::zeros(); u.len() + 1];
        let mut ws = self.ws.lock().expect("workspace lock");
        self.inner.rollout(&mut ws, &x0, &u, &mut traj).map_err(runtime_err)?;
        Ok(trajectory(py, &traj))
    }

    /// Rollout and exact Jacobians: `x0` (9,), `U` (N, 4) -> `(X, A, B)` with shapes
    /// (N + 1, 9), (N, 9, 9), (N, 9, 4); `A[k] = dX[k+1]/dX[k]`, `B[k] = dX[k+1]/dU[k]`.
    #[allow(non_snake_case)]
    fn linearise<'py>(&self, py: Python<'py>, x0: Array<'py>, U: Array<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let (x0, u) = (state("x0", &x0)?, inputs("U", &U)?);
        if u.is_empty() {
            return Err(PyValueError::new_err("U: a horizon has at least one step"));
        }
        let mut lin = HorizonLinearisation::new(u.len());
        let mut ws = self.ws.lock().expect("workspace lock");
        self.inner.linearise_horizon(&mut ws, &x0, &u, &mut lin).map_err(runtime_err)?;
        let n = u.len();
        let a = Array3::from_shape_fn((n, NX, NX), |(k, i, j)| lin.a()[k][(i, j)]);
        let b = Array3::from_shape_fn((n, NX, NU), |(k, i, j)| lin.b()[k][(i, j)]);
        (trajectory(py, lin.trajectory()), a.into_pyarray(py), b.into_pyarray(py)).into_pyobject(py)
    }

    /// Batch rollout: `X0` (B, 9), `Ub` (B, N, 4) -> (B, N + 1, 9). Releases the GIL.
    #[allow(non_snake_case)]
    fn rollout_batch<'py>(
        &self,
        py: Python<'py>,
        X0: Array<'py>,
        Ub: Array<'py>,
    ) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let x0v = checked("X0", &X0, &[None, Some(NX)])?;
        let batch = x0v.shape()[0];
        let uv = checked("Ub", &Ub, &[Some(batch), None, Some(NU)])?;
        let n = uv.shape()[1];
        let x0: Vec<State> = (0..batch).map(|b| State::from_fn(|i, _| x0v[[b, i]])).collect();
        // C-contiguous input (the usual case) is read as one run of rows.
        let u: Vec<Input> = match uv.as_slice() {
            Some(flat) => flat.chunks_exact(NU).map(Input::from_column_slice).collect(),
            None => (0..batch)
                .flat_map(|b| (0..n).map(move |k| (b, k)))
                .map(|(b, k)| Input::from_fn(|i, _| uv[[b, k, i]]))
                .collect(),
        };
        let p = &self.inner;
        let out = py.detach(|| {
            let mut ws = BatchWorkspace::new(p);
            let mut out = vec![State::zeros(); batch * (n + 1)];
            p.rollout_batch(&mut ws, &x0, &u, &mut out).map(|()| out)
        });
        let flat: Vec<f64> = out.map_err(runtime_err)?.iter().flat_map(|x| x.iter().copied()).collect();
        let out = Array3::from_shape_vec((batch, n + 1, NX), flat).expect("batch * (n + 1) states of 9");
        Ok(out.into_pyarray(py))
    }

    fn __repr__(&self) -> String {
        format!("pinc.Predictor(dt={}, state_inputs={:?})", self.inner.dt(), self.inner.state_inputs())
    }
}

/// The analytic vehicle (RK4): `x0_sim` (8,) `[x, y, z, psi, u, v, w, r]`, `U` (N, 4) held
/// per sample -> (N + 1, 8). `vehicle`: a dict of `VehicleParams` overrides (e.g.
/// `{"m": 12.0}`), None for the BlueROV2.
#[pyfunction]
#[pyo3(signature = (x0_sim, U, dt = 0.08, vehicle = None))]
#[allow(non_snake_case)]
fn simulate<'py>(
    py: Python<'py>,
    x0_sim: Array<'py>,
    U: Array<'py>,
    dt: f64,
    vehicle: Option<Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let s = checked("x0_sim", &x0_sim, &[Some(NS)])?;
    let s0 = SimState::from_fn(|i, _| s[[i]]);
    let u = inputs("U", &U)?;
    if !(dt.is_finite() && dt > 0.0) {
        return Err(PyValueError::new_err(format!("dt: {dt} is not a positive number of seconds")));
    }
    let mut v = Rk4Vehicle::with_dt(dt);
    if let Some(overrides) = vehicle {
        v.params = params(&overrides)?;
    }
    let traj = v.simulate(&s0, &u);
    Ok(Array2::from_shape_fn((traj.len(), NS), |(k, i)| traj[k][i]).into_pyarray(py))
}

/// The BlueROV2's parameters with `overrides` applied (the keys of a vehicle file); an
/// unknown name, a value that is not a number or coefficients that make the model
/// meaningless are errors naming the key.
fn params(overrides: &Bound<'_, PyDict>) -> PyResult<VehicleParams> {
    let mut params = VehicleParams::default();
    for (k, v) in overrides.iter() {
        let key: String = k.extract().map_err(|_| PyValueError::new_err("vehicle: keys must be strings"))?;
        let value: f64 = v.extract().map_err(|_| PyValueError::new_err(format!("vehicle[{key:?}]: not a number")))?;
        let known: Vec<&str> = params.named().iter().map(|(k, _)| *k).collect();
        let Some(slot) = params.get_mut(&key) else {
            return Err(PyValueError::new_err(format!("vehicle: unknown parameter {key:?} (known: {known:?})")));
        };
        *slot = value;
    }
    params.validate().map_err(|e| PyValueError::new_err(format!("vehicle: {e}")))?;
    Ok(params)
}

/// The figures of each model (`.pinc` paths) and of `vehicle`'s analytic model (a vehicle
/// file) on the set `set` of the dataset folder `data` (`pinc dataset import`), from the starts
/// `start` asks for: `"recorded"`, `"estimated"` (pinc's estimator run over `start_history`
/// seconds of samples before each window, never the window itself) or `"both"`. One dict per
/// row, as `pinc eval --data --json` prints them (a model's `physics_mse` is NaN where the
/// JSON has null); the estimator's assumptions are in the `estimator` key of every row.
#[pyfunction]
#[pyo3(signature = (data, models = Vec::new(), vehicle = None, set = "test", start = "recorded",
    start_history = pinc::estimation::window_starts::DEFAULT_HISTORY_S))]
fn evaluate<'py>(
    py: Python<'py>,
    data: std::path::PathBuf,
    models: Vec<std::path::PathBuf>,
    vehicle: Option<std::path::PathBuf>,
    set: &str,
    start: &str,
    start_history: f64,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let start: pinc::eval::StartFrom = start.parse().map_err(|e| PyValueError::new_err(format!("start: {e}")))?;
    let dataset = pinc::dataset::load(&data).map_err(|e| PincError::new_err(e.to_string()))?;
    let loaded = models
        .iter()
        .map(|p| PincModel::load(p).map_err(|e| PincError::new_err(format!("{}: {e}", p.display()))))
        .collect::<PyResult<Vec<_>>>()?;
    let params =
        vehicle.as_ref().map(|p| VehicleParams::load(p).map_err(|e| PincError::new_err(e.to_string()))).transpose()?;
    let refs: Vec<&PincModel> = loaded.iter().collect();
    let evaluation = py
        .detach(|| pinc::eval::evaluate_recorded(&dataset, set, &refs, params.as_ref(), start, start_history))
        .map_err(|e| match e {
            pinc::eval::RecordedEvalError::Model { index, source } => {
                PincError::new_err(format!("{} on {}: {source}", models[index].display(), data.display()))
            }
            other => PincError::new_err(format!("{}: {other}", data.display())),
        })?;
    let mut rows = Vec::new();
    for r in &evaluation.rows {
        let d = PyDict::new(py);
        match r.evaluated {
            pinc::eval::Evaluated::Model(i) => d.set_item("model", &models[i])?,
            pinc::eval::Evaluated::Vehicle => d.set_item("vehicle", &vehicle)?,
        }
        let m = &r.metrics;
        d.set_item("start", r.start)?;
        d.set_item("one_step_mse", m.one_step_mse)?;
        d.set_item("rollout10_mse", m.rollout10_mse)?;
        d.set_item("physics_mse", m.physics_mse)?;
        d.set_item("vpt_s", m.vpt_s)?;
        d.set_item("vpt_median_s", m.vpt_median_s)?;
        d.set_item("windows", m.windows)?;
        d.set_item("data", &data)?;
        d.set_item("vpt_threshold_m", pinc::eval::VPT_THRESHOLD_M)?;
        d.set_item("estimator", &evaluation.estimator)?;
        rows.push(d);
    }
    Ok(rows)
}

#[pymodule]
fn _pinc(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Predictor>()?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_class::<ClosedLoop>()?;
    m.add_function(wrap_pyfunction!(monte_carlo_report, m)?)?;
    m.add("PincError", m.py().get_type::<PincError>())?;
    Ok(())
}

/// One controller's outcome as the Python side stores it (JSON; `null` for an infinite
/// RMS error, since JSON has no infinity).
#[derive(serde::Serialize, serde::Deserialize)]
struct OutcomeJson {
    seed: u64,
    success: bool,
    failure: Option<String>,
    rms_depth_m: Option<f64>,
    rms_heading_deg: Option<f64>,
    #[serde(default)]
    rms_horizontal_m: Option<f64>,
    #[serde(default)]
    solve_ms: Vec<f64>,
}

impl From<Outcome> for OutcomeJson {
    fn from(o: Outcome) -> Self {
        let finite = |v: f64| v.is_finite().then_some(v);
        Self {
            seed: o.seed,
            success: o.success,
            failure: o.failure,
            rms_depth_m: finite(o.rms_depth_m),
            rms_heading_deg: finite(o.rms_heading_deg),
            rms_horizontal_m: o.rms_horizontal_m.and_then(finite),
            solve_ms: o.solve_ms,
        }
    }
}

impl From<OutcomeJson> for Outcome {
    fn from(o: OutcomeJson) -> Self {
        Self {
            seed: o.seed,
            success: o.success,
            failure: o.failure,
            rms_depth_m: o.rms_depth_m.unwrap_or(f64::INFINITY),
            rms_heading_deg: o.rms_heading_deg.unwrap_or(f64::INFINITY),
            rms_horizontal_m: o.rms_horizontal_m,
            solve_ms: o.solve_ms,
        }
    }
}

fn controller(name: &str) -> PyResult<Controller> {
    match name {
        "pinc" => Ok(Controller::Pinc),
        "oracle" => Ok(Controller::Oracle),
        other => Err(PyValueError::new_err(format!("controller: `{other}` is neither pinc nor oracle"))),
    }
}

fn json_err(what: &str) -> impl Fn(serde_json::Error) -> PyErr + '_ {
    move |e| PyValueError::new_err(format!("{what}: {e}"))
}

/// A closed-loop campaign built from its settings (JSON of `mpc_track`'s flags, see
/// `pinc.closed_loop`): the library's one set-up path, shared with `mpc_track`.
#[pyclass(frozen, module = "pinc")]
struct ClosedLoop {
    inner: Campaign,
}

#[pymethods]
impl ClosedLoop {
    #[new]
    fn new(settings_json: &str) -> PyResult<Self> {
        let settings: Settings = serde_json::from_str(settings_json).map_err(json_err("settings"))?;
        let inner = Campaign::new(&settings).map_err(|e| PincError::new_err(e.to_string()))?;
        Ok(Self { inner })
    }

    /// The perturbed plant of `seed` (JSON): vehicle coefficients and current.
    fn draw(&self, seed: u64) -> PyResult<String> {
        serde_json::to_string(&self.inner.draw(seed)).map_err(json_err("draw"))
    }

    /// One Monte-Carlo run of `controller` against the plant of `seed` (JSON outcome).
    fn monte_carlo_run(&self, py: Python<'_>, seed: u64, controller_name: &str) -> PyResult<String> {
        let c = controller(controller_name)?;
        let outcome = py.detach(|| self.inner.monte_carlo_run(seed, c));
        serde_json::to_string(&OutcomeJson::from(outcome)).map_err(json_err("outcome"))
    }

    /// One unperturbed run's summary (JSON; the figures of `mpc_track --json`).
    fn nominal_run(&self, py: Python<'_>, controller_name: &str) -> PyResult<String> {
        let c = controller(controller_name)?;
        let summary = py.detach(|| self.inner.nominal_run(c)).map_err(runtime_err)?;
        serde_json::to_string(&summary).map_err(json_err("summary"))
    }

    /// The scenario's name.
    fn scenario_name(&self) -> String {
        self.inner.scenario.name().to_string()
    }
}

/// `mpc_track --monte-carlo`'s summary of two controllers' outcomes (JSON lists, in seed
/// order): returns the JSON of both robustness figures and the table text, and writes the
/// histogram PNG at `png`.
#[pyfunction]
fn monte_carlo_report(
    settings_json: &str,
    pinc_json: &str,
    oracle_json: &str,
    first_seed: u64,
    png: std::path::PathBuf,
    json_path: std::path::PathBuf,
) -> PyResult<(String, String, String)> {
    let settings: Settings = serde_json::from_str(settings_json).map_err(json_err("settings"))?;
    let scenario = Campaign::new(&settings).map_err(|e| PincError::new_err(e.to_string()))?.scenario;
    let read = |what: &str, text: &str| -> PyResult<Vec<Outcome>> {
        let v: Vec<OutcomeJson> = serde_json::from_str(text).map_err(json_err(what))?;
        Ok(v.into_iter().map(Outcome::from).collect())
    };
    let (p, o) = (read("pinc outcomes", pinc_json)?, read("oracle outcomes", oracle_json)?);
    let n = p.len();
    histogram(&png, &p, &o, n).map_err(|e| PincError::new_err(format!("{}: {e}", png.display())))?;
    let (rp, ro) = (robustness(&p), robustness(&o));
    let text = table(n, first_seed, &scenario, &rp, &ro, &json_path);
    let j = |r| serde_json::to_string(r).map_err(json_err("robustness"));
    Ok((j(&rp)?, j(&ro)?, text))
}
