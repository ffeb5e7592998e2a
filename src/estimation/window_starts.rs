//! Recorded windows started where a controller would start them: from the state its
//! estimator gives after running over the samples before the window, not from the recorded
//! state (whose body velocities a real log often gets wrong: a tank's recorded velocities
//! disagree with the motion of its recorded positions for half a second at a time).
//!
//! An imported dataset keeps each run's windows in order and back to back (each window's
//! first sample is the one before's last, docs/LOGS_CSV.md), so the samples before a window
//! are the windows before it in the same run. The estimator sees of each of them what a
//! vehicle measures and a recording holds: position, depth, heading and yaw rate, and the
//! input held over each interval; never the recorded body velocities. One filter runs along
//! each run, and a point's estimate is its prediction to that point's time from everything
//! earlier, before the point's own measurements (docs/MODEL.md 12.1).

use super::{Estimator, Measurement, NoiseSettings, white_noise_std};
use crate::dataset::TrajectorySet;
use crate::runtime::RuntimeError;
use crate::traits::DiscreteModel;
use crate::types::State;
use crate::vehicle::{to_network, to_simulator};
use serde::Serialize;

/// How much history a window's estimate is built from, by default (s): the filter starts
/// with its velocities unknown (0 within 0.3 m/s) and forgets that start within about a
/// second of positions (measured on generated runs, `tests/data/estimated_start.rs`).
pub const DEFAULT_HISTORY_S: f64 = 4.0;

/// The smallest sensor noise a noise estimate gives (m, rad): below it the filter would
/// follow the recording's rounding.
const NOISE_FLOOR: [f64; 3] = [0.002, 0.002, 0.002];

/// The filter's process noise on `u v w` (m/s) and `r` (rad/s) per sample.
const VELOCITY_PROCESS_STD: [f64; 4] = [0.1, 0.1, 0.1, 0.05];

/// What the estimated starts were built with, and what the set allowed.
#[derive(Debug, Clone, Serialize)]
pub struct StartSettings {
    /// Seconds of its run the filter must have fused before a point has an estimate.
    pub history_s: f64,
    /// The filter's noise: its position, depth and heading noise estimated from the set
    /// ([`StartSettings::from_set`]), its process noise on the velocities raised, the rest
    /// the live session's defaults.
    pub noise: NoiseSettings,
}

impl StartSettings {
    /// Settings for `set`: the position, depth and heading noise measured from the set's own
    /// samples ([`white_noise_std`], as `pinc fit` measures a vehicle's sensors), at least 2 mm
    /// or 2 mrad; the depth sensor taken without lag (its samples share the dataset's grid).
    pub fn from_set(set: &TrajectorySet, history_s: f64) -> Self {
        let noise = measured_noise(set);
        let default = NoiseSettings::default();
        let pick = |k: usize, fallback: f64| noise[k].map_or(fallback, |s| s.max(NOISE_FLOOR[k]));
        let mut settings = NoiseSettings {
            position_std: pick(0, default.position_std),
            depth_std: pick(1, default.depth_std),
            heading_std: pick(2, default.heading_std),
            depth_delay: 0.0,
            ..default
        };
        // The yaw rate of a recording is its attitude's: as trustworthy as the heading it
        // comes with, per second.
        settings.yaw_rate_std = settings.yaw_rate_std.max(settings.heading_std);
        // The model under judgement is not trusted to carry the velocities between samples:
        // 2-5 times the live session's process noise on u v w and r, so that the positions
        // set them (on the tank recordings the identified physics' mean VPT from these starts
        // is 0.61 s; with a fresh filter per window it was 0.58 s at the live session's noise
        // and 0.62 s at twice this).
        for k in 4..8 {
            settings.process_std[k] = VELOCITY_PROCESS_STD[k - 4];
        }
        Self { history_s, noise: settings }
    }
}

/// A set's windows that the estimator could start, twice: as recorded, and with every point's
/// estimate as its start ([`TrajectorySet::starts`]).
#[derive(Debug, Clone)]
pub struct EstimatedStarts {
    /// The windows with an estimate at every point, as recorded.
    pub recorded: TrajectorySet,
    /// The same windows, each point's estimate in `starts`.
    pub estimated: TrajectorySet,
    /// Windows left out: less than [`StartSettings::history_s`] of their run before them.
    pub without_history: usize,
}

