//! What a fit found and how its model does on data it did not train on: per coefficient and
//! per axis what the recordings determined, the sensor model, physics against hybrid on the
//! held-out time; written as `report.json`, `report.md` and `report.png`.

use super::{Fit, FitError};
use crate::dataset::TrajectorySet;
use crate::identify::{ESTIMATED, Identification, MAX_RELATIVE_STD_ERR, judged_against};
use crate::plot::{Panel, Series, figure};
use crate::runtime::Predictor;
use crate::train::TrainOutcome;
use crate::traits::DiscreteModel;
use crate::types::State;
use crate::vehicle::{Rk4Vehicle, VehicleParams};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// The axes and the coefficients of each.
pub const AXES: [(&str, &[&str]); 4] = [
    ("surge", &["x_ud", "x_u", "x_uu"]),
    ("sway", &["y_vd", "y_v", "y_vv"]),
    ("heave", &["volume", "z_wd", "z_w", "z_ww"]),
    ("yaw", &["n_rd", "n_r", "n_rr"]),
];

/// What the data said of one coefficient.
#[derive(Debug, Clone, Serialize)]
pub struct CoefficientFinding {
    /// Its name in the vehicle file.
    pub name: &'static str,
    /// The starting file's value.
    pub start: f64,
    /// The fitted model's value.
    pub fitted: f64,
    /// Its standard error, where the data determined it.
    pub std_err: Option<f64>,
    /// `identified`, `not_excited` (the data leave it undetermined: kept from the start) or
    /// `no_position_source` (surge and sway without a position or velocity sensor: the
    /// estimator's velocities are the starting file's own, so a fit would echo it).
    pub status: &'static str,
    /// Why, in words.
    pub why: String,
}

/// What the data said of one axis.
#[derive(Debug, Clone, Serialize)]
pub struct AxisFinding {
    /// surge, sway, heave or yaw.
    pub axis: &'static str,
    /// Whether the coefficients the controller needs of it were determined.
    pub determined: bool,
    /// Why not, where not.
    pub why: String,
}

/// The report's findings.
#[derive(Debug, Clone, Serialize)]
pub struct Findings {
    /// Per coefficient, in the identification's order.
    pub coefficients: Vec<CoefficientFinding>,
    /// Per axis.
    pub axes: Vec<AxisFinding>,
    /// What makes the model unfit to fly as it is (empty: the fit passed); the model file
    /// carries them.
    pub warnings: Vec<String>,
    /// What an owner should know that does not fail the fit.
    pub notes: Vec<String>,
}

