//! Bytes <-> [`PincModel`]: the fixed header, the checksum, bincode, and validation.

use super::format::{PincModelV1, PincModelV2, PincModelV3};
use super::{FORMAT_VERSION, HEADER_SIZE, MAGIC, MAX_FILE_BYTES, ModelError, OLDEST_READ_VERSION, PincModel, validate};
use std::path::Path;

fn bincode_config() -> impl bincode::config::Config {
    // The limit bounds what any length prefix inside the payload can make the decoder claim.
    bincode::config::standard().with_limit::<MAX_FILE_BYTES>()
}

impl PincModel {
    /// Validates the model, then encodes it as a complete `.pinc` file.
    ///
    /// # Errors
    /// Any [`validate`](super::validate) failure; an encoding failure.
    pub fn to_bytes(&self) -> Result<Vec<u8>, ModelError> {
        validate(self)?;
        self.to_bytes_unvalidated()
    }

    /// Encodes without validating: for tools and tests that must produce bad files.
    pub fn to_bytes_unvalidated(&self) -> Result<Vec<u8>, ModelError> {
        let payload =
            bincode::serde::encode_to_vec(self, bincode_config()).map_err(|e| ModelError::Encode(e.to_string()))?;
        let mut out = Vec::with_capacity(HEADER_SIZE + payload.len());
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        out.extend_from_slice(&payload);
        Ok(out)
    }

    /// Parses and validates a `.pinc` file held in memory.
    ///
    /// # Errors
    /// A typed [`ModelError`] for a foreign or truncated file, another version, a size over
    /// the limits, a checksum mismatch, an undecodable payload, or a model that fails
    /// validation. Allocates no more than the bytes given justify.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ModelError> {
        if bytes.len() < HEADER_SIZE {
            if !bytes.is_empty() && !MAGIC.starts_with(&bytes[..bytes.len().min(MAGIC.len())]) {
                return Err(ModelError::BadMagic { found: bytes[..bytes.len().min(MAGIC.len())].to_vec() });
            }
            return Err(ModelError::Truncated { needed: HEADER_SIZE, found: bytes.len() });
        }
        if bytes[..8] != MAGIC {
            return Err(ModelError::BadMagic { found: bytes[..8].to_vec() });
        }
        let version = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
        if !(OLDEST_READ_VERSION..=FORMAT_VERSION).contains(&version) {
            return Err(ModelError::UnsupportedVersion { found: version, supported: FORMAT_VERSION });
        }
        let declared = u64::from_le_bytes(bytes[12..20].try_into().expect("8 bytes"));
        if declared > (MAX_FILE_BYTES - HEADER_SIZE) as u64 {
            return Err(ModelError::TooLarge { declared, max: MAX_FILE_BYTES - HEADER_SIZE });
        }
        let declared = declared as usize;
        let body = &bytes[HEADER_SIZE..];
        if body.len() < declared {
            return Err(ModelError::Truncated { needed: HEADER_SIZE + declared, found: bytes.len() });
        }
        if body.len() > declared {
            return Err(ModelError::TrailingBytes { extra: body.len() - declared });
        }
        let stored = u32::from_le_bytes(bytes[20..24].try_into().expect("4 bytes"));
        let computed = crc32fast::hash(body);
        if stored != computed {
            return Err(ModelError::ChecksumMismatch { stored, computed });
        }
        let decode_error = |e: bincode::error::DecodeError| ModelError::Decode(e.to_string());
        let (model, used): (PincModel, usize) = match version {
            1 => {
                let (v1, used): (PincModelV1, usize) =
                    bincode::serde::decode_from_slice(body, bincode_config()).map_err(decode_error)?;
                (v1.into(), used)
            }
            2 => {
                let (v2, used): (PincModelV2, usize) =
                    bincode::serde::decode_from_slice(body, bincode_config()).map_err(decode_error)?;
                (v2.into(), used)
            }
            3 => {
                let (v3, used): (PincModelV3, usize) =
                    bincode::serde::decode_from_slice(body, bincode_config()).map_err(decode_error)?;
                (v3.into(), used)
            }
            _ => bincode::serde::decode_from_slice(body, bincode_config()).map_err(decode_error)?,
        };
        if used != body.len() {
            return Err(ModelError::TrailingBytes { extra: body.len() - used });
        }
        validate(&model)?;
        Ok(model)
    }

    /// Reads and validates a `.pinc` file.
    ///
    /// # Errors
    /// As [`PincModel::from_bytes`], plus [`ModelError::Io`]; a file over
    /// [`MAX_FILE_BYTES`] is refused before it is read.
    ///
    /// # Example
    /// A shipped model loads; a copy with one flipped bit is refused by its checksum:
    /// ```
    /// use pinc::model::{ModelError, PincModel};
    ///
    /// let path = concat!(env!("CARGO_MANIFEST_DIR"), "/models/mpc_pinc.pinc");
    /// let model = PincModel::load(path)?;
    /// assert_eq!((model.architecture.hidden_layers, model.architecture.width), (4, 32));
    ///
    /// let mut bytes = std::fs::read(path)?;
    /// let last = bytes.len() - 1;
    /// bytes[last] ^= 1;
    /// assert!(matches!(PincModel::from_bytes(&bytes), Err(ModelError::ChecksumMismatch { .. })));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ModelError> {
        let path = path.as_ref();
        let io = |source| ModelError::Io { path: path.to_path_buf(), source };
        let len = std::fs::metadata(path).map_err(io)?.len();
        if len > MAX_FILE_BYTES as u64 {
            return Err(ModelError::TooLarge { declared: len, max: MAX_FILE_BYTES });
        }
        Self::from_bytes(&std::fs::read(path).map_err(io)?)
    }

    /// Validates and writes the model to `path`.
    ///
    /// # Errors
    /// Validation failures and [`ModelError::Io`].
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), ModelError> {
        let path = path.as_ref();
        std::fs::write(path, self.to_bytes()?).map_err(|source| ModelError::Io { path: path.to_path_buf(), source })
    }
}
