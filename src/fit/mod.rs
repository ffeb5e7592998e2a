//! `pinc fit`: an owner's recordings to a model of their vehicle that flies it (docs/FIT.md).
//!
//! One pipeline, in this order, each stage on the previous one's result:
//! 1. the recordings' MAVLink messages (or a `.BIN`'s streams) replayed through the state
//!    estimator on the starting vehicle file (a stock vehicle logs no velocities: the filter
//!    gives them);
//! 2. the estimate cut into windows and split in time (train, dev, held out), and the vehicle
//!    identified from the train split;
//! 3. the sensors: each reading's noise from the reading alone, the depth lag against the
//!    autopilot's vertical velocity where the recordings hold it, else from the heave equation
//!    on the readings and the applied force ([`sensors`]);
//! 4. the estimate and the identification again with the identified vehicle and the sensor
//!    model (the velocities of pass 1 came from a vehicle that was not this one); then the
//!    heave fitted on the depth readings themselves ([`heave_on_depth`]);
//! 5. the heave force the identified vehicle still misses, as the filter's heave gain
//!    estimates it, taken into its heave equation;
//! 6. a hybrid (the identified vehicle's step plus a correction anchored at rest) trained on
//!    a fixed number of epochs;
//! 7. the report: what the data determined per coefficient and per axis, physics and hybrid
//!    on the held-out part ([`report`]).
//!
//! Everything follows the seed and the epochs; nothing follows the wall clock but the
//! optional time cap, which the report names when it cut the training.
//!
//! Each stage is a module of its own, declared below in the order the pipeline runs them;
//! this file holds the entry points, [`fit`] and [`determinacy`].

pub mod heave_on_depth;
pub mod open_loop_depth;
pub mod report;
pub mod sensors;
pub mod watch;

// What a fit is given.
mod settings;
// Reading the recordings and the starting vehicle.
mod inputs;
// 1 and 4: the estimate and its windows.
mod estimate;
// 2: the identification.
mod identification;
// 3: the sensor model (the arithmetic in `sensors`).
mod sensor_model;
// 5: the heave gain.
mod heave_gain;
// 1-5 composed.
mod identified;
// 6: the hybrid's training (7 is `report`).
mod training;

pub use heave_gain::with_heave_gain;
pub use identified::Identified;
pub use sensor_model::LagMethod;
pub use settings::{FitSettings, FitStart};
pub use training::{cut_by_time, train_config};
// Where `report` takes them from.
use heave_gain::HEAVE_GAIN_TOLERANCE;
pub(crate) use identification::coefficient;

use crate::dataset::import::sha256_hex;
use crate::model::{FittedVehicle, PincModel};
use crate::train::{TrainOutcome, train};
use crate::vehicle::{Thrusters, VehicleParams};
use inputs::{Content, Log, read_recording, starting_vehicle};
use settings::check;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use training::splits;

/// The stages, for a progress display.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Reading the recordings.
    Read,
    /// Estimating the state on the starting vehicle.
    Estimate,
    /// Identifying the vehicle.
    Identify,
    /// Finding the depth lag (`n` candidates).
    SensorLag(usize),
    /// Estimating again on the identified vehicle and sensors.
    Refine,
    /// Training the hybrid for `epochs`.
    Train(usize),
    /// Writing the report.
    Report,
}

/// What the fit is doing, for a terminal or a page.
pub fn stage_text(stage: &Stage) -> String {
    match stage {
        Stage::Read => "reading the recordings".to_string(),
        Stage::Estimate => "estimating the state on the starting vehicle".into(),
        Stage::Identify => "identifying the vehicle".into(),
        Stage::SensorLag(n) => format!("finding the depth sensor's lag ({n} candidates)"),
        Stage::Refine => "estimating and identifying again on the fitted vehicle and sensors".into(),
        Stage::Train(_) => "training the hybrid".into(),
        Stage::Report => "writing the report".into(),
    }
}

