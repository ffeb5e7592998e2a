//! Datasets from recorded runs (docs/MODEL.md section 9): CSV files or the MCAP logs
//! `mpc_track` writes, resampled to the model's sample period, cut into windows and split
//! into train / dev / test by run, stored exactly like a generated dataset.

mod ardupilot;
mod csv_log;
mod csv_mapping;
mod csv_rows;
mod dataflash;
mod mcap_cut;
mod mcap_log;
mod resample;
mod ros2;
mod streams;
mod tlog;
mod windows;

pub use super::source::{ImportOptions, ImportSource, McapTopics, SkipCounts, SourceFile, StreamInfo, StreamReport};
pub use ardupilot::{
    ArdupilotOptions, BLUEROV2_VECTORED_MIX, InputSource, ThrusterConversion, manual_control_axes, pilot_to_pwm,
};
pub use csv_log::read_csv;
pub use csv_mapping::{
    AngleUnit, CsvMapping, HeadingFrame, HeadingMapping, InputMapping, PositionMapping, QUATERNION_NORM_TOLERANCE,
    QuaternionOrder, TimeMapping, TimeUnit, VelocityAxes, VelocityMapping, YawRateMapping, load_mapping,
    read_mapped_csv,
};
pub use dataflash::read_bin;
pub use mcap_cut::Cut as McapCut;
pub use mcap_log::read_mcap;
pub use resample::{default_gap_tolerance, log_dt, ned_to_body, resample, stream_set_of};
pub use ros2::{Ros2Options, read_ros2};
pub use streams::{BodyFrame, CommandsToInput, Series, StreamSet, WorldFrame};
#[cfg(feature = "vehicle")]
pub use tlog::mcap_messages;
pub use tlog::{TlogMessages, mavlink_log, read_tlog, tlog_messages};
pub use windows::cut_windows;

use super::{Dataset, DatasetPreset, Excitation, InitialRanges, SetSpec, TrajectorySet};
use crate::types::{Input, NS, SimState};
use crate::vehicle::VehicleParams;
use std::path::PathBuf;

/// One log as read: its streams, its path and the SHA-256 of its bytes.
#[derive(Debug, Clone)]
pub struct LogFile {
    /// The file.
    pub path: PathBuf,
    /// SHA-256 of its bytes (hex).
    pub sha256: String,
    /// What the reader found in it.
    pub streams: StreamSet,
}

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
    /// What the reader noticed (a torn last line skipped), for the import report.
    pub notes: Vec<String>,
}

impl Recording {
    /// An empty recording of `path`, for a reader to fill.
    pub fn empty(path: &std::path::Path) -> Self {
        Self { path: path.to_path_buf(), t: Vec::new(), states: Vec::new(), inputs: Vec::new(), notes: Vec::new() }
    }
}

/// A log's format extension in lower case, looking through the `.partial` a recording is
/// written under until it is finished (`pool.mcap.partial` is an `mcap`): a session cut off
/// leaves that name, and what it holds is read.
pub fn log_extension(path: &std::path::Path) -> Option<String> {
    let name = path.file_name()?.to_str()?.to_ascii_lowercase();
    let name = name.strip_suffix(".partial").unwrap_or(&name);
    name.rsplit_once('.').map(|(_, ext)| ext.to_string())
}

/// The bytes the manifest's SHA-256 covers: the file's, or for a bag folder every file in
/// it, in name order.
pub fn file_bytes(path: &std::path::Path) -> std::io::Result<Vec<u8>> {
    if !path.is_dir() {
        return std::fs::read(path);
    }
    let mut files: Vec<std::path::PathBuf> =
        std::fs::read_dir(path)?.map(|e| e.map(|e| e.path())).collect::<Result<_, _>>()?;
    files.retain(|f| f.is_file());
    files.sort();
    let mut bytes = Vec::new();
    for f in files {
        bytes.extend(std::fs::read(f)?);
    }
    Ok(bytes)
}

/// True if the MCAP file's summary lists a channel with CDR messages (a ROS 2 bag); a file
/// that cannot be read says no here and gets its error from the reader.
pub fn mcap_is_cdr(path: &std::path::Path) -> bool {
    let Ok(bytes) = std::fs::read(path) else { return false };
    match mcap::Summary::read(&bytes) {
        Ok(Some(summary)) => summary.channels.values().any(|c| c.message_encoding == "cdr"),
        _ => false,
    }
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

impl ImportOptions {
    /// Checks the numbers before any file is read.
    ///
    /// # Errors
    /// A non-positive period or gap tolerance, a window under 2 points, fractions that are
    /// negative, do not sum to 1 or are all zero (a zero train or dev fraction is allowed:
    /// a folder of held-out runs is `0,0,1`).
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
        if let Some(g) = self.gap_tolerance.filter(|g| !(g.is_finite() && *g > 0.0)) {
            return bad(format!("--gap-tolerance must be a positive number of seconds, got {g}"));
        }
        Ok(())
    }
}

/// Builds the dataset from row-aligned recordings (CSV, MCAP): each goes through
/// [`stream_set_of`] and [`import_logs`], so a log at any rate is resampled to `dt`.
///
/// # Errors
/// As [`import_logs`].
pub fn import(recordings: &[Recording], hashes: &[String], options: &ImportOptions) -> Result<Dataset, ImportError> {
    let logs: Vec<LogFile> = recordings
        .iter()
        .zip(hashes)
        .map(|(rec, sha)| LogFile { path: rec.path.clone(), sha256: sha.clone(), streams: stream_set_of(rec) })
        .collect();
    import_logs(&logs, options)
}

/// Builds the dataset from logs: each resampled to `dt` ([`resample`]), cut into windows,
/// split, with collocation times.
///
/// # Errors
/// A log whose streams cannot make the state, no run long enough for one window, or a split
/// with a positive fraction left empty.
pub fn import_logs(logs: &[LogFile], options: &ImportOptions) -> Result<Dataset, ImportError> {
    options.check()?;
    let mut per_run = Vec::with_capacity(logs.len());
    let mut reports = Vec::with_capacity(logs.len());
    let mut rows = Vec::with_capacity(logs.len());
    let mut skipped = SkipCounts::default();
    for log in logs {
        let (rec, report) = resample(&log.streams, options.dt, options.gap_tolerance, &log.path)?;
        let (windows, skips) = cut_windows(&rec, options.dt, options.window)?;
        skipped.add(&skips);
        // Samples dropped for a time stamp that went backwards (the most of any stream: a
        // row-aligned log drops a row from every stream).
        skipped.non_monotonic += report.streams.iter().map(|s| s.dropped).max().unwrap_or(0);
        per_run.push(windows);
        rows.push(rec.t.len());
        reports.push(report);
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
                logs.len(),
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
            starts: Vec::new(),
        };
        for w in ws {
            set.states.extend(w.states.iter().map(crate::vehicle::to_network));
            set.inputs.extend_from_slice(&w.inputs);
        }
        set.collocation = super::collocation::collocation_times(
            options.seed,
            name,
            ws.len() * (options.window - 1),
            colloc,
            options.dt,
        );
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
    let files = logs
        .iter()
        .zip(reports)
        .enumerate()
        .map(|(r, (log, report))| SourceFile {
            path: log.path.display().to_string(),
            sha256: log.sha256.clone(),
            rows: rows[r],
            windows: per_run[r].len(),
            split: assignment.run_split[r].to_string(),
            report,
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