/// The findings of an identification (its vehicle already holds the starting file's values
/// where the data could not tell), given whether a position source was fused, which sensors
/// kept a default and how the training ended.
pub fn findings(
    id: &Identification,
    start: &VehicleParams,
    horizontal: bool,
    sensors_defaulted: &[&str],
    training: Option<&TrainOutcome>,
) -> Findings {
    let surge_sway = |k: &str| AXES[..2].iter().any(|(_, ks)| ks.contains(&k));
    let coefficients: Vec<CoefficientFinding> = ESTIMATED
        .iter()
        .map(|&name| {
            let echo = !horizontal && surge_sway(name);
            // An echo's standard error is the fit of the starting file to its own motion.
            let (fitted, std_err) = (super::coefficient(&id.vehicle, name), id.std_err_of(name).filter(|_| !echo));
            let (status, why) = if echo {
                let kept = if matches!(name, "x_ud" | "y_vd") {
                    "the surge and sway added masses set to the mean of the starting file's two (their difference \
                     couples the yaw into surge and sway, which the recordings cannot confirm)"
                } else {
                    "kept from the starting file"
                };
                (
                    "no_position_source",
                    format!(
                        "no position or velocity sensor: the estimated surge and sway come from the starting file's \
                         own model, so they cannot correct it; {kept}"
                    ),
                )
            } else if let Some(se) = std_err {
                let against = judged_against(&id.vehicle, name, id.speeds);
                let what = match name {
                    "x_ud" | "y_vd" | "z_wd" | "n_rd" => "the effective mass or inertia",
                    "volume" => "the value",
                    _ => "the axis's damping at the data's RMS speed",
                };
                ("identified", format!("standard error {:.1} % of {what}", 100.0 * se / against.max(1e-12)))
            } else {
                (
                    "not_excited",
                    format!(
                        "the recordings do not excite it enough (standard error over {:.0} % of what it is judged \
                         against: its value, the effective mass or inertia, or the axis's damping); kept from the \
                         starting file",
                        100.0 * MAX_RELATIVE_STD_ERR
                    ),
                )
            };
            CoefficientFinding { name, start: super::coefficient(start, name), fitted, std_err, status, why }
        })
        .collect();
    let ok = |k: &str| coefficients.iter().any(|c| c.name == k && c.status == "identified");
    let mut warnings = Vec::new();
    let mut notes = Vec::new();
    let axes = AXES
        .iter()
        .map(|&(axis, keys)| {
            let (mass, damping) = (keys[keys.len() - 3], &keys[keys.len() - 2..]);
            let mut missing: Vec<&str> = Vec::new();
            if axis == "heave" && !ok("volume") {
                missing.push("volume (the net buoyancy)");
            }
            if !ok(mass) {
                missing.push(mass);
            }
            if !damping.iter().any(|k| ok(k)) {
                missing.push("any damping (linear or quadratic)");
            }
            let controlled = matches!(axis, "heave" | "yaw");
            let why = if missing.is_empty() {
                String::new()
            } else if !horizontal && !controlled {
                format!("no position source: the {axis} coefficients stay the starting file's")
            } else {
                format!("the recordings did not determine {}", missing.join(", "))
            };
            if !missing.is_empty() {
                if controlled || horizontal {
                    warnings.push(format!(
                        "{axis}: {why}; record more of it (longer, or a wider excitation of that axis) and fit again"
                    ));
                } else {
                    notes.push(format!("{axis}: {why} (add a DVL or another position source to fit it)"));
                }
            }
            AxisFinding { axis, determined: missing.is_empty(), why }
        })
        .collect();
    for &s in sensors_defaulted {
        warnings.push(if s == "depth lag" {
            "sensors: the depth lag is not determined (the best lag is at the end of 0-0.3 s, or at 0 against the heave \
             equation, on these recordings); the \
             estimator's default is kept"
                .to_string()
        } else {
            format!("sensors: too few {s} readings to measure their noise; the estimator's default is kept")
        });
    }
    if let Some(epoch) = training.and_then(super::cut_by_time) {
        notes.push(format!(
            "training: the time cap cut it after epoch {epoch} of {}; the same settings without the cap (or on a faster \
             machine) train further",
            training.map_or(epoch, |t| t.history.len().max(epoch))
        ));
    }
    if training.is_some_and(|t| t.best_epoch == 0) {
        notes.push(
            "training: no correction beat the identified physics clearly on the dev data; the model is its physics \
             (longer recordings let a correction show)"
                .into(),
        );
    }
    Findings { coefficients, axes, warnings, notes }
}

/// Physics and hybrid against the estimate on the held-out windows: RMS error over every
/// step of every window, per quantity.
#[derive(Debug, Clone, Serialize)]
pub struct HeldOut {
    /// Windows and their length (s).
    pub windows: usize,
    /// Seconds per window.
    pub window_s: f64,
    /// `[depth m, heading rad, u, v, w m/s, r rad/s]` RMS, the identified vehicle's RK4 step.
    pub physics_rms: [f64; 6],
    /// The same for the hybrid.
    pub hybrid_rms: [f64; 6],
    /// Mean valid prediction time (s) of each.
    pub physics_vpt_s: f64,
    /// The hybrid's.
    pub hybrid_vpt_s: f64,
    /// The reference vehicle file's physics on the same windows (`--reference`).
    pub reference: Option<ReferenceScore>,
    /// The identified physics per axis: its velocity error against the velocity.
    pub axes: Vec<AxisHeldOut>,
}

/// A reference vehicle file scored on the held-out windows.
#[derive(Debug, Clone, Serialize)]
pub struct ReferenceScore {
    /// The file.
    pub file: PathBuf,
    /// `[depth m, heading rad, u, v, w m/s, r rad/s]` RMS of its RK4 step.
    pub rms: [f64; 6],
    /// Its velocity errors per axis, judged as the fit's are.
    pub axes: Vec<AxisHeldOut>,
}

