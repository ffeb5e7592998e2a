//! What an imported dataset records about where it came from (its manifest's `source`): the
//! files, the options and what the import found and skipped. Below both the generation and
//! the import, which share these types.

use serde::{Deserialize, Serialize};

/// Which topics and fields hold the state and the command.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct McapTopics {
    /// Topic of the state messages.
    pub state_topic: String,
    /// Dotted path, inside a state message, of an object with keys `x y z psi u v w r`.
    pub state_field: String,
    /// Topic of the command messages.
    pub command_topic: String,
    /// Dotted path, inside a command message, of an object with keys `X Y Z Mz`.
    pub command_field: String,
}

impl Default for McapTopics {
    fn default() -> Self {
        Self {
            state_topic: "/vehicle/state".into(),
            state_field: "sim".into(),
            command_topic: "/mpc/command".into(),
            command_field: "input".into(),
        }
    }
}

/// Samples that went into no window, by reason.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SkipCounts {
    /// Rows holding a NaN or an infinity.
    pub non_finite_rows: usize,
    /// Time steps longer than the log's period (each ends a window).
    pub gaps: usize,
    /// Time stamps not after the previous one (each ends a window).
    pub non_monotonic: usize,
    /// Whole rows left over at the ends of stretches, too short for one more window.
    pub tail_rows: usize,
}

impl SkipCounts {
    /// Adds another run's counts.
    pub fn add(&mut self, o: &SkipCounts) {
        self.non_finite_rows += o.non_finite_rows;
        self.gaps += o.gaps;
        self.non_monotonic += o.non_monotonic;
        self.tail_rows += o.tail_rows;
    }
}

/// One stream of a log as the import found it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StreamInfo {
    /// The quantity: `position`, `depth`, `attitude`, `velocity_ned`, `velocity_body`,
    /// `yaw_rate` or `input`.
    pub name: String,
    /// Where the reader took it from.
    pub source: String,
    /// Samples with a finite time stamp.
    pub samples: usize,
    /// Median rate (Hz): one over the median time step; absent with fewer than two samples.
    pub rate_hz: Option<f64>,
    /// First and last time stamp (s).
    pub span_s: Option<(f64, f64)>,
    /// Steps between consecutive samples longer than `gap_tolerance_s`.
    pub gaps: usize,
    /// The longest step between consecutive samples (s).
    pub longest_step_s: f64,
    /// The tolerance its gaps were judged by (s).
    pub gap_tolerance_s: f64,
    /// Samples dropped because their time stamp was not finite or went backwards.
    pub dropped: usize,
}

/// What the import found in one file: each stream, and the reader's and the resampling's
/// notes.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct StreamReport {
    /// One entry per stream present.
    pub streams: Vec<StreamInfo>,
    /// What the reader and the resampling assumed, one line each.
    pub notes: Vec<String>,
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
    /// Longest step between two samples of a stream that is not a gap (s); `None`: per
    /// stream, three of its median periods and at least `2 dt`.
    #[serde(default)]
    pub gap_tolerance: Option<f64>,
    /// True when `dt` was chosen from the logs (`dataset::import::log_dt`) rather than given.
    #[serde(default)]
    pub dt_from_log: bool,
}

/// One imported file in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceFile {
    /// The path as given.
    pub path: String,
    /// SHA-256 of its bytes (hex, as `sha256sum` prints it).
    pub sha256: String,
    /// Rows at the dataset's period after resampling (the log's rows when it was recorded at
    /// that period).
    pub rows: usize,
    /// Windows cut from it.
    pub windows: usize,
    /// The split its windows went to (`train`, `dev`, `test`, or `time` when every run was
    /// split by time).
    pub split: String,
    /// Each stream's rate, span and gaps, and the reader's notes.
    #[serde(default)]
    pub report: StreamReport,
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
