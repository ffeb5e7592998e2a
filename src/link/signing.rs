//! MAVLink 2 message signing: the secret key a ground station and the autopilot share, read
//! from a file, and the `SETUP_SIGNING` message that gives it to the autopilot. With a key,
//! the link signs what pinc sends and drops every frame that is unsigned or signed with
//! another key (the `mavlink` crate's signing), so another host on the tether's network can
//! neither feed the controller a state nor command the vehicle.

use mavlink::dialects::ardupilotmega::SETUP_SIGNING_DATA;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// What can be wrong with a key file.
#[derive(Debug, thiserror::Error)]
pub enum SigningError {
    /// It cannot be read.
    #[error("signing key {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// It holds nothing.
    #[error("signing key {path}: the file is empty (write 64 hex digits, or a passphrase)")]
    Empty {
        /// The file.
        path: PathBuf,
    },
}

/// A 32-byte signing key.
#[derive(Clone, PartialEq, Eq)]
pub struct SigningKey {
    key: [u8; 32],
    /// Where it came from, for messages (never the key itself).
    source: String,
}

impl std::fmt::Debug for SigningKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SigningKey(from {})", self.source) // the secret stays out of logs
    }
}

/// Seconds from 1970-01-01 to 2015-01-01, the epoch of signing time stamps.
const SIGNING_EPOCH_UNIX_S: u64 = 1_420_070_400;

impl SigningKey {
    /// The key of a file: 64 hexadecimal digits are the key's bytes; anything else is a
    /// passphrase whose SHA-256 is the key (as MAVProxy's `signing setup` makes one). Leading
    /// and trailing white space is ignored.
    ///
    /// # Errors
    /// The file cannot be read or is empty.
    pub fn load(path: &Path) -> Result<Self, SigningError> {
        let text = std::fs::read_to_string(path).map_err(|source| SigningError::Io { path: path.into(), source })?;
        let source = path.display().to_string();
        Self::from_text(text.trim(), source).ok_or_else(|| SigningError::Empty { path: path.into() })
    }

    /// The key of a text, as [`SigningKey::load`] reads a file; `None` if it is empty.
    pub fn from_text(text: &str, source: String) -> Option<Self> {
        if text.is_empty() {
            return None;
        }
        let hex = text.len() == 64 && text.bytes().all(|b| b.is_ascii_hexdigit());
        let key = if hex {
            std::array::from_fn(|i| u8::from_str_radix(&text[2 * i..2 * i + 2], 16).expect("checked hex digits"))
        } else {
            Sha256::digest(text.as_bytes()).into()
        };
        Some(Self { key, source })
    }

    /// The key's bytes.
    pub fn bytes(&self) -> &[u8; 32] {
        &self.key
    }

    /// Where it was read from.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// The crate's signing configuration: sign everything sent on `link_id`, accept only
    /// frames signed with this key.
    pub fn config(&self, link_id: u8) -> mavlink::SigningConfig {
        mavlink::SigningConfig::new(self.key, link_id, true, false)
    }

    /// `SETUP_SIGNING` giving this key to `target`, its time stamp now (10 us since
    /// 2015-01-01, as the protocol counts).
    pub fn setup_message(&self, target_system: u8, target_component: u8) -> SETUP_SIGNING_DATA {
        let since_unix = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        let initial_timestamp =
            since_unix.as_micros().saturating_sub(u128::from(SIGNING_EPOCH_UNIX_S) * 1_000_000) / 10;
        SETUP_SIGNING_DATA {
            initial_timestamp: initial_timestamp as u64,
            target_system,
            target_component,
            secret_key: self.key,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_is_the_key_and_anything_else_a_passphrase() {
        let hex = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff";
        let k = SigningKey::from_text(hex, "t".into()).unwrap();
        assert_eq!(k.bytes()[..4], [0x00, 0x11, 0x22, 0x33]);
        assert_eq!(k.bytes()[31], 0xff);
        // SHA-256 of "abc" (FIPS 180-2's example): ba7816bf...
        let p = SigningKey::from_text("abc", "t".into()).unwrap();
        assert_eq!(p.bytes()[..4], [0xba, 0x78, 0x16, 0xbf]);
        assert!(SigningKey::from_text("", "t".into()).is_none());
        assert!(!format!("{p:?}").contains("ba78"), "the key stays out of Debug");
        let m = p.setup_message(1, 1);
        // 2026 is about 11 years after the epoch: 3.5e13 tens of microseconds.
        assert!(m.initial_timestamp > 30_000_000_000_000 && m.secret_key == *p.bytes());
    }

    #[test]
    fn an_empty_file_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("key.txt");
        std::fs::write(&path, "  \n").unwrap();
        let e = SigningKey::load(&path).unwrap_err();
        assert!(e.to_string().contains("key.txt") && e.to_string().contains("empty"), "{e}");
    }
}
