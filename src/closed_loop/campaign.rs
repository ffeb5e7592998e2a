//! A closed-loop campaign from plain settings: the one code path that `mpc_track` and the
//! Python package both take to build the controller and scenario and to run one perturbed
//! plant, so a run of a seed anywhere equals the same seed's run in `mpc_track`, bit for bit.

use super::monte_carlo::{Draw, Outcome, Robustness, Spread, draw, run_perturbed};
use super::path_plan::{PathFrame, PathHeading, PathLimits, read_path_file, survey};
use super::run::run;
use super::scenario::Scenario;
use super::summary::{Summary, summarise};
use crate::Input;
use crate::model::PincModel;
use crate::mpc::{Mpc, MpcConfig, MpcError, QpSolver};
use crate::plot::{Panel, Series, figure};
use crate::runtime::Predictor;
use crate::traits::DiscreteModel;
use crate::vehicle::{Rk4Vehicle, VehicleParams};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Everything a closed-loop run is built from, as plain values (the flags of `mpc_track`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Settings {
    /// The frozen model inside the MPC (its training envelope bounds the inputs).
    pub model: PathBuf,
    /// Vehicle file of the plant and of the oracle's model [`None`: the BlueROV2].
    pub vehicle: Option<PathBuf>,
    /// Built-in scenario: `default`, `disturbed`, `station`, `hold` or `survey` (ignored when
    /// `reference`, `path` or `survey` is given).
    pub scenario: String,
    /// References from a CSV file `t,depth_m,heading_deg`.
    pub reference: Option<PathBuf>,
    /// A path of waypoints to follow (CSV, [`read_path_file`]).
    pub path: Option<PathBuf>,
    /// What the path's coordinates are measured from.
    pub path_frame: PathFrame,
    /// A lawnmower survey from the start: width (across the legs), length, leg spacing (m),
    /// speed (m/s), depth (m).
    pub survey: Option<[f64; 5]>,
    /// Heading along a path or survey (deg) [`None`: along the track].
    pub path_heading: Option<f64>,
    /// Water velocity north, east (m/s) [`None`: the scenario's].
    pub current: Option<[f64; 2]>,
    /// The farthest a path may go from the start (m).
    pub max_distance: Option<f64>,
    /// Length of the run (s) [`None`: the scenario's, or the reference file's last time].
    pub duration: Option<f64>,
    /// Prediction horizon (samples).
    pub horizon: usize,
    /// Gain of the disturbance estimate.
    pub disturbance_gain: f64,
    /// Constrain the predicted velocities to the model's training envelope.
    pub envelope_constraints: bool,
    /// Linear penalty per unit of envelope slack.
    pub envelope_penalty: f64,
    /// Fraction of each velocity range the envelope bounds sit inside the envelope.
    pub envelope_margin: f64,
    /// Weights on input changes X, Y, Z, Mz [`None`: [`MpcConfig`]'s].
    pub input_rate: Option<[f64; 4]>,
    /// Wall-clock limit of one QP solve (s) [`None`: [`MpcConfig`]'s]. A solve that hits it
    /// falls back, so a run is reproducible only while no solve does: raise it for
    /// campaigns on loaded or slow machines.
    pub solver_time_limit: Option<f64>,
    /// Steps per condensed block of the QP (1: the sparse form) [`None`: [`MpcConfig`]'s].
    pub condensing_block: Option<usize>,
    /// Solve the QP as before partial condensing ([`MpcConfig::with_sparse_qp`]), for comparison.
    pub sparse_qp: bool,
    /// The QP solver [`None`: the Riccati interior-point method, or Clarabel with
    /// `sparse_qp`, its formulation].
    pub qp: Option<QpSolver>,
}

impl Default for Settings {
    fn default() -> Self {
        let c = MpcConfig::default();
        Self {
            model: PathBuf::from("models/mpc_pinc_thrust.pinc"),
            vehicle: None,
            scenario: "default".into(),
            reference: None,
            path: None,
            path_frame: PathFrame::Start,
            survey: None,
            path_heading: None,
            current: None,
            max_distance: None,
            duration: None,
            horizon: 20,
            disturbance_gain: c.disturbance_gain,
            envelope_constraints: true,
            envelope_penalty: c.envelope_penalty,
            envelope_margin: c.envelope_margin,
            input_rate: None,
            solver_time_limit: None,
            condensing_block: None,
            sparse_qp: false,
            qp: None,
        }
    }
}

/// Which controller runs: the MPC on the PINC, or the identical MPC on the analytic model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Controller {
    /// The MPC on the frozen PINC of [`Settings::model`].
    Pinc,
    /// The MPC on the analytic vehicle (it knows the nominal plant).
    Oracle,
}