/// The quantities of [`HeldOut`].
pub const QUANTITIES: [&str; 6] = ["depth", "heading", "u", "v", "w", "r"];

/// The largest gain error ([`AxisHeldOut::gain_error`]) of the identified physics on the
/// held-out windows before the report calls the axis biased. Measured on the firmware's
/// recordings (three with the GPS, one stock): the fits 0.0-0.07 on every axis (heave the
/// largest); the simulator's own file 0.0-0.04 against them; a file with the surge and sway drag
/// of the issue's hidden-seed fit (2.7x and 1.6x at 0.2 m/s) -0.17 and -0.13.
pub const MAX_GAIN_ERROR: f64 = 0.1;

/// Held-out velocities slower than this (RMS; m/s, and rad/s for the yaw rate) did not drive
/// the axis enough to judge it.
pub const MIN_HELD_OUT_SPEED: f64 = 0.03;

/// How well the identified physics predicts one axis's velocity on the held-out windows, each
/// rolled out from its start: what a coefficient's standard error cannot show (a bias the
/// whole recording shares).
#[derive(Debug, Clone, Serialize)]
pub struct AxisHeldOut {
    /// surge, sway, heave or yaw.
    pub axis: &'static str,
    /// RMS error of the physics' velocity (m/s, rad/s).
    pub rms_error: f64,
    /// RMS of the velocity itself on those windows.
    pub rms_velocity: f64,
    /// The physics' velocity error regressed on the velocity: the fraction by which it
    /// predicts the axis too fast (positive) or too slow (negative) on average.
    pub gain_error: f64,
    /// Whether it was judged: the axis fitted (surge and sway need a position source) and
    /// driven at least [`MIN_HELD_OUT_SPEED`].
    pub judged: bool,
    /// Judged and its gain error over [`MAX_GAIN_ERROR`] either way.
    pub biased: bool,
}

/// [`AxisHeldOut`] of `vehicle`'s RK4 step on `test`, per axis.
pub fn held_out_axes(vehicle: &VehicleParams, test: &TrajectorySet, horizontal: bool) -> Vec<AxisHeldOut> {
    let physics = Rk4Vehicle { params: *vehicle, ..Rk4Vehicle::with_dt(test.dt) };
    let mut sums = ErrorSums::default();
    for i in 0..test.count {
        let (states, inputs) = test.trajectory(i);
        sums.add(&rollout(&physics, &test.start(i, 0), inputs), states);
    }
    sums.axes(horizontal)
}

/// The report's warning for each biased axis of `axes`.
pub fn bias_warnings(axes: &[AxisHeldOut]) -> Vec<String> {
    let names = ["u", "v", "w", "r"];
    axes.iter()
        .zip(names)
        .filter(|(a, _)| a.biased)
        .map(|(a, name)| {
            format!(
                "{}: held out, the identified physics predicts {name} {:.0} % too {} on average (at most {:.0} %; RMS \
                 error {:.3}): a bias its standard errors do not show (a lagging position, a thrust curve that is not \
                 this vehicle's, too few speeds); record more of that axis, at the speeds it will fly, and fit again",
                a.axis,
                100.0 * a.gain_error.abs(),
                if a.gain_error > 0.0 { "fast" } else { "slow" },
                100.0 * MAX_GAIN_ERROR,
                a.rms_error
            )
        })
        .collect()
}

fn rollout<M: DiscreteModel>(m: &M, x0: &State, inputs: &[crate::Input]) -> Vec<State> {
    let mut ws = m.workspace();
    let mut out = vec![*x0];
    for u in inputs {
        let mut next = State::zeros();
        if m.step(&mut ws, out.last().expect("x0"), u, &mut next).is_err() {
            break;
        }
        out.push(next);
    }
    out
}

/// The heading (rad) of a network-form state.
fn heading(x: &State) -> f64 {
    x[4].atan2(x[3])
}

