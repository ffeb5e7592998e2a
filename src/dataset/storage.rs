//! On-disk form of a dataset, readable by numpy without pinc:
//!
//! ```text
//! DIR/manifest.json            preset, seed, layouts, units, and every array's file and shape
//! DIR/<set>/states.npy         float64 (count, points, 9)  network-form states
//! DIR/<set>/inputs.npy         float64 (count, points-1, 4) held inputs [X, Y, Z, Mz]
//! DIR/<set>/collocation.npy    float64 (count, points-1, m) physics-loss times in [0, dt]
//! ```
//!
//! Loading checks the manifest against the preset it names and every array against the
//! manifest (dtype, order, shape, byte length, finiteness) before trusting anything.

use super::{Dataset, DatasetError, DatasetPreset, TrajectorySet};
use crate::types::{INPUT_NAMES, Input, NU, NX, STATE_NAMES, State};
use npyz::WriterBuilder;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs;
use std::io::{BufWriter, Write};
use std::path::{Component, Path, PathBuf};

/// `format` field of every manifest.
pub const MANIFEST_FORMAT: &str = "pinc-dataset";
/// Manifest version this build writes and reads.
pub const MANIFEST_VERSION: u32 = 1;
/// File name of the manifest inside a dataset folder.
pub const MANIFEST_FILE: &str = "manifest.json";

/// The JSON manifest of a dataset folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always [`MANIFEST_FORMAT`].
    pub format: String,
    /// Always [`MANIFEST_VERSION`].
    pub version: u32,
    /// The generating preset, verbatim.
    pub preset: DatasetPreset,
    /// The generating seed.
    pub seed: u64,
    /// Names of the state columns.
    pub state_layout: Vec<String>,
    /// Names of the input columns.
    pub input_layout: Vec<String>,
    /// Units of every column and of time.
    pub units: BTreeMap<String, String>,
    /// One entry per set.
    pub sets: Vec<SetEntry>,
    /// For a dataset imported from recorded runs: the files (with their SHA-256), the
    /// options and what was skipped.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<super::source::ImportSource>,
}

/// Manifest entry of one set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetEntry {
    /// Set name.
    pub name: String,
    /// Sample period (s).
    pub dt: f64,
    /// Number of trajectories.
    pub count: usize,
    /// Points per trajectory.
    pub points: usize,
    /// Collocation times per interval.
    pub collocation_points: usize,
    /// The states array.
    pub states: ArrayEntry,
    /// The inputs array.
    pub inputs: ArrayEntry,
    /// The collocation array, present when `collocation_points > 0`.
    pub collocation: Option<ArrayEntry>,
}

/// An array file, relative to the dataset folder, and its shape.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ArrayEntry {
    /// Relative path.
    pub file: String,
    /// Shape (C order).
    pub shape: Vec<u64>,
}

fn units() -> BTreeMap<String, String> {
    let pairs = [
        ("x", "m"),
        ("y", "m"),
        ("z", "m (NED, positive down)"),
        ("cos_psi", "1"),
        ("sin_psi", "1"),
        ("u", "m/s"),
        ("v", "m/s"),
        ("w", "m/s"),
        ("r", "rad/s"),
        ("X", "N"),
        ("Y", "N"),
        ("Z", "N"),
        ("Mz", "N m"),
        ("dt", "s"),
        ("collocation", "s from the start of the interval"),
    ];
    pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect()
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io { path: path.to_path_buf(), source }
}

fn write_npy(path: &Path, shape: &[u64], data: impl Iterator<Item = f64>) -> Result<(), DatasetError> {
    let file = fs::File::create(path).map_err(io_err(path))?;
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(shape)
        .writer(BufWriter::new(file))
        .begin_nd()
        .map_err(io_err(path))?;
    w.extend(data).map_err(io_err(path))?;
    w.finish().map_err(io_err(path))
}

/// Writes `data` into the folder `dir` and returns the manifest written. The folder appears
/// whole or not at all: everything is written into a sibling folder first, which then
/// replaces `dir`. An existing `dir` is replaced only if it is empty or a dataset (it holds
/// a manifest), so a mistyped path never deletes unrelated files.
pub fn save(data: &Dataset, dir: &Path) -> Result<Manifest, DatasetError> {
    if dir.exists() {
        let empty = fs::read_dir(dir).map_err(io_err(dir))?.next().is_none();
        if !empty && !dir.join(MANIFEST_FILE).is_file() {
            return Err(DatasetError::Inconsistent {
                path: dir.to_path_buf(),
                message: "exists and is not a dataset folder (no manifest.json); choose another --out".into(),
            });
        }
    }
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "dataset".into());
    let partial = dir.with_file_name(format!(".{name}.partial-{}", std::process::id()));
    let _ = fs::remove_dir_all(&partial);
    let written = write_folder(data, &partial);
    let manifest = match written {
        Ok(m) => m,
        Err(e) => {
            let _ = fs::remove_dir_all(&partial);
            return Err(e);
        }
    };
    if dir.exists() {
        fs::remove_dir_all(dir).map_err(io_err(dir))?;
    }
    fs::rename(&partial, dir).map_err(io_err(dir))?;
    Ok(manifest)
}