/// Why a campaign could not be set up (each names the file or setting at fault).
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    /// The model file could not be loaded.
    #[error("{path}: {why}")]
    Model {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        why: String,
    },
    /// The model has no training envelope to bound the inputs.
    #[error("{0}: no training envelope to bound the inputs")]
    NoEnvelope(PathBuf),
    /// The vehicle or reference file could not be read.
    #[error("{0}")]
    File(String),
    /// A setting out of range.
    #[error("{0}")]
    Setting(String),
}

/// A campaign ready to run: model, plant, scenario and controller configuration loaded once.
#[derive(Debug, Clone)]
pub struct Campaign {
    /// The frozen model.
    pub model: PincModel,
    /// The nominal plant (each perturbed run draws around it).
    pub vehicle: VehicleParams,
    /// The scenario.
    pub scenario: Scenario,
    /// The controller configuration (bounds from the model's envelope, or for a fitted model
    /// whose correction is zero its thrusters' reach).
    pub config: MpcConfig,
    /// Input bounds (from the model's envelope, or the fitted thrusters' reach).
    pub bounds: (Input, Input),
}

/// The input bounds of a fitted model whose correction is zero: the reach of the thrusters it
/// carries. It is its physics wherever it flies, so the forces its training happened to see
/// (the fit's excitation: a fifth of the thrusters' heave at full pilot gain) need not bound it;
/// held to them, the MPC flew depth 1.08-1.27x worse than on the vehicle's own file on the
/// firmware, saturating in heave where the file's flight asked 50 N. `None` for any other model.
fn physics_only_bounds(model: &PincModel) -> Result<Option<(Input, Input)>, String> {
    let Some(fitted) = model.fitted.as_ref().filter(|_| model.correction_is_zero()) else { return Ok(None) };
    let source = std::path::Path::new("the model's fitted thrusters");
    let thrusters = crate::vehicle::Thrusters::from_toml(&fitted.thrusters_toml, source).map_err(|e| e.to_string())?;
    Ok(thrusters.map(|t| t.input_bounds()))
}