/// A model's rollouts against the held-out estimate, summed: squared errors per quantity of
/// [`QUANTITIES`], and per velocity its square and its product with the error (for the gain).
#[derive(Default)]
struct ErrorSums {
    squared: [f64; 6],
    velocity: [f64; 4],
    cross: [f64; 4],
    points: usize,
}

impl ErrorSums {
    /// Adds `pred` against `truth` (network-form states).
    fn add(&mut self, pred: &[State], truth: &[State]) {
        for (p, t) in pred.iter().zip(truth) {
            let dpsi = crate::vehicle::wrap_angle(heading(p) - heading(t));
            let e = [p[2] - t[2], dpsi, p[5] - t[5], p[6] - t[6], p[7] - t[7], p[8] - t[8]];
            for (s, e) in self.squared.iter_mut().zip(e) {
                *s += e * e;
            }
            for c in 0..4 {
                self.velocity[c] += t[5 + c] * t[5 + c];
                self.cross[c] += e[2 + c] * t[5 + c];
            }
            self.points += 1;
        }
    }

    /// The root of a sum's mean over the points.
    fn root_mean(&self, sum: f64) -> f64 {
        (sum / self.points.max(1) as f64).sqrt()
    }

    /// RMS error per quantity.
    fn rms(&self) -> [f64; 6] {
        self.squared.map(|v| self.root_mean(v))
    }

    /// [`AxisHeldOut`] per axis; surge and sway judged only where `horizontal`.
    fn axes(&self, horizontal: bool) -> Vec<AxisHeldOut> {
        AXES.iter()
            .enumerate()
            .map(|(c, &(axis, _))| {
                let (rms_error, rms_velocity) = (self.root_mean(self.squared[2 + c]), self.root_mean(self.velocity[c]));
                // An axis that never moved has no gain to speak of.
                let gain_error = if rms_velocity > 1e-9 { self.cross[c] / self.velocity[c] } else { 0.0 };
                let judged = (horizontal || c >= 2) && rms_velocity >= MIN_HELD_OUT_SPEED;
                AxisHeldOut {
                    axis,
                    rms_error,
                    rms_velocity,
                    gain_error,
                    judged,
                    // A NaN gain (no finite velocity) is a bias too.
                    biased: judged && (gain_error.abs() > MAX_GAIN_ERROR || gain_error.is_nan()),
                }
            })
            .collect()
    }
}

/// [`HeldOut`] of `model` (and its physics, and a reference vehicle's) on `test`; `horizontal`:
/// whether surge and sway were fitted.
pub fn held_out(
    model: &crate::model::PincModel,
    test: &TrajectorySet,
    reference: Option<&(PathBuf, VehicleParams)>,
    horizontal: bool,
) -> HeldOut {
    let physics = Rk4Vehicle { params: model.vehicle, ..Rk4Vehicle::with_dt(test.dt) };
    let hybrid = Predictor::<f64>::reference(model);
    let other = reference.map(|(_, p)| Rk4Vehicle { params: *p, ..Rk4Vehicle::with_dt(test.dt) });
    let (mut sp, mut sh, mut sr) = (ErrorSums::default(), ErrorSums::default(), ErrorSums::default());
    for i in 0..test.count {
        let (states, inputs) = test.trajectory(i);
        let x0 = test.start(i, 0);
        sp.add(&rollout(&physics, &x0, inputs), states);
        sh.add(&rollout(&hybrid, &x0, inputs), states);
        if let Some(other) = &other {
            sr.add(&rollout(other, &x0, inputs), states);
        }
    }
    let vpt_p = crate::eval::evaluate_set_discrete(&physics, test).map_or(f64::NAN, |m| m.vpt_s);
    let vpt_h = crate::eval::evaluate_set(model, test, &model.vehicle).map_or(f64::NAN, |m| m.vpt_s);
    HeldOut {
        windows: test.count,
        window_s: (test.points - 1) as f64 * test.dt,
        physics_rms: sp.rms(),
        hybrid_rms: sh.rms(),
        physics_vpt_s: vpt_p,
        hybrid_vpt_s: vpt_h,
        reference: reference.map(|(file, _)| ReferenceScore {
            file: file.clone(),
            rms: sr.rms(),
            axes: sr.axes(horizontal),
        }),
        axes: sp.axes(horizontal),
    }
}

