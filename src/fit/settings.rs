//! What a fit is given ([`FitSettings`]) and where its predictions start ([`FitStart`]), with
//! the check of the settings' numbers. Apart because it is the fit's interface: the command
//! line, the watch and the web page fill it, the stages only read it.

use super::FitError;
use std::path::PathBuf;

/// What a fit is given.
#[derive(Debug, Clone)]
pub struct FitSettings {
    /// The recordings: `.tlog`, pinc's MCAP (`pinc vehicle record` / `excite`) or an ArduPilot
    /// `.BIN`.
    pub recordings: Vec<PathBuf>,
    /// The starting vehicle file: its thrusters (kept), mass, inertia and the values of the
    /// coefficients the data cannot determine.
    pub vehicle: PathBuf,
    /// Sample period of the estimate, the dataset and the model (s).
    pub dt: f64,
    /// Points per window.
    pub window: usize,
    /// Fractions of train, dev and held-out time.
    pub split: [f64; 3],
    /// Seed of the split's collocation times, the network's initialisation and the batches.
    pub seed: u64,
    /// The hybrid's training budget.
    pub epochs: usize,
    /// A wall-clock cap on the training (s): it cuts the run short (the report says so) and
    /// changes nothing else.
    pub time_cap_s: Option<f64>,
    /// Hidden layers and width of the correction.
    pub layers: usize,
    /// Neurons per hidden layer.
    pub width: usize,
    /// Surface pressure (hPa) and water density (kg/m^3) for depth from pressure.
    pub surface_pressure: f64,
    /// Water density (kg/m^3).
    pub water_density: f64,
    /// A vehicle file scored on the same held-out windows, for comparison only (a simulator's
    /// own file, a model fitted before); nothing of it enters the fit.
    pub reference: Option<PathBuf>,
    /// Where each interval's and window's prediction starts, for the identification, the
    /// training and the held-out figures alike (the targets are the smoothed estimate either way).
    pub start: FitStart,
}

/// Where a fit's predictions start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum FitStart {
    /// The smoothed estimate: the same states as the targets (what the fit did before it had
    /// a choice).
    #[default]
    Smoothed,
    /// The filter's estimate as it was at that point, the causal one a controller starts from
    /// (nothing after the point went into it).
    Estimated,
}

impl FitStart {
    /// Its name in the report's JSON and on the command line.
    pub fn key(self) -> &'static str {
        match self {
            Self::Smoothed => "smoothed",
            Self::Estimated => "estimated",
        }
    }

    /// Where the report says its held-out rollouts start.
    pub fn describe(self) -> &'static str {
        match self {
            Self::Smoothed => "each window's smoothed first state",
            Self::Estimated => "the filter's estimate at each window's start, as a controller has it",
        }
    }
}

impl FitSettings {
    /// The defaults for `recordings` and `vehicle`.
    pub fn new(recordings: Vec<PathBuf>, vehicle: PathBuf) -> Self {
        Self {
            recordings,
            vehicle,
            dt: crate::DEFAULT_DT,
            window: 26,
            split: [0.7, 0.15, 0.15],
            seed: 0,
            epochs: 60,
            time_cap_s: None,
            layers: 2,
            width: 32,
            surface_pressure: 1013.25,
            water_density: 1000.0,
            reference: None,
            start: FitStart::Smoothed,
        }
    }
}

/// The settings' numbers (the recordings are checked where they are read).
pub(super) fn check(s: &FitSettings) -> Result<(), FitError> {
    let bad = |m: String| Err(FitError::Settings(m));
    if !(s.dt.is_finite() && s.dt > 0.0) {
        return bad(format!("--dt must be a positive number of seconds, got {}", s.dt));
    }
    if s.epochs == 0 {
        return bad("--epochs: at least one".into());
    }
    if s.layers == 0 || s.width == 0 {
        return bad("--layers and --width: at least one".into());
    }
    if s.time_cap_s.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
        return bad("--time-cap must be a positive number of minutes".into());
    }
    Ok(())
}