impl Campaign {
    /// Loads and checks everything `s` names.
    pub fn new(s: &Settings) -> Result<Self, SetupError> {
        let vehicle = match &s.vehicle {
            Some(path) => VehicleParams::load(path).map_err(|e| SetupError::File(e.to_string()))?,
            None => VehicleParams::default(),
        };
        let model =
            PincModel::load(&s.model).map_err(|e| SetupError::Model { path: s.model.clone(), why: e.to_string() })?;
        let bounds = match physics_only_bounds(&model).map_err(SetupError::File)? {
            Some(bounds) => bounds,
            None => {
                Predictor::reference(&model).input_bounds().ok_or_else(|| SetupError::NoEnvelope(s.model.clone()))?
            }
        };
        let heading = s.path_heading.map_or(PathHeading::Track, PathHeading::Fixed);
        let mut scenario = scenario_of(s, &path_limits(&vehicle, bounds, s.max_distance, heading))?;
        // A reference file or path took the duration above (checked there); the built-ins take it here.
        if s.reference.is_none()
            && s.path.is_none()
            && s.survey.is_none()
            && let Some(d) = s.duration
        {
            if !(d.is_finite() && d > 0.0) {
                return Err(SetupError::Setting(format!("--duration must be a positive number of seconds, got {d}")));
            }
            scenario.duration = d;
        }
        if let Some(t) = s.solver_time_limit
            && !(t.is_finite() && t > 0.0)
        {
            return Err(SetupError::Setting(format!(
                "--solver-time-limit must be a positive number of seconds, got {t}"
            )));
        }
        if let Some(c) = s.current {
            if !c.iter().all(|v| v.is_finite()) {
                return Err(SetupError::Setting(format!("--current {c:?}: two finite speeds north,east (m/s)")));
            }
            scenario.current = c;
        }
        let qp = s.qp.unwrap_or(if s.sparse_qp { QpSolver::Clarabel } else { QpSolver::Riccati });
        if s.sparse_qp && qp != QpSolver::Clarabel {
            return Err(SetupError::Setting(format!(
                "sparse_qp is a formulation of Clarabel's QP; the {qp} solver takes the stages as they are"
            )));
        }
        let defaults = MpcConfig::default();
        let config = MpcConfig {
            input_rate: s.input_rate.unwrap_or(defaults.input_rate),
            horizon: s.horizon,
            bounds: Some(bounds),
            disturbance_gain: s.disturbance_gain,
            envelope_constraints: s.envelope_constraints,
            envelope_penalty: s.envelope_penalty,
            envelope_margin: s.envelope_margin,
            solver_time_limit: s.solver_time_limit.unwrap_or(defaults.solver_time_limit),
            condensing_block: s.condensing_block.unwrap_or(defaults.condensing_block),
            qp,
            ..defaults
        };
        let config = if s.sparse_qp { config.with_sparse_qp() } else { config };
        // A horizontal goal puts the position into the problem, on all four axes.
        let config = if scenario.horizontal.is_some() { config.four_axis() } else { config };
        Ok(Self { model, vehicle, scenario, config, bounds })
    }

    /// The perturbed plant of `seed`, as `mpc_track --monte-carlo` draws it.
    pub fn draw(&self, seed: u64) -> Draw {
        draw(&self.vehicle, seed)
    }

    /// One Monte-Carlo run: `controller` (built afresh on the nominal model) against the
    /// plant of `seed`. A controller that cannot be built is that run's failure.
    pub fn monte_carlo_run(&self, seed: u64, controller: Controller) -> Outcome {
        let d = self.draw(seed);
        let outcome = match controller {
            Controller::Oracle => {
                Mpc::new(self.oracle(), self.config.clone()).map(|mut m| run_perturbed(&mut m, &self.scenario, &d))
            }
            Controller::Pinc => Mpc::new(Predictor::reference(&self.model), self.config.clone())
                .map(|mut m| run_perturbed(&mut m, &self.scenario, &d)),
        };
        outcome.unwrap_or_else(|e| setup_failure(seed, e))
    }

    /// One unperturbed run's summary (the figures of `mpc_track --json`, without its log).
    pub fn nominal_run(&self, controller: Controller) -> Result<Summary, MpcError> {
        let samples = match controller {
            Controller::Oracle => {
                run(&mut Mpc::new(self.oracle(), self.config.clone())?, &self.scenario, &self.vehicle, |_| true)
            }
            Controller::Pinc => run(
                &mut Mpc::new(Predictor::reference(&self.model), self.config.clone())?,
                &self.scenario,
                &self.vehicle,
                |_| true,
            ),
        };
        Ok(summarise(&samples, &self.scenario, self.config.horizon as f64 * self.model.dt))
    }

    /// The analytic model of the nominal plant at the model's sample time, as a controller's
    /// model ([`Rk4Vehicle::for_control`]).
    pub fn oracle(&self) -> Rk4Vehicle {
        Rk4Vehicle::for_control(self.vehicle, self.model.dt)
    }
}

/// The limits a path is checked against: the vehicle's steady horizontal speed at the
/// model's largest force on the axis it travels along (surge where it faces along each leg,
/// else the smaller of surge and sway), and the distance limit.
pub fn path_limits(
    vehicle: &VehicleParams,
    (lo, hi): (Input, Input),
    max_distance: Option<f64>,
    heading: PathHeading,
) -> PathLimits {
    let surge = crate::vehicle::terminal_speed(hi[0].min(-lo[0]).max(0.0), vehicle.x_u, vehicle.x_uu);
    let sway = crate::vehicle::terminal_speed(hi[1].min(-lo[1]).max(0.0), vehicle.y_v, vehicle.y_vv);
    let max_speed = match heading {
        PathHeading::Track => surge,
        PathHeading::Fixed(_) => surge.min(sway),
    };
    PathLimits { max_speed, max_distance }
}