/// `set`'s windows started from the estimator's state at every point
/// ([`estimate_point_starts`]), beside the same windows as recorded.
///
/// # Errors
/// The model failed on the estimate (non-finite values).
pub fn with_estimated_starts<M: DiscreteModel + Clone>(
    model: &M,
    set: &TrajectorySet,
    settings: &StartSettings,
) -> Result<EstimatedStarts, RuntimeError> {
    with_estimated_starts_and_targets(model, set, settings, Targets::Recorded)
}

/// What a training set's states (its targets) are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Targets {
    /// As recorded.
    Recorded,
    /// The body velocities and yaw rate (`u v w r`) replaced by the run's smoothed estimate
    /// ([`smoothed_points`]), the positions, depth and heading as recorded: velocities that
    /// agree with the recorded motion.
    Smoothed,
}

/// [`with_estimated_starts`], the estimated set's targets as `targets` asks.
///
/// # Errors
/// The model failed on the estimate (non-finite values).
pub fn with_estimated_starts_and_targets<M: DiscreteModel + Clone>(
    model: &M,
    set: &TrajectorySet,
    settings: &StartSettings,
    targets: Targets,
) -> Result<EstimatedStarts, RuntimeError> {
    let (points, smoothed) = run_filters(model, set, settings, targets == Targets::Smoothed)?;
    // A window's first point has the least history: where it has an estimate, all do.
    let keep: Vec<usize> = (0..set.count).filter(|&i| points[i * set.points].is_some()).collect();
    let recorded = subset(set, &keep);
    let mut estimated = recorded.clone();
    estimated.starts = keep
        .iter()
        .flat_map(|&i| &points[i * set.points..(i + 1) * set.points])
        .map(|s| s.expect("every point after a window's first has more history"))
        .collect();
    if targets == Targets::Smoothed {
        let smoothed: Vec<State> = keep
            .iter()
            .flat_map(|&i| &smoothed[i * set.points..(i + 1) * set.points])
            .map(|s| s.expect("a point with a filtered estimate has a smoothed one"))
            .collect();
        for (x, s) in estimated.states.iter_mut().zip(&smoothed) {
            for c in 5..crate::types::NX {
                x[c] = s[c];
            }
        }
    }
    Ok(EstimatedStarts { recorded, estimated, without_history: set.count - keep.len() })
}

/// The windows of `set` chosen by `keep`, in that order.
fn subset(set: &TrajectorySet, keep: &[usize]) -> TrajectorySet {
    let (n, c) = (set.points - 1, set.collocation_points);
    let mut out = TrajectorySet {
        name: set.name.clone(),
        dt: set.dt,
        count: keep.len(),
        points: set.points,
        collocation_points: c,
        states: Vec::with_capacity(keep.len() * set.points),
        inputs: Vec::with_capacity(keep.len() * n),
        collocation: Vec::with_capacity(keep.len() * n * c),
        starts: Vec::new(),
    };
    for &i in keep {
        let (s, u) = set.trajectory(i);
        out.states.extend_from_slice(s);
        out.inputs.extend_from_slice(u);
        out.collocation.extend_from_slice(&set.collocation[i * n * c..(i + 1) * n * c]);
    }
    out
}

/// Whether window `i` continues window `i - 1` (its first sample is that one's last, exactly).
fn continues(set: &TrajectorySet, i: usize) -> bool {
    i > 0 && set.trajectory(i - 1).0.last() == set.trajectory(i).0.first()
}

/// The white noise ([`white_noise_std`]) of the horizontal position (the larger of north and
/// east), the depth and the heading, over each run's samples in time order (`None` where a
/// set has too few).
fn measured_noise(set: &TrajectorySet) -> [Option<f64>; 3] {
    let mut series: [Vec<(f64, f64)>; 4] = Default::default();
    let mut t = 0.0;
    for i in 0..set.count {
        let (s, _) = set.trajectory(i);
        // A window that continues the one before repeats its first sample: left out. One that
        // starts a run is set a second apart (the few samples whose neighbours straddle two
        // runs are outliers the median ignores).
        let skip = usize::from(continues(set, i));
        if skip == 0 {
            t += 1.0;
        }
        for x in &s[skip..] {
            let sim = to_simulator(x);
            for (c, v) in series.iter_mut().zip([sim[0], sim[1], sim[2], sim[3]]) {
                c.push((t, v));
            }
            t += set.dt;
        }
    }
    let std = |k: usize, wrap: bool| white_noise_std(&series[k], wrap);
    let horizontal = match (std(0, false), std(1, false)) {
        (Some(a), Some(b)) => Some(a.max(b)),
        _ => None,
    };
    [horizontal, std(2, false), std(3, true)]
}

