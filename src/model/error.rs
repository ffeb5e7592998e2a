//! Why a `.pinc` file or model was refused.

use std::path::PathBuf;

/// Every way loading, validating or saving a model can fail. Never a panic.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// Fewer bytes than the header or the declared payload need.
    #[error("truncated: {needed} bytes needed, {found} present")]
    Truncated {
        /// Bytes required.
        needed: usize,
        /// Bytes present.
        found: usize,
    },
    /// Not a `.pinc` file.
    #[error("not a .pinc file (magic bytes {found:02x?})")]
    BadMagic {
        /// The first bytes found.
        found: Vec<u8>,
    },
    /// Written by a different format version.
    #[error(
        "format version {found} is not supported (this build reads versions 1 to {supported}; a newer pinc wrote this file)"
    )]
    UnsupportedVersion {
        /// Version in the file.
        found: u32,
        /// Version this build reads.
        supported: u32,
    },
    /// The declared payload exceeds [`super::MAX_FILE_BYTES`].
    #[error("declared payload of {declared} bytes exceeds the limit of {max}")]
    TooLarge {
        /// Declared size.
        declared: u64,
        /// Limit.
        max: usize,
    },
    /// Bytes follow the declared payload.
    #[error("{extra} unexpected bytes after the payload")]
    TrailingBytes {
        /// How many.
        extra: usize,
    },
    /// The payload does not match its checksum.
    #[error("checksum mismatch: stored {stored:08x}, computed {computed:08x} (file corrupted)")]
    ChecksumMismatch {
        /// CRC-32 in the header.
        stored: u32,
        /// CRC-32 of the payload read.
        computed: u32,
    },
    /// The payload does not decode as a model.
    #[error("payload does not decode: {0}")]
    Decode(String),
    /// The payload could not be encoded.
    #[error("payload does not encode: {0}")]
    Encode(String),
    /// A declared dimension disagrees with the data.
    #[error("{what}: expected {expected}, found {found}")]
    DimensionMismatch {
        /// Which array or count.
        what: String,
        /// What the architecture implies.
        expected: usize,
        /// What is there.
        found: usize,
    },
    /// A weight, scaling or envelope value is NaN or infinite.
    #[error("{what}[{index}] is not finite ({value})")]
    NonFinite {
        /// Which array.
        what: String,
        /// Index of the first bad value.
        index: usize,
        /// The value.
        value: f64,
    },
    /// A size exceeds the format's limits.
    #[error("{what} = {value} exceeds the limit of {max}")]
    LimitExceeded {
        /// Which quantity.
        what: &'static str,
        /// Its value.
        value: usize,
        /// The limit.
        max: usize,
    },
    /// A value is out of its valid range.
    #[error("{what}: {message}")]
    Invalid {
        /// Which field.
        what: String,
        /// What is wrong.
        message: String,
    },
    /// A PyTorch state dict is not in the expected layout.
    #[error("import: {0}")]
    Import(String),
}
