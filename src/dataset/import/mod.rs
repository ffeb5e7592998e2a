//! Datasets from recorded runs (docs/MODEL.md section 9): CSV files or the MCAP logs
//! `mpc_track` writes, resampled to the model's sample period, cut into windows and split
//! into train / dev / test by run, stored exactly like a generated dataset.

mod csv_log;
mod mcap_log;
mod ros2;
mod streams;
mod windows;

pub use csv_log::read_csv;
pub use mcap_log::{McapTopics, read_mcap};
pub use ros2::{BodyFrame, CommandsToInput, Ros2Options, WorldFrame, read_ros2};
pub use streams::{Series, StreamSet};
pub use windows::{SkipCounts, cut_windows};

use super::{Dataset, DatasetPreset, Excitation, InitialRanges, SetSpec, TrajectorySet};
use crate::types::{Input, NS, SimState};
use crate::vehicle::VehicleParams;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// One recorded run: time stamps, simulator-form states and the inputs held from each row to
/// the next, row by row as recorded (rows with NaN or gaps are kept; windowing skips them).
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The file it came from.
    pub path: PathBuf,
    /// Time stamps (s).
    pub t: Vec<f64>,
    /// `[x, y, z, psi, u, v, w, r]` per row.
    pub states: Vec<SimState>,
    /// `[X, Y, Z, Mz]` per row, held until the next row.
    pub inputs: Vec<Input>,
}

/// What can go wrong while importing: every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file's content is not what the format requires.
    #[error("{path}: {message}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong and where (line, topic, field).
        message: String,
    },
    /// The options or the runs together cannot make the requested dataset.
    #[error("{0}")]
    Unusable(String),
}

/// The options of an import, recorded in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImportOptions {
    /// `csv`, `mcap`, or both (`csv+mcap`) for a mix chosen by extension.
    pub format: String,
    /// Sample period of the dataset (s).
    pub dt: f64,
    /// Points per window (intervals + 1).
    pub window: usize,
    /// Fractions of train, dev and test.
    pub split: [f64; 3],
    /// Seed of the run shuffle and the collocation times.
    pub seed: u64,
    /// Collocation times per interval of the train split (as the presets: 1 is `t = dt`).
    pub collocation_points: usize,
    /// The topics and fields read from MCAP logs.
    pub topics: Option<McapTopics>,
}

impl ImportOptions {
    /// Checks the numbers before any file is read.
    ///
    /// # Errors
    /// A non-positive period, a window under 2 points, fractions that are negative, do not
    /// sum to 1 or leave train or test empty.
    pub fn check(&self) -> Result<(), ImportError> {
        let bad = |m: String| Err(ImportError::Unusable(m));
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return bad(format!("--dt must be a positive number of seconds, got {}", self.dt));
        }
        if self.window < 2 {
            return bad(format!("--window must be at least 2 points, got {}", self.window));
        }
        let [tr, dev, test] = self.split;
        if self.split.iter().any(|f| !(f.is_finite() && *f >= 0.0)) || ((tr + dev + test) - 1.0).abs() > 1e-6 {
            return bad(format!("--split: three non-negative fractions summing to 1, got {tr},{dev},{test}"));
        }
        if tr == 0.0 || test == 0.0 {
            return bad("--split: the train and test fractions must be positive".into());
        }
        Ok(())
    }
}

/// One imported file in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceFile {
    /// The path as given.
    pub path: String,
    /// SHA-256 of its bytes (hex, as `sha256sum` prints it).
    pub sha256: String,
    /// Rows read.
    pub rows: usize,
    /// Windows cut from it.
    pub windows: usize,
    /// The split its windows went to (`train`, `dev`, `test`, or `time` when every run was
    /// split by time).
    pub split: String,
}

/// Where an imported dataset came from: written into its manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImportSource {
    /// The files, in the order given.
    pub files: Vec<SourceFile>,
    /// The options.
    pub options: ImportOptions,
    /// `run` (whole runs per split) or `time` (each run split by time, one window apart).
    pub split_by: String,
    /// Samples that went into no window, by reason.
    pub skipped: SkipCounts,
}

