//! Errors of dataset storage: each names the file at fault.

use std::path::PathBuf;

/// Why a dataset could not be written or read back.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file named by the manifest (or the manifest itself) does not exist.
    #[error("{path}: missing file")]
    MissingFile {
        /// The missing path.
        path: PathBuf,
    },
    /// Reading or writing failed at the operating-system level.
    #[error("{path}: {source}")]
    Io {
        /// The file being accessed.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The manifest is not valid JSON of the expected form.
    #[error("{path}: invalid manifest: {message}")]
    BadManifest {
        /// The manifest path.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A `.npy` file is not a C-ordered little-endian float64 array.
    #[error("{path}: not a C-ordered float64 .npy array: {message}")]
    BadArray {
        /// The array file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An array's shape differs from what the manifest declares.
    #[error("{path}: shape {found:?} but the manifest declares {expected:?}")]
    ShapeMismatch {
        /// The array file.
        path: PathBuf,
        /// Shape implied by the manifest.
        expected: Vec<u64>,
        /// Shape in the file header.
        found: Vec<u64>,
    },
    /// An array holds NaN or infinity.
    #[error("{path}: non-finite value {value} at flat index {index}")]
    NonFinite {
        /// The array file.
        path: PathBuf,
        /// Flat (C-order) index of the first bad element.
        index: usize,
        /// The bad value.
        value: f64,
    },
    /// Array contents contradict the manifest (e.g. collocation times outside `[0, dt]`).
    #[error("{path}: {message}")]
    Inconsistent {
        /// The file at fault.
        path: PathBuf,
        /// What disagrees.
        message: String,
    },
}