/// The plot: the held-out windows laid end to end, each rolled out from its start, the
/// estimate against physics and hybrid for depth, heading, heave and yaw rate.
fn plot(path: &Path, model: &crate::model::PincModel, test: &TrajectorySet) -> Result<(), String> {
    let physics = Rk4Vehicle { params: model.vehicle, ..Rk4Vehicle::with_dt(test.dt) };
    let hybrid = Predictor::<f64>::reference(model);
    let shown = test.count.min(8);
    let mut lines: [[Vec<(f64, f64)>; 3]; 4] = Default::default();
    let quantity = |x: &State, q: usize| match q {
        0 => x[2],
        1 => heading(x).to_degrees(),
        2 => x[7],
        _ => x[8],
    };
    for i in 0..shown {
        let (states, inputs) = test.trajectory(i);
        let t0 = i as f64 * (test.points as f64) * test.dt;
        let x0 = test.start(i, 0);
        let runs = [states.to_vec(), rollout(&physics, &x0, inputs), rollout(&hybrid, &x0, inputs)];
        for (q, line) in lines.iter_mut().enumerate() {
            for (k, run) in runs.iter().enumerate() {
                line[k].extend(run.iter().enumerate().map(|(j, x)| (t0 + j as f64 * test.dt, quantity(x, q))));
                line[k].push((f64::NAN, f64::NAN));
            }
        }
    }
    let titles = [("depth", "m"), ("heading", "deg"), ("heave rate w", "m/s"), ("yaw rate r", "rad/s")];
    let panels: Vec<Panel> = lines
        .into_iter()
        .zip(titles)
        .map(|([est, phys, hyb], (title, unit))| Panel {
            title,
            x_label: "held-out windows end to end (s)",
            y_label: unit,
            log_y: false,
            series: vec![
                Series { label: "estimate (recorded)", points: est, color: 0, dashed: false },
                Series { label: "identified physics", points: phys, color: 1, dashed: true },
                Series { label: "hybrid", points: hyb, color: 2, dashed: false },
            ],
        })
        .collect();
    figure(path, 1400, 1000, 2, &panels).map_err(|e| e.to_string())
}

/// The files a fit writes, in its folder.
#[derive(Debug, Clone, Serialize)]
pub struct Written {
    /// The folder.
    pub folder: PathBuf,
    /// The identified vehicle file (thrusters inline).
    pub vehicle: PathBuf,
    /// The hybrid model carrying the thrusters and the sensor model.
    pub model: PathBuf,
    /// The report: JSON, Markdown and the plot.
    pub report_json: PathBuf,
    /// Markdown.
    pub report_md: PathBuf,
    /// The plot.
    pub report_png: PathBuf,
    /// Per-epoch training record (CSV).
    pub training_csv: PathBuf,
}

/// The report as JSON: everything `report.md` shows.
pub fn json(fit: &Fit, held: &HeldOut, command: &str) -> serde_json::Value {
    let s = &fit.identified.sensors;
    serde_json::json!({
        "command": command,
        "passed": fit.report.warnings.is_empty(),
        "warnings": fit.report.warnings,
        "notes": fit.report.notes,
        "recordings": fit.recordings.iter().map(|(p, sha, span)| serde_json::json!({
            "path": p.display().to_string(), "sha256": sha, "estimated_s": span})).collect::<Vec<_>>(),
        "position_source": fit.identified.horizontal,
        "start": fit.start.key(),
        "passes": fit.identified.passes,
        "heave_on_depth": fit.identified.heave_on_depth,
        "heave_gains": fit.identified.heave_gains,
        "coefficients": fit.report.coefficients,
        "axes": fit.report.axes,
        "rms_residual": {"u": fit.identified.identification.rms_residual[0], "v": fit.identified.identification.rms_residual[1],
            "w": fit.identified.identification.rms_residual[2], "r": fit.identified.identification.rms_residual[3]},
        "sensors": {"depth_std_m": s.depth_std, "depth_delay_s": s.depth_delay, "heading_std_rad": s.heading_std,
            "yaw_rate_std_rad_s": s.yaw_rate_std, "defaulted": fit.identified.sensors_defaulted,
            "lag_method": fit.identified.lag_method.key(), "horizontal": fit.identified.horizontal_noise,
            "lag_scan": fit.identified.lag_scan.iter().map(|(l, v)| serde_json::json!({"lag_s": l, "residual": v})).collect::<Vec<_>>()},
        "training": {"epochs_run": fit.training.history.len(), "best_epoch": fit.training.best_epoch,
            "stop": fit.training.stop, "seconds": fit.training.seconds,
            "cut_by_time_cap": super::cut_by_time(&fit.training).is_some()},
        "held_out": held,
        "open_loop_depth": {"identified": fit.open_loop_depth.0, "reference": fit.open_loop_depth.1},
        "dataset": {"train": fit.identified.dataset.set("train").map_or(0, |s| s.count),
            "dev": fit.identified.dataset.set("dev").map_or(0, |s| s.count), "test": fit.identified.dataset.set("test").map_or(0, |s| s.count)},
    })
}