/// What the estimator knows at every point of every window of `set` before that point's own
/// measurements, as a controller's filter runs: one filter per run (its windows in order),
/// fed each sample's position, depth, heading and yaw rate at its time and the input held
/// over each interval, and read at each sample's time just before that sample is fused (its
/// prediction from everything earlier). `None` for the points with less than
/// [`StartSettings::history_s`] of the run before them. Indexed as `set.states`.
///
/// # Errors
/// The model failed on the estimate (non-finite values).
pub fn estimate_point_starts<M: DiscreteModel + Clone>(
    model: &M,
    set: &TrajectorySet,
    settings: &StartSettings,
) -> Result<Vec<Option<State>>, RuntimeError> {
    Ok(run_filters(model, set, settings, false)?.0)
}

/// The same filters' estimates smoothed backward over each run (its every sample fused, the
/// later ones included): the velocities that agree with the positions around a point, for a
/// target rather than a start. Indexed as `set.states`; `None` where
/// [`estimate_point_starts`] has none.
///
/// # Errors
/// The model failed on the estimate (non-finite values).
pub fn smoothed_points<M: DiscreteModel + Clone>(
    model: &M,
    set: &TrajectorySet,
    settings: &StartSettings,
) -> Result<Vec<Option<State>>, RuntimeError> {
    Ok(run_filters(model, set, settings, true)?.1)
}

/// One filter per run: each point's prediction before its own measurements, and with
/// `smooth` the run's smoothed estimate there.
#[allow(clippy::type_complexity)] // two per-point lists
fn run_filters<M: DiscreteModel + Clone>(
    model: &M,
    set: &TrajectorySet,
    settings: &StartSettings,
    smooth: bool,
) -> Result<(Vec<Option<State>>, Vec<Option<State>>), RuntimeError> {
    let dt = set.dt;
    let needed = (settings.history_s / dt - 1e-9).ceil().max(1.0) as usize;
    let mut out = vec![None; set.states.len()];
    let mut smoothed = vec![None; if smooth { set.states.len() } else { 0 }];
    let mut filter: Option<Estimator<M>> = None;
    // The current run's points with their sample index in the run (its time over dt).
    let mut run_points: Vec<(usize, usize)> = Vec::new();
    // Samples fused in the current run; the run's time is `fused dt`.
    let mut fused = 0usize;
    for i in 0..set.count {
        if !continues(set, i) {
            if let Some(f) = filter.take() {
                smooth_run(&f, &run_points, dt, &out, &mut smoothed);
            }
            let fresh = Estimator::new(model.clone(), settings.noise.clone());
            filter = Some(if smooth { fresh.keep_history() } else { fresh });
            run_points.clear();
            fused = 0;
        }
        let f = filter.as_mut().expect("the first window starts a run");
        let (xs, us) = set.trajectory(i);
        // A window that continues the one before begins with that one's last sample, which
        // the filter has not fused yet (each window fuses its points but the last).
        for k in 0..xs.len() {
            let t = fused as f64 * dt;
            let before = f.advance(t)?;
            if fused >= needed {
                out[i * set.points + k] = before.map(|e| to_network(&e.sim));
            }
            run_points.push((i * set.points + k, fused));
            if k + 1 == xs.len() {
                break;
            }
            let s = to_simulator(&xs[k]);
            f.measure(Measurement::Position { t, x: s[0], y: s[1], z: f64::NAN });
            f.measure(Measurement::Depth { t, z: s[2] });
            f.measure(Measurement::Heading { t, psi: s[3] });
            f.measure(Measurement::YawRate { t, r: s[7] });
            f.advance(t)?;
            // Reported halfway through the interval it is held over: the step to the next
            // sample averages exactly this input.
            f.applied(t + 0.5 * dt, us[k]);
            fused += 1;
        }
    }
    if let Some(f) = filter.take() {
        smooth_run(&f, &run_points, dt, &out, &mut smoothed);
    }
    Ok((out, smoothed))
}