/// The scenario `s` names: a reference file, a path file, a survey, or a built-in one.
fn scenario_of(s: &Settings, limits: &PathLimits) -> Result<Scenario, SetupError> {
    let heading = s.path_heading.map_or(PathHeading::Track, PathHeading::Fixed);
    let given = [s.reference.is_some(), s.path.is_some(), s.survey.is_some()];
    if given.iter().filter(|&&g| g).count() > 1 {
        return Err(SetupError::Setting("give one of --reference, --path and --survey".into()));
    }
    if let Some(d) = s.max_distance
        && !(d.is_finite() && d > 0.0)
    {
        return Err(SetupError::Setting(format!("--max-distance must be a positive number of metres, got {d}")));
    }
    let current = s.current.unwrap_or(super::FOUR_AXIS_CURRENT);
    let scenario = match (&s.reference, &s.path, &s.survey, s.scenario.as_str()) {
        (Some(path), ..) => Scenario::from_file(path, s.duration).map_err(|e| SetupError::File(e.to_string()))?,
        (_, Some(path), ..) => {
            let plan = read_path_file(path, s.path_frame, limits).map_err(|e| SetupError::File(e.to_string()))?;
            let name = path.file_stem().map_or_else(|| "path".into(), |n| n.to_string_lossy().into_owned());
            Scenario::along(&name, plan, current, s.duration)
        }
        (_, _, Some([width, length, spacing, speed, depth]), _) => {
            if !(width.is_finite() && *width >= 0.0 && spacing.is_finite() && *spacing > 0.0) {
                return Err(SetupError::Setting(format!(
                    "--survey: width {width} and spacing {spacing} (non-negative, positive)"
                )));
            }
            let legs = (width / spacing + 1e-9).floor() as usize + 1;
            let plan = survey((legs, *length, *spacing), *speed, *depth, heading, limits)
                .map_err(|e| SetupError::Setting(e.to_string()))?;
            Scenario::along("survey", plan, current, s.duration)
        }
        (.., "default") => Scenario::default(),
        (.., "disturbed") => Scenario::disturbed(),
        (.., "station") => Scenario::station(),
        (.., "hold") => Scenario::hold(),
        (.., "survey") => Scenario::survey(),
        (.., other) => {
            return Err(SetupError::Setting(format!(
                "scenario: `{other}` is none of default, disturbed, station, hold, survey"
            )));
        }
    };
    if let (Some(limit), Some(h)) = (s.max_distance, &scenario.horizontal)
        && h.reach() > limit
    {
        return Err(SetupError::Setting(format!(
            "scenario {}: its path reaches {:.2} m from the start, past --max-distance {limit} m",
            scenario.name(),
            h.reach()
        )));
    }
    Ok(scenario)
}

/// A controller that cannot be built from a configuration that built before is a bug, but a
/// Monte-Carlo batch reports it as that run's failure rather than stopping.
fn setup_failure(seed: u64, e: MpcError) -> Outcome {
    Outcome {
        seed,
        success: false,
        failure: Some(format!("controller set-up: {e}")),
        rms_depth_m: f64::INFINITY,
        rms_horizontal_m: None,
        rms_heading_deg: f64::INFINITY,
        solve_ms: Vec::new(),
    }
}