/// The report as Markdown.
pub fn markdown(fit: &Fit, held: &HeldOut, command: &str) -> String {
    let mut md = String::new();
    let verdict = if fit.report.warnings.is_empty() { "passed" } else { "FAILED: read the warnings" };
    md += &format!("# Fit report: {verdict}\n\n`{command}`\n\n");
    for (p, sha, span) in &fit.recordings {
        md +=
            &format!("- recording `{}` ({span:.0} s estimated, SHA-256 {})\n", p.display(), &sha[..12.min(sha.len())]);
    }
    md += &format!(
        "- position source: {}\n\n",
        if fit.identified.horizontal { "yes" } else { "none (depth, heading, yaw rate and the thrust only)" }
    );
    for w in &fit.report.warnings {
        md += &format!("**Warning** {w}\n\n");
    }
    for n in &fit.report.notes {
        md += &format!("Note: {n}\n\n");
    }
    md += "## Coefficients\n\n| coefficient | start | fitted | std. error | status |\n|---|---|---|---|---|\n";
    for c in &fit.report.coefficients {
        let se = c.std_err.map_or("-".to_string(), |s| format!("{s:.3e}"));
        md += &format!("| {} | {:.5} | {:.5} | {se} | {}: {} |\n", c.name, c.start, c.fitted, c.status, c.why);
    }
    md += "\n## Axes\n\n| axis | determined | why not |\n|---|---|---|\n";
    for a in &fit.report.axes {
        md += &format!("| {} | {} | {} |\n", a.axis, if a.determined { "yes" } else { "no" }, a.why);
    }
    if let Some(h) = &fit.identified.heave_on_depth {
        md += &heave_on_depth_markdown(h);
    }
    md += &format!(
        "\nEstimate-and-identify passes: {}. The filter's heave gain (the share of the applied heave force the \
         vehicle misses) {}; the heave equation took it in until under {}.\n",
        fit.identified.passes,
        fit.identified.heave_gains.iter().map(|g| format!("{g:.3}")).collect::<Vec<_>>().join(" -> "),
        super::HEAVE_GAIN_TOLERANCE
    );
    let s = &fit.identified.sensors;
    md += &format!(
        "\n## Sensors\n\ndepth noise {:.3} m, depth lag {:.2} s (the best of {} tried against {}), heading noise {:.4} rad, \
         yaw-rate noise {:.4} rad/s\n",
        s.depth_std,
        s.depth_delay,
        fit.identified.lag_scan.len(),
        fit.identified.lag_method.describe(),
        s.heading_std,
        s.yaw_rate_std
    );
    if let Some(h) = &fit.identified.horizontal_noise {
        md += &format!(
            "\nThe position source, measured from its readings as the others: position noise {:.3} m, NED velocity noise \
             {:.3} m/s (at least {} and {}), what the fit's estimator was told of them.\n",
            h.position_std,
            h.velocity_std,
            super::sensors::HORIZONTAL_NOISE_FLOOR[0],
            super::sensors::HORIZONTAL_NOISE_FLOOR[1]
        );
    }
    md += &held_out_markdown(fit, held);
    md += &open_loop_depth_markdown(fit);
    md += &format!(
        "\n## Training\n\n{} epochs run (best on dev: {}), {:.0} s.\n",
        fit.training.history.len(),
        fit.training.best_epoch,
        fit.training.seconds
    );
    md
}