/// Why a fit stopped.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// A setting is out of range.
    #[error("{0}")]
    Settings(String),
    /// A recording or the vehicle file could not be read or used.
    #[error("{path}: {message}")]
    Input {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The data cannot make a dataset or an identification.
    #[error("{0}")]
    Data(String),
    /// Training failed.
    #[error("training the hybrid: {0}")]
    Train(String),
    /// Writing the folder failed.
    #[error("{path}: {message}")]
    Output {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// What a fit produced (before it is written).
pub struct Fit {
    /// What the estimate-and-identify stages found: the vehicle, the sensors, the passes.
    pub identified: Identified,
    /// The hybrid, carrying the vehicle's thrusters and sensors.
    pub model: PincModel,
    /// How the training ended.
    pub training: TrainOutcome,
    /// The recordings: path, SHA-256, seconds estimated.
    pub recordings: Vec<(PathBuf, String, f64)>,
    /// The report's findings (the model's warnings among them).
    pub report: report::Findings,
    /// The reference vehicle file and its coefficients ([`FitSettings::reference`]).
    pub reference: Option<(PathBuf, VehicleParams)>,
    /// Where its predictions started ([`FitSettings::start`]).
    pub start: FitStart,
    /// The identified vehicle's depth open loop against the readings, and the reference
    /// file's on the same segments.
    pub open_loop_depth: (open_loop_depth::OpenLoopDepth, Option<open_loop_depth::OpenLoopDepth>),
}

/// The recordings and the starting vehicle a fit works on.
struct Pipeline<'a> {
    settings: &'a FitSettings,
    base: VehicleParams,
    thrusters: Thrusters,
    logs: Vec<Log>,
}

/// Whether the recording so far determines what the controller needs (a recording's watch,
/// `pinc vehicle excite`): the fit's stages 1-5 on `messages` (a `.tlog`'s or a live link's
/// MAVLink, in arrival order), then the report's findings per coefficient and axis.
///
/// # Errors
/// As [`fit`]'s first stages: too short a recording, a vehicle file that cannot be read.
pub fn determinacy(
    settings: &FitSettings,
    messages: Vec<(u64, u8, mavlink::dialects::ardupilotmega::MavMessage)>,
) -> Result<(report::Findings, Identified), FitError> {
    // The messages are the recording: the settings' list of files may be empty.
    check(settings)?;
    let (base, thrusters, _) = starting_vehicle(settings)?;
    let log =
        Log { path: PathBuf::from("(live)"), sha256: String::new(), content: Content::Mavlink(messages), cut: None };
    let pipeline = Pipeline { settings, base, thrusters, logs: vec![log] };
    let found = pipeline.identified(&mut |_| {})?;
    let mut findings = report::findings(&found.identification, &base, found.horizontal, &found.sensors_defaulted, None);
    findings.warnings.extend(found.bias_warnings());
    Ok((findings, found))
}

/// Runs the pipeline; `on_stage` hears of each stage, `on_epoch` of each training epoch.
///
/// # Errors
/// [`FitError`], naming the file or stage.
pub fn fit(
    settings: &FitSettings,
    interrupt: &AtomicBool,
    mut on_stage: impl FnMut(Stage),
    on_epoch: impl FnMut(&crate::train::EpochRecord),
) -> Result<Fit, FitError> {
    check(settings)?;
    if settings.recordings.is_empty() {
        return Err(FitError::Settings("no recording given".into()));
    }
    on_stage(Stage::Read);
    let (base, thrusters, thrusters_toml) = starting_vehicle(settings)?;
    let reference = match &settings.reference {
        Some(path) => Some((
            path.clone(),
            VehicleParams::load(path).map_err(|e| FitError::Input { path: path.clone(), message: e.to_string() })?,
        )),
        None => None,
    };
    let mut logs = Vec::new();
    for path in &settings.recordings {
        let input = |message: String| FitError::Input { path: path.clone(), message };
        let bytes = std::fs::read(path).map_err(|e| input(e.to_string()))?;
        let (content, cut) = read_recording(path, &thrusters, settings.water_density).map_err(input)?;
        logs.push(Log { path: path.clone(), sha256: sha256_hex(&bytes), content, cut });
    }
    let pipeline = Pipeline { settings, base, thrusters, logs };
    let found = pipeline.identified(&mut on_stage)?;

    // The hybrid on the identified vehicle.
    on_stage(Stage::Train(settings.epochs));
    let cfg = train_config(settings, found.identification.vehicle, found.horizontal);
    let (train_set, dev) = splits(&found.dataset)?;
    let source = format!(
        "pinc fit {}",
        settings.recordings.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" ")
    );
    let training =
        train(&cfg, train_set, dev, &source, interrupt, on_epoch).map_err(|e| FitError::Train(e.to_string()))?;

    on_stage(Stage::Report);
    let recordings: Vec<(PathBuf, String, f64)> = pipeline
        .logs
        .iter()
        .zip(&found.runs)
        .map(|(l, r)| {
            let span = r.smoothed.last().map_or(0.0, |s| s.t) - r.smoothed.first().map_or(0.0, |s| s.t);
            (l.path.clone(), l.sha256.clone(), span)
        })
        .collect();
    let mut findings =
        report::findings(&found.identification, &base, found.horizontal, &found.sensors_defaulted, Some(&training));
    findings.warnings.extend(found.bias_warnings());
    findings.notes.extend(found.heave_on_depth.iter().flat_map(|h| h.notes()));
    for (log, span) in pipeline.logs.iter().zip(&recordings) {
        if let Some(cut) = &log.cut {
            let line = format!("{}: {cut}; fitted from the {:.0} s it holds", log.path.display(), span.2);
            findings.notes.insert(0, line);
        }
    }
    let mut model = training.model.clone();
    // Timings stay out of the file: the same inputs give the same bytes.
    for key in ["train_seconds", "step_ms"] {
        model.provenance.metrics.remove(key);
    }
    model.fitted = Some(FittedVehicle { thrusters_toml, sensors: found.sensors, warnings: findings.warnings.clone() });
    let open_loop_depth = (found.open_loop_depth.clone(), reference.as_ref().map(|(_, p)| found.open_loop_depth_of(p)));
    Ok(Fit {
        identified: found,
        model,
        training,
        recordings,
        report: findings,
        reference,
        start: settings.start,
        open_loop_depth,
    })
}