/// The summary table of a campaign of `n` runs from `seed` (`mpc_track --monte-carlo`'s),
/// the full figures being in `json_path`.
pub fn table(n: usize, seed: u64, scenario: &Scenario, rp: &Robustness, ro: &Robustness, json_path: &Path) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let spread = |s: &Spread, f: f64| format!("{:.3} / {:.3} / {:.3}", s.median * f, s.p95 * f, s.max * f);
    // Writing to a String cannot fail.
    let _ =
        writeln!(out, "{n} perturbed runs of scenario {} (seeds {}..{})", scenario.name(), seed, seed + n as u64 - 1);
    let _ = writeln!(out, "{:<28} {:>26} {:>26}", "", "PINC", "oracle");
    let _ =
        writeln!(out, "{:<28} {:>25.1}% {:>25.1}%", "success rate", 100.0 * rp.success_rate, 100.0 * ro.success_rate);
    let rows = [
        ("RMS depth, cm (med/p95/max)", &rp.rms_depth_m, &ro.rms_depth_m, 100.0),
        ("RMS heading, deg", &rp.rms_heading_deg, &ro.rms_heading_deg, 1.0),
    ];
    for (label, p, o, f) in rows {
        let _ = writeln!(out, "{label:<28} {:>26} {:>26}", spread(p, f), spread(o, f));
    }
    if let (Some(p), Some(o)) = (&rp.rms_horizontal_m, &ro.rms_horizontal_m) {
        let _ = writeln!(out, "{:<28} {:>26} {:>26}", "RMS horizontal, cm", spread(p, 100.0), spread(o, 100.0));
    }
    let _ = writeln!(out, "{:<28} {:>26.3} {:>26.3}", "solve time p99, ms", rp.solve_ms_p99, ro.solve_ms_p99);
    for (name, r) in [("PINC", rp), ("oracle", ro)] {
        for (seed, why) in r.failures.iter().take(10) {
            let _ = writeln!(out, "  {name} failed, seed {seed}: {why}");
        }
        if r.failures.len() > 10 {
            let _ = writeln!(
                out,
                "  ... and {} more {name} failures (all in {})",
                r.failures.len() - 10,
                json_path.display()
            );
        }
    }
    out
}

/// Histograms (as step outlines) of the runs' RMS depth and heading errors, both
/// controllers, as a PNG at `path`; `n` runs each.
pub fn histogram(path: &Path, pinc: &[Outcome], oracle: &[Outcome], n: usize) -> Result<(), String> {
    let bins = 30usize.min(n.max(5));
    let outline = |values: Vec<f64>, (lo, hi): (f64, f64)| -> Vec<(f64, f64)> {
        let w = (hi - lo) / bins as f64;
        let mut counts = vec![0usize; bins];
        for v in values.into_iter().filter(|v| v.is_finite()) {
            counts[(((v - lo) / w) as usize).min(bins - 1)] += 1;
        }
        let mut pts = vec![(lo, 0.0)];
        for (i, c) in counts.iter().enumerate() {
            pts.push((lo + i as f64 * w, *c as f64));
            pts.push((lo + (i + 1) as f64 * w, *c as f64));
        }
        pts.push((hi, 0.0));
        pts
    };
    // The range of both controllers' finite values, widened by 5 % on each side.
    let range = |f: &dyn Fn(&Outcome) -> f64| {
        let v: Vec<f64> = pinc.iter().chain(oracle).map(f).filter(|v| v.is_finite()).collect();
        let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        let pad = 0.05 * (hi - lo).max(1e-9);
        if lo.is_finite() { ((lo - pad).max(0.0), hi + pad) } else { (0.0, 1.0) }
    };
    let mut panels = Vec::new();
    type Measure = fn(&Outcome) -> f64;
    let quantities: [(&str, &str, Measure); 2] = [
        ("RMS depth error per run", "cm", |o| o.rms_depth_m * 100.0),
        ("RMS heading error per run", "deg", |o| o.rms_heading_deg),
    ];
    for (title, unit, f) in quantities {
        let span = range(&f);
        panels.push(Panel {
            title,
            x_label: unit,
            y_label: "runs",
            log_y: false,
            series: vec![
                Series { label: "PINC", points: outline(pinc.iter().map(f).collect(), span), color: 0, dashed: false },
                Series {
                    label: "oracle",
                    points: outline(oracle.iter().map(f).collect(), span),
                    color: 1,
                    dashed: true,
                },
            ],
        });
    }
    figure(path, 1400, 560, 2, &panels)
}