/// Builds the dataset from recorded runs: windows per run, split, collocation times.
///
/// # Errors
/// No run long enough for one window, a log period that is not `dt` or an integer fraction
/// of it, or a split left empty.
pub fn import(recordings: &[Recording], hashes: &[String], options: &ImportOptions) -> Result<Dataset, ImportError> {
    options.check()?;
    let mut per_run = Vec::with_capacity(recordings.len());
    let mut skipped = SkipCounts::default();
    for rec in recordings {
        let (windows, skips) = cut_windows(rec, options.dt, options.window)?;
        skipped.add(&skips);
        per_run.push(windows);
    }
    let total: usize = per_run.iter().map(Vec::len).sum();
    if total == 0 {
        return Err(ImportError::Unusable(format!(
            "no run holds a window of {} points ({} s) without a gap or NaN; {}",
            options.window,
            (options.window - 1) as f64 * options.dt,
            skipped
        )));
    }
    let assignment = windows::split(&per_run, options.split, options.seed);
    let names = ["train", "dev", "test"];
    for (i, name) in names.iter().enumerate() {
        if options.split[i] > 0.0 && assignment.windows[i].is_empty() {
            return Err(ImportError::Unusable(format!(
                "the {name} split is empty: {total} windows of {} points from {} runs are too few for --split {:?}",
                options.window,
                recordings.len(),
                options.split
            )));
        }
    }
    let mut sets = Vec::new();
    let mut specs = Vec::new();
    for (i, name) in names.iter().enumerate() {
        let colloc = if i == 0 { options.collocation_points } else { 0 };
        let ws = &assignment.windows[i];
        let mut set = TrajectorySet {
            name: name.to_string(),
            dt: options.dt,
            count: ws.len(),
            points: options.window,
            collocation_points: colloc,
            states: Vec::with_capacity(ws.len() * options.window),
            inputs: Vec::with_capacity(ws.len() * (options.window - 1)),
            collocation: Vec::new(),
        };
        for w in ws {
            set.states.extend(w.states.iter().map(crate::vehicle::to_network));
            set.inputs.extend_from_slice(&w.inputs);
        }
        set.collocation =
            super::generate::collocation_times(options.seed, name, ws.len() * (options.window - 1), colloc, options.dt);
        specs.push(SetSpec {
            name: name.to_string(),
            count: set.count,
            points: set.points,
            dt: set.dt,
            initial: initial_ranges(ws),
            excitation: Excitation::Recorded,
            paper_scaling: false,
            collocation_points: colloc,
        });
        sets.push(set);
    }
    let files = recordings
        .iter()
        .zip(hashes)
        .enumerate()
        .map(|(r, (rec, sha))| SourceFile {
            path: rec.path.display().to_string(),
            sha256: sha.clone(),
            rows: rec.t.len(),
            windows: per_run[r].len(),
            split: assignment.run_split[r].to_string(),
        })
        .collect();
    let source = ImportSource {
        files,
        options: options.clone(),
        split_by: if assignment.by_run { "run" } else { "time" }.into(),
        skipped,
    };
    // The vehicle is unknown: the manifest keeps the BlueROV2 only because the field is
    // required; training and evaluation take the vehicle from --vehicle or the model.
    let preset = DatasetPreset { name: "import".into(), sets: specs, vehicle: VehicleParams::default() };
    Ok(Dataset { preset, seed: options.seed, sets, source: Some(source) })
}

/// The box of the windows' initial states (what a preset's `initial` describes).
fn initial_ranges(windows: &[windows::Window]) -> InitialRanges {
    let mut r = InitialRanges { lo: [f64::INFINITY; NS], hi: [f64::NEG_INFINITY; NS] };
    for w in windows {
        for i in 0..NS {
            r.lo[i] = r.lo[i].min(w.states[0][i]);
            r.hi[i] = r.hi[i].max(w.states[0][i]);
        }
    }
    if windows.is_empty() {
        r = InitialRanges { lo: [0.0; NS], hi: [0.0; NS] };
    }
    r
}

/// SHA-256 of `bytes` as lowercase hex (what `sha256sum` prints).
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}