/// The smoothed estimate at each of a run's points that has a filtered one (none where the
/// filter kept no history).
fn smooth_run<M: DiscreteModel>(
    f: &Estimator<M>,
    points: &[(usize, usize)],
    dt: f64,
    filtered: &[Option<State>],
    out: &mut [Option<State>],
) {
    if out.is_empty() {
        return;
    }
    // The filter starts at the run's first sample and steps once per sample.
    let mut by_sample = vec![None; points.last().map_or(0, |p| p.1 + 1)];
    for s in f.smoothed() {
        let k = (s.t / dt).round() as usize;
        if let Some(slot) = by_sample.get_mut(k) {
            *slot = Some(to_network(&crate::types::SimState::from_fn(|c, _| s.state[c])));
        }
    }
    for &(at, sample) in points {
        if filtered[at].is_some() {
            out[at] = by_sample[sample];
        }
    }
}

/// Why a dataset's windows cannot start from estimates.
#[derive(Debug, Clone, thiserror::Error)]
pub enum StartError {
    /// A file behind the set recorded no position: its `x, y` were dead-reckoned from the
    /// very velocities an estimated start is meant to replace.
    #[error(
        "{file} has no position stream (its x, y were integrated from its velocities): an estimated start needs \
         recorded positions"
    )]
    NoPositions {
        /// The file, as imported.
        file: String,
    },
    /// The estimator's model failed on the estimate.
    #[error("the estimator: {0}")]
    Estimator(#[from] RuntimeError),
    /// A history that is not a positive number of seconds.
    #[error("the history before each window must be a positive number of seconds, got {0}")]
    BadHistory(f64),
    /// No window has enough samples before it.
    #[error(
        "none of the {windows} windows has {history_s} s of samples before it in its run (windows of generated \
         sets stand alone; an imported run's first windows have none)"
    )]
    NoHistory {
        /// Windows in the set.
        windows: usize,
        /// The history asked for (s).
        history_s: f64,
    },
}

/// Refuses a set whose recordings hold no positions (read from the import report of every
/// file whose windows went to `set_name`); a generated set has its true positions.
///
/// # Errors
/// [`StartError::NoPositions`], naming the first such file.
pub fn check_positions(data: &crate::dataset::Dataset, set_name: &str) -> Result<(), StartError> {
    let Some(source) = &data.source else { return Ok(()) };
    let feeding = source.files.iter().filter(|f| f.split == set_name || f.split == "time");
    for f in feeding {
        if !f.report.streams.iter().any(|s| s.name == "position") {
            return Err(StartError::NoPositions { file: f.path.clone() });
        }
    }
    Ok(())
}

/// The set `set_name` of `data` started from the estimator on the analytic model of
/// `vehicle` ([`with_estimated_starts`]), with the settings measured from it: what `pinc eval`,
/// `pinc train` and `pinc identify` run for `--start estimated`.
///
/// # Errors
/// Recordings without positions, a bad history, no window with enough history, or the
/// estimator's failure.
pub fn estimated_set(
    data: &crate::dataset::Dataset,
    set: &TrajectorySet,
    vehicle: &crate::vehicle::VehicleParams,
    history_s: f64,
    targets: Targets,
) -> Result<(EstimatedStarts, StartSettings), StartError> {
    if !(history_s.is_finite() && history_s > 0.0) {
        return Err(StartError::BadHistory(history_s));
    }
    check_positions(data, &set.name)?;
    let settings = StartSettings::from_set(set, history_s);
    let model = crate::vehicle::Rk4Vehicle { params: *vehicle, ..crate::vehicle::Rk4Vehicle::with_dt(set.dt) };
    let starts = with_estimated_starts_and_targets(&model, set, &settings, targets)?;
    if starts.without_history == set.count {
        return Err(StartError::NoHistory { windows: set.count, history_s });
    }
    Ok((starts, settings))
}

impl StartSettings {
    /// One line of what the estimator assumed, and what of `set` it could start.
    pub fn describe(&self, starts: &EstimatedStarts) -> String {
        let n = &self.noise;
        format!(
            "estimated starts on {}: {} of {} windows ({} without {} s of samples before them); the estimator \
             assumed position noise {:.4} m, depth {:.4} m, heading {:.4} rad (measured from the set), no depth lag",
            starts.recorded.name,
            starts.recorded.count,
            starts.recorded.count + starts.without_history,
            starts.without_history,
            self.history_s,
            n.position_std,
            n.depth_std,
            n.heading_std
        )
    }
}