/// The report's held-out section: RMS errors per quantity, the valid prediction times, and
/// the gain error per axis.
fn held_out_markdown(fit: &Fit, held: &HeldOut) -> String {
    let mut md = String::new();
    md += &format!(
        "\n## Held out ({} windows of {:.1} s, rolled out from {} against the smoothed estimate)\n\n| RMS error | {} |\n|---|{}\n",
        held.windows,
        held.window_s,
        fit.start.describe(),
        QUANTITIES.join(" | "),
        "---|".repeat(QUANTITIES.len())
    );
    let row = |name: &str, v: &[f64; 6]| {
        format!("| {name} | {} |\n", v.iter().map(|x| format!("{x:.4}")).collect::<Vec<_>>().join(" | "))
    };
    md += &row("identified physics", &held.physics_rms);
    md += &row("hybrid", &held.hybrid_rms);
    if let Some(r) = &held.reference {
        md += &row(&format!("reference `{}` (compared only)", r.file.display()), &r.rms);
    }
    md += &format!(
        "\nMean valid prediction time: physics {:.2} s, hybrid {:.2} s. Units: m, rad, m/s, rad/s. Plot: report.png.\n",
        held.physics_vpt_s, held.hybrid_vpt_s
    );
    md += &format!(
        "\nThe identified physics' velocity per axis against the held-out estimate: its gain error (the error regressed on \
         the velocity: how much too fast, or too slow if negative, it predicts the axis) shows a bias the standard errors \
         cannot; judged where the axis was fitted and driven at {MIN_HELD_OUT_SPEED} or more, at most {:.0} % either \
         way:\n\n| axis | RMS error | RMS velocity | gain error | judged |\n|---|---|---|---|---|\n",
        100.0 * MAX_GAIN_ERROR
    );
    for a in &held.axes {
        let verdict = judged_text(a.judged, a.biased);
        md += &format!(
            "| {} | {:.4} | {:.4} | {:+.1} % | {verdict} |\n",
            a.axis,
            a.rms_error,
            a.rms_velocity,
            100.0 * a.gain_error
        );
    }
    md
}

/// A check's verdict in a report's table.
fn judged_text(judged: bool, biased: bool) -> &'static str {
    match (judged, biased) {
        (false, _) => "no",
        (true, false) => "yes: within",
        (true, true) => "yes: BIASED",
    }
}

/// The heave as identified from the velocities and as fitted on the depth readings.
fn heave_on_depth_markdown(h: &super::heave_on_depth::HeaveOnDepth) -> String {
    let mut md = format!(
        "\nThe heave fitted on the depth readings ({} segments, {} readings, RMS {:.3} m against them), which the \
         vehicle takes, beside the identification's from the smoothed velocities:\n\n| coefficient | from the \
         velocities | on the depth | std. error |\n|---|---|---|---|\n",
        h.segments, h.readings, h.rms_m
    );
    for (i, key) in super::heave_on_depth::HEAVE_KEYS.iter().enumerate() {
        let se = h.std_err[i].map_or("not determined: the starting file's".to_string(), |s| format!("{s:.3e}"));
        md += &format!("| {key} | {:.5} | {:.5} | {se} |\n", h.from_velocities[i], h.fitted[i]);
    }
    md
}