fn write_folder(data: &Dataset, dir: &Path) -> Result<Manifest, DatasetError> {
    fs::create_dir_all(dir).map_err(io_err(dir))?;
    let mut entries = Vec::new();
    for set in &data.sets {
        let sub = dir.join(&set.name);
        fs::create_dir_all(&sub).map_err(io_err(&sub))?;
        let (c, p, m) = (set.count as u64, set.points as u64, set.collocation_points as u64);
        let states = ArrayEntry { file: format!("{}/states.npy", set.name), shape: vec![c, p, NX as u64] };
        let inputs = ArrayEntry { file: format!("{}/inputs.npy", set.name), shape: vec![c, p - 1, NU as u64] };
        write_npy(&dir.join(&states.file), &states.shape, set.states.iter().flat_map(|s| s.iter().copied()))?;
        write_npy(&dir.join(&inputs.file), &inputs.shape, set.inputs.iter().flat_map(|u| u.iter().copied()))?;
        let collocation = if m > 0 {
            let e = ArrayEntry { file: format!("{}/collocation.npy", set.name), shape: vec![c, p - 1, m] };
            write_npy(&dir.join(&e.file), &e.shape, set.collocation.iter().copied())?;
            Some(e)
        } else {
            None
        };
        entries.push(SetEntry {
            name: set.name.clone(),
            dt: set.dt,
            count: set.count,
            points: set.points,
            collocation_points: set.collocation_points,
            states,
            inputs,
            collocation,
        });
    }
    let manifest = Manifest {
        format: MANIFEST_FORMAT.into(),
        version: MANIFEST_VERSION,
        preset: data.preset.clone(),
        seed: data.seed,
        state_layout: STATE_NAMES.iter().map(|s| s.to_string()).collect(),
        input_layout: INPUT_NAMES.iter().map(|s| s.to_string()).collect(),
        units: units(),
        sets: entries,
        source: data.source.clone(),
    };
    let path = dir.join(MANIFEST_FILE);
    let json = serde_json::to_string_pretty(&manifest)
        .map_err(|e| DatasetError::BadManifest { path: path.clone(), message: e.to_string() })?;
    let mut f = fs::File::create(&path).map_err(io_err(&path))?;
    f.write_all(json.as_bytes()).and_then(|_| f.write_all(b"\n")).map_err(io_err(&path))?;
    Ok(manifest)
}

fn read_file(path: &Path) -> Result<Vec<u8>, DatasetError> {
    fs::read(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => DatasetError::MissingFile { path: path.to_path_buf() },
        _ => DatasetError::Io { path: path.to_path_buf(), source: e },
    })
}

/// Reads a C-ordered `<f8` array whose header must declare exactly `shape`.
fn read_npy(path: &Path, shape: &[u64]) -> Result<Vec<f64>, DatasetError> {
    let bytes = read_file(path)?;
    let bad = |message: String| DatasetError::BadArray { path: path.to_path_buf(), message };
    let mut cursor = std::io::Cursor::new(&bytes[..]);
    let header = npyz::NpyHeader::from_reader(&mut cursor).map_err(|e| bad(e.to_string()))?;
    match header.dtype() {
        npyz::DType::Plain(ts) if ts.to_string() == "<f8" => {}
        other => return Err(bad(format!("dtype {}", other.descr()))),
    }
    if header.order() != npyz::Order::C {
        return Err(bad("Fortran order".into()));
    }
    if header.shape() != shape {
        return Err(DatasetError::ShapeMismatch {
            path: path.to_path_buf(),
            expected: shape.to_vec(),
            found: header.shape().to_vec(),
        });
    }
    let body = &bytes[cursor.position() as usize..];
    let n: u64 = shape.iter().product();
    if body.len() as u64 != n * 8 {
        return Err(bad(format!("{} data bytes for {n} float64 values", body.len())));
    }
    let values: Vec<f64> =
        body.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("chunks of 8"))).collect();
    if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(DatasetError::NonFinite { path: path.to_path_buf(), index, value });
    }
    Ok(values)
}

