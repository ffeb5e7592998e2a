//! Recorded windows started where a controller would start them: from the state its
//! estimator gives after running over the samples before the window, not from the recorded
//! state (whose body velocities a real log often gets wrong: a tank's recorded velocities
//! disagree with the motion of its recorded positions for half a second at a time).
//!
//! An imported dataset keeps each run's windows in order and back to back (each window's
//! first sample is the one before's last, docs/LOGS_CSV.md), so the samples before a window
//! are the windows before it in the same run. The estimator sees of each of them what a
//! vehicle measures and a recording holds: position, depth, heading and yaw rate, and the
//! input held over each interval; never the recorded body velocities, and nothing of the
//! window itself: the start is the filter's prediction to the window's first time.

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
    /// Seconds of samples run through the filter before each window.
    pub history_s: f64,
    /// The filter's noise: its position, depth and heading noise estimated from the set
    /// ([`StartSettings::from_set`]), the rest the live session's defaults.
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
        // was 0.58 s at the live session's noise, 0.61 s here, 0.62 s at twice this).
        for k in 4..8 {
            settings.process_std[k] = VELOCITY_PROCESS_STD[k - 4];
        }
        Self { history_s, noise: settings }
    }
}

/// Each window's estimated start, and what could not be estimated.
#[derive(Debug, Clone)]
pub struct WindowStarts {
    /// Per window: the estimated start (network form), or `None` where the run had fewer
    /// than [`StartSettings::history_s`] of samples before it.
    pub starts: Vec<Option<State>>,
    /// Windows with too little history before them.
    pub without_history: usize,
}

impl WindowStarts {
    /// The windows that have an estimate, as two sets over the same windows: their recorded
    /// starts as they are, and the same windows started from the estimates.
    pub fn split_sets(&self, set: &TrajectorySet) -> (TrajectorySet, TrajectorySet) {
        let keep: Vec<usize> = (0..set.count).filter(|&i| self.starts[i].is_some()).collect();
        let recorded = subset(set, &keep);
        let mut estimated = recorded.clone();
        for (j, &i) in keep.iter().enumerate() {
            estimated.states[j * set.points] = self.starts[i].expect("kept windows have an estimate");
        }
        estimated.name = format!("{} (estimated starts)", set.name);
        (recorded, estimated)
    }
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

/// The estimated start of every window of `set` on `model`: a fresh filter per window, fed
/// the `history_s` of samples before it (its position, depth, heading and yaw rate at each
/// sample's time, the held input over each interval), then predicted to the window's first
/// time without its measurements.
///
/// # Errors
/// The model failed on the estimate (non-finite values).
pub fn estimate_starts<M: DiscreteModel + Clone>(
    model: &M,
    set: &TrajectorySet,
    settings: &StartSettings,
) -> Result<WindowStarts, RuntimeError> {
    let dt = set.dt;
    let needed = (settings.history_s / dt).ceil().max(1.0) as usize;
    let intervals = set.points - 1;
    let mut starts = Vec::with_capacity(set.count);
    // Samples of the current run before window i: (state, input held after it), oldest first.
    let mut history: Vec<(State, crate::types::Input)> = Vec::new();
    for i in 0..set.count {
        if !continues(set, i) {
            history.clear();
        }
        if history.len() < needed {
            starts.push(None);
        } else {
            let recent = &history[history.len() - needed..];
            starts.push(Some(run_filter(model, recent, dt, &settings.noise)?));
        }
        let (s, u) = set.trajectory(i);
        history.extend((0..intervals).map(|k| (s[k], u[k])));
    }
    let without_history = starts.iter().filter(|s| s.is_none()).count();
    Ok(WindowStarts { starts, without_history })
}

/// The filter over `samples` (sample `k` at `k dt`, its input held to the next), predicted
/// to the time after the last one.
fn run_filter<M: DiscreteModel + Clone>(
    model: &M,
    samples: &[(State, crate::types::Input)],
    dt: f64,
    noise: &NoiseSettings,
) -> Result<State, RuntimeError> {
    let mut filter = Estimator::new(model.clone(), noise.clone());
    for (k, (x, u)) in samples.iter().enumerate() {
        let t = k as f64 * dt;
        let s = to_simulator(x);
        filter.measure(Measurement::Position { t, x: s[0], y: s[1], z: f64::NAN });
        filter.measure(Measurement::Depth { t, z: s[2] });
        filter.measure(Measurement::Heading { t, psi: s[3] });
        filter.measure(Measurement::YawRate { t, r: s[7] });
        filter.advance(t)?;
        // Reported halfway through the interval it is held over: the step to the next
        // sample averages exactly this input.
        filter.applied(t + 0.5 * dt, *u);
    }
    let end = samples.len() as f64 * dt;
    let estimate = filter.advance(end)?.expect("the filter started on the first sample's heading, yaw rate and depth");
    Ok(to_network(&estimate.sim))
}

/// Why a dataset's windows cannot start from estimates.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
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