/// The report's open-loop depth section: the identified vehicle's and the reference file's.
fn open_loop_depth_markdown(fit: &Fit) -> String {
    let (identified, reference) = &fit.open_loop_depth;
    let mut md = format!(
        "\n## Depth open loop ({} segments of {:.0} s, {} readings)\n\nEach segment rolled out from its start on the \
         recorded thrust alone, against the depth sensor's readings (not the estimate): the gain error is the error \
         regressed on the rollout's own move, how much too far (or too little, if negative) the vehicle is predicted to \
         move in depth; judged where the rollouts moved {} m or more, at most {:.0} % either way.\n\n| vehicle | RMS \
         error (m) | RMS move (m) | gain error | judged |\n|---|---|---|---|---|\n",
        identified.segments,
        identified.segment_s,
        identified.readings,
        super::open_loop_depth::MIN_DEPTH_MOVED_M,
        100.0 * super::open_loop_depth::MAX_DEPTH_GAIN_ERROR
    );
    let mut row = |name: String, c: &super::open_loop_depth::OpenLoopDepth| {
        let verdict = judged_text(c.judged, c.biased);
        md += &format!("| {name} | {:.3} | {:.3} | {:+.1} % | {verdict} |\n", c.rms_m, c.moved_m, 100.0 * c.gain_error);
    };
    row("identified".into(), identified);
    if let (Some(r), Some((file, _))) = (reference, &fit.reference) {
        row(format!("reference `{}` (compared only)", file.display()), r);
    }
    md
}

/// The training's epochs as CSV: rate, dev figures and which epoch was kept.
pub fn training_csv(training: &TrainOutcome) -> String {
    let mut csv = String::from("epoch,lr,dev_one_step_mse,dev_rollout10_mse,dev_vpt_s,best\n");
    for r in &training.history {
        csv += &format!(
            "{},{:e},{:e},{:e},{},{}\n",
            r.epoch,
            r.lr,
            r.dev_one_step,
            r.dev_rollout10,
            r.dev_vpt,
            u8::from(r.best)
        );
    }
    csv
}

/// Writes the fit's folder whole or not at all: built beside as `FOLDER.partial`, then
/// renamed over any earlier one.
///
/// # Errors
/// A file cannot be written.
pub fn write(fit: &Fit, folder: &Path, command: &str) -> Result<Written, FitError> {
    let partial = folder.with_extension("partial");
    let out = |path: &Path, e: String| FitError::Output { path: path.to_path_buf(), message: e };
    let _ = std::fs::remove_dir_all(&partial);
    std::fs::create_dir_all(&partial).map_err(|e| out(&partial, e.to_string()))?;
    let test = fit
        .identified
        .dataset
        .set("test")
        .filter(|s| s.count > 0)
        .ok_or_else(|| FitError::Data("the held-out split is empty: record longer".into()))?;
    let held = held_out(&fit.model, test, fit.reference.as_ref(), fit.identified.horizontal);
    let put = |name: &str, bytes: &[u8]| -> Result<(), FitError> {
        let p = partial.join(name);
        std::fs::write(&p, bytes).map_err(|e| out(&p, e.to_string()))
    };
    let header = format!(
        "# Fitted by `{command}`.\n# Coefficients the recordings did not determine keep the starting file's values \
         (report.md says which and why).\n"
    );
    let thrusters = fit.model.fitted.as_ref().map_or(String::new(), |f| f.thrusters_toml.clone());
    put("vehicle.toml", (header + &fit.identified.identification.vehicle.to_toml() + "\n" + &thrusters).as_bytes())?;
    put("model.pinc", &fit.model.to_bytes().map_err(|e| out(&partial.join("model.pinc"), e.to_string()))?)?;
    let json = serde_json::to_string_pretty(&json(fit, &held, command)).expect("JSON of plain values");
    put("report.json", json.as_bytes())?;
    put("report.md", markdown(fit, &held, command).as_bytes())?;
    put("training.csv", training_csv(&fit.training).as_bytes())?;
    plot(&partial.join("report.png"), &fit.model, test).map_err(|e| out(&partial.join("report.png"), e))?;
    if folder.exists() {
        std::fs::remove_dir_all(folder).map_err(|e| out(folder, e.to_string()))?;
    }
    std::fs::rename(&partial, folder).map_err(|e| out(folder, e.to_string()))?;
    Ok(Written {
        folder: folder.to_path_buf(),
        vehicle: folder.join("vehicle.toml"),
        model: folder.join("model.pinc"),
        report_json: folder.join("report.json"),
        report_md: folder.join("report.md"),
        report_png: folder.join("report.png"),
        training_csv: folder.join("training.csv"),
    })
}
