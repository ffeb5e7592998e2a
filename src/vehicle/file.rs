//! Vehicle files: TOML whose top-level keys are `VehicleParams`' field names. An omitted key
//! keeps the BlueROV2 value; an unknown key, a value that is not a number, or coefficients
//! that make the model meaningless are errors naming the key and the file.

use super::{ParamsError, VehicleParams};
use std::path::{Path, PathBuf};

/// Why a vehicle file was refused; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum VehicleFileError {
    /// The file could not be read.
    #[error("{path}: {source}", path = path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The reason.
        source: std::io::Error,
    },
    /// Not TOML (the message gives line and column).
    #[error("{path}: {message}", path = path.display())]
    Syntax {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// A key that is not a vehicle coefficient (a typo must not pass silently).
    #[error("{path}: unknown key {key:?} (the keys are m, g, rho, volume, x_ud, y_vd, z_wd, n_rd, izz, x_u, y_v, z_w, n_r, x_uu, y_vv, z_ww, n_rr, and the tables thruster and curve)", path = path.display())]
    UnknownKey {
        /// The file.
        path: PathBuf,
        /// The key.
        key: String,
    },
    /// A key whose value is not a number.
    #[error("{path}: {key} = {found} is not a number", path = path.display())]
    NotANumber {
        /// The file.
        path: PathBuf,
        /// The key.
        key: String,
        /// The value as written.
        found: String,
    },
    /// A thruster or thruster curve that cannot be used (docs/THRUSTERS.md).
    #[error("{path}: {}{message}", if thruster.is_empty() { String::new() } else { format!("thruster {thruster}: ") }, path = path.display())]
    Thruster {
        /// The file.
        path: PathBuf,
        /// The thruster's name (empty when the fault is not one thruster's).
        thruster: String,
        /// What is wrong.
        message: String,
    },
    /// Numbers that make the model meaningless.
    #[error("{path}: {source}", path = path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Which coefficient and why.
        source: ParamsError,
    },
}

impl VehicleParams {
    /// Parses a vehicle file's text; `path` names it in errors.
    ///
    /// # Errors
    /// Syntax, an unknown key, a value that is not a number, or [`VehicleParams::validate`].
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, VehicleFileError> {
        let path = path.to_path_buf();
        let table: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| VehicleFileError::Syntax { path: path.clone(), message: e.to_string() })?;
        let mut params = VehicleParams::default();
        for (key, value) in &table {
            // The thrusters and their curves: `Thrusters::from_toml` reads them.
            if key == "thruster" || key == "curve" {
                continue;
            }
            let number = match value {
                toml::Value::Float(f) => *f,
                toml::Value::Integer(i) => *i as f64,
                other => {
                    return Err(VehicleFileError::NotANumber { path, key: key.clone(), found: other.to_string() });
                }
            };
            match params.get_mut(key) {
                Some(slot) => *slot = number,
                None => return Err(VehicleFileError::UnknownKey { path, key: key.clone() }),
            }
        }
        params.validate().map_err(|source| VehicleFileError::Invalid { path, source })?;
        Ok(params)
    }

    /// Reads and parses a vehicle file.
    ///
    /// # Errors
    /// As [`VehicleParams::from_toml`], plus [`VehicleFileError::Io`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self, VehicleFileError> {
        let path = path.as_ref();
        let text =
            std::fs::read_to_string(path).map_err(|source| VehicleFileError::Io { path: path.into(), source })?;
        Self::from_toml(&text, path)
    }

    /// Every coefficient as a vehicle file (exact: each value is written with the digits
    /// that read back as the same double).
    pub fn to_toml(&self) -> String {
        self.named().iter().map(|(k, v)| format!("{k} = {v:?}\n")).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<VehicleParams, VehicleFileError> {
        VehicleParams::from_toml(text, Path::new("v.toml"))
    }

    #[test]
    fn the_shipped_bluerov2_file_is_the_default_with_every_key() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/bluerov2.toml");
        assert_eq!(VehicleParams::load(&path).unwrap(), VehicleParams::default());
        let text = std::fs::read_to_string(path).unwrap();
        let table: toml::Table = text.parse().unwrap();
        assert_eq!(table.len(), 19, "every key written out, and the thruster and curve tables");
    }

    #[test]
    fn omitted_keys_keep_the_bluerov2_values_and_files_round_trip() {
        let p = parse("m = 13.5\nx_uu = -40\n").unwrap();
        assert_eq!((p.m, p.x_uu, p.y_v), (13.5, -40.0, VehicleParams::default().y_v));
        assert_eq!(parse(&p.to_toml()).unwrap(), p);
    }

    #[test]
    fn bad_files_are_errors_naming_the_key_and_the_file() {
        let msg = |text: &str| parse(text).unwrap_err().to_string();
        assert!(msg("mass = 12\n").starts_with("v.toml: unknown key \"mass\""), "{}", msg("mass = 12\n"));
        assert_eq!(msg("m = \"heavy\"\n"), "v.toml: m = \"heavy\" is not a number");
        assert!(msg("m = 11\nm = 12\n").starts_with("v.toml: "), "duplicate key: {}", msg("m = 11\nm = 12\n"));
        assert_eq!(msg("m = nan\n"), "v.toml: m = NaN is not finite");
        assert!(msg("x_ud = 12\n").starts_with("v.toml: x_ud = 12: the effective mass"), "{}", msg("x_ud = 12\n"));
        assert!(msg("z_ww = 5\n").starts_with("v.toml: z_ww = 5: positive damping"), "{}", msg("z_ww = 5\n"));
        assert!(msg("volume = 0\n").starts_with("v.toml: volume = 0: must be positive"));
        let missing = VehicleParams::load("no/such/vehicle.toml").unwrap_err().to_string();
        assert!(missing.starts_with("no/such/vehicle.toml: "), "{missing}");
    }
}