/// A manifest path must stay inside the dataset folder.
fn resolve(dir: &Path, manifest_path: &Path, file: &str) -> Result<PathBuf, DatasetError> {
    let rel = Path::new(file);
    if rel.components().any(|c| !matches!(c, Component::Normal(_))) {
        return Err(DatasetError::BadManifest {
            path: manifest_path.to_path_buf(),
            message: format!("file {file:?} is not a plain relative path"),
        });
    }
    Ok(dir.join(rel))
}

fn check_entry(manifest_path: &Path, set: &SetEntry, spec: Option<&super::SetSpec>) -> Result<(), DatasetError> {
    let fail = |message: String| {
        Err(DatasetError::Inconsistent {
            path: manifest_path.to_path_buf(),
            message: format!("set {:?}: {message}", set.name),
        })
    };
    let Some(spec) = spec else { return fail("not in the preset".into()) };
    if (spec.count, spec.points, spec.collocation_points) != (set.count, set.points, set.collocation_points)
        || spec.dt != set.dt
    {
        return fail("count, points, dt or collocation points differ from the preset".into());
    }
    if set.points < 2 || !set.dt.is_finite() || set.dt <= 0.0 {
        return fail(format!("needs at least 2 points and dt > 0, has {} points, dt {}", set.points, set.dt));
    }
    let (c, p, m) = (set.count as u64, set.points as u64, set.collocation_points as u64);
    if set.states.shape != [c, p, NX as u64] || set.inputs.shape != [c, p - 1, NU as u64] {
        return fail(format!(
            "array shapes {:?} / {:?} disagree with count {c} and points {p}",
            set.states.shape, set.inputs.shape
        ));
    }
    match (&set.collocation, m) {
        (None, 0) => Ok(()),
        (Some(e), m) if m > 0 && e.shape == [c, p - 1, m] => Ok(()),
        _ => fail(format!("collocation array disagrees with {m} points per interval")),
    }
}

/// Reads a dataset folder written by [`save`], validating everything.
pub fn load(dir: &Path) -> Result<Dataset, DatasetError> {
    let manifest_path = dir.join(MANIFEST_FILE);
    let bad_manifest = |message: String| DatasetError::BadManifest { path: manifest_path.clone(), message };
    let text = read_file(&manifest_path)?;
    let manifest: Manifest = serde_json::from_slice(&text).map_err(|e| bad_manifest(e.to_string()))?;
    if manifest.format != MANIFEST_FORMAT || manifest.version != MANIFEST_VERSION {
        return Err(bad_manifest(format!(
            "format {:?} version {}, expected {MANIFEST_FORMAT:?} version {MANIFEST_VERSION}",
            manifest.format, manifest.version
        )));
    }
    manifest.preset.vehicle.validate().map_err(|e| bad_manifest(format!("preset vehicle: {e}")))?;
    if manifest.sets.len() != manifest.preset.sets.len() {
        return Err(DatasetError::Inconsistent {
            path: manifest_path.clone(),
            message: format!("{} sets listed, preset has {}", manifest.sets.len(), manifest.preset.sets.len()),
        });
    }
    let mut sets = Vec::with_capacity(manifest.sets.len());
    for e in &manifest.sets {
        check_entry(&manifest_path, e, manifest.preset.set(&e.name))?;
        let states_path = resolve(dir, &manifest_path, &e.states.file)?;
        let states = read_npy(&states_path, &e.states.shape)?;
        let inputs = read_npy(&resolve(dir, &manifest_path, &e.inputs.file)?, &e.inputs.shape)?;
        let collocation = match &e.collocation {
            Some(c) => {
                let path = resolve(dir, &manifest_path, &c.file)?;
                let times = read_npy(&path, &c.shape)?;
                if let Some(t) = times.iter().find(|t| !(0.0..=e.dt).contains(*t)) {
                    return Err(DatasetError::Inconsistent {
                        path,
                        message: format!("collocation time {t} outside [0, {}]", e.dt),
                    });
                }
                times
            }
            None => Vec::new(),
        };
        let states: Vec<State> = states.chunks_exact(NX).map(State::from_column_slice).collect();
        if let Some((i, s)) = states.iter().enumerate().find(|(_, s)| ((s[3] * s[3] + s[4] * s[4]) - 1.0).abs() > 1e-6)
        {
            return Err(DatasetError::Inconsistent {
                path: states_path,
                message: format!("state {i}: cos^2 + sin^2 = {}", s[3] * s[3] + s[4] * s[4]),
            });
        }
        sets.push(TrajectorySet {
            name: e.name.clone(),
            dt: e.dt,
            count: e.count,
            points: e.points,
            collocation_points: e.collocation_points,
            states,
            inputs: inputs.chunks_exact(NU).map(Input::from_column_slice).collect(),
            collocation,
            starts: Vec::new(),
        });
    }
    Ok(Dataset { preset: manifest.preset, seed: manifest.seed, sets, source: manifest.source })
}
