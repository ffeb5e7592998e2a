//! The data folder: everything the page lists, downloads and deletes lives under one folder,
//! in four kinds (`recordings`, `excitations`, `models`, `flights`; a model or a flight is a
//! folder of files). A name from a request is one plain file or folder name: anything that
//! could leave the folder (`..`, `/`, `\`, a leading dot) is refused before the disk is touched.

use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

/// The kinds of things the folder holds, each in its own sub-folder.
pub const KINDS: [&str; 4] = ["recordings", "excitations", "models", "flights"];

/// Why a name or a file was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DataError {
    #[error("unknown kind {0:?}: one of recordings, excitations, models, flights")]
    Kind(String),
    #[error(
        "{what} {name:?} is refused: names are letters, digits, '.', '_' and '-', not starting with a dot, at most 100 characters (no '..', '/' or '\\')"
    )]
    Name { what: &'static str, name: String },
    #[error("{0} does not exist in the data folder")]
    Missing(String),
    #[error("{path}: {error}")]
    Io { path: String, error: String },
}

/// A plain name: `[A-Za-z0-9._-]`, not starting with a dot, 1-100 characters.
pub fn check_name(what: &'static str, name: &str) -> Result<(), DataError> {
    let plain = !name.is_empty()
        && name.len() <= 100
        && !name.starts_with('.')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'));
    if plain { Ok(()) } else { Err(DataError::Name { what, name: name.to_string() }) }
}

/// The owner's limits, in the data folder.
const LIMITS_FILE: &str = "limits.json";

/// The data folder.
#[derive(Clone)]
pub struct DataFolder {
    root: PathBuf,
}

fn io(path: &Path, e: std::io::Error) -> DataError {
    DataError::Io { path: path.display().to_string(), error: e.to_string() }
}

impl DataFolder {
    /// The folder and its kinds' sub-folders, made if missing.
    pub fn open(root: &Path) -> Result<Self, DataError> {
        for kind in KINDS {
            let dir = root.join(kind);
            std::fs::create_dir_all(&dir).map_err(|e| io(&dir, e))?;
        }
        Ok(Self { root: root.to_path_buf() })
    }

    /// The folder itself.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The sub-folder of `kind`.
    pub fn dir(&self, kind: &str) -> Result<PathBuf, DataError> {
        if KINDS.contains(&kind) { Ok(self.root.join(kind)) } else { Err(DataError::Kind(kind.to_string())) }
    }

    /// The path of `kind/name` (or of `file` inside that folder), checked, not necessarily
    /// existing.
    pub fn path(&self, kind: &str, name: &str, file: Option<&str>) -> Result<PathBuf, DataError> {
        check_name("name", name)?;
        let mut path = self.dir(kind)?.join(name);
        if let Some(file) = file {
            check_name("file", file)?;
            path.push(file);
        }
        Ok(path)
    }

    /// The path of an existing `kind/name[/file]`.
    pub fn existing(&self, kind: &str, name: &str, file: Option<&str>) -> Result<PathBuf, DataError> {
        let path = self.path(kind, name, file)?;
        let shown = [Some(kind), Some(name), file].into_iter().flatten().collect::<Vec<_>>().join("/");
        if path.symlink_metadata().is_ok() { Ok(path) } else { Err(DataError::Missing(shown)) }
    }

    /// What the folder holds (bytes): every file under it.
    pub fn size(&self) -> u64 {
        fn walk(dir: &Path) -> u64 {
            let Ok(read) = std::fs::read_dir(dir) else { return 0 };
            read.flatten()
                .map(|e| match e.metadata() {
                    Ok(m) if m.is_dir() => walk(&e.path()),
                    Ok(m) => m.len(),
                    Err(_) => 0,
                })
                .sum()
        }
        walk(&self.root)
    }

    /// The free space of the folder's disk for this user (bytes), where the system says.
    pub fn free(&self) -> Option<u64> {
        use std::os::unix::ffi::OsStrExt;
        let path = std::ffi::CString::new(self.root.as_os_str().as_bytes()).ok()?;
        // SAFETY: statvfs(3) writes one plain struct through the pointer; the path is a valid C
        // string for the call's length.
        let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
        if unsafe { libc::statvfs(path.as_ptr(), &mut st) } != 0 {
            return None;
        }
        Some(st.f_bavail as u64 * st.f_frsize as u64)
    }

    /// The newest entry of `kind` (by modification time) that holds `file`.
    pub fn newest(&self, kind: &str, file: &str) -> Option<String> {
        let read = std::fs::read_dir(self.dir(kind).ok()?).ok()?;
        read.flatten()
            .filter(|e| e.path().join(file).is_file())
            .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.file_name().to_string_lossy().into_owned())))
            .filter(|(_, name)| check_name("name", name).is_ok())
            .max()
            .map(|(_, name)| name)
    }

    /// The limits the owner set on the page (`limits.json`), if any.
    ///
    /// # Errors
    /// The file cannot be read, or it is not limits (named with what is wrong).
    pub fn limits(&self) -> Result<Option<super::orders::DiveLimits>, DataError> {
        let path = self.root.join(LIMITS_FILE);
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(io(&path, e)),
        };
        let bad = |error: String| DataError::Io { path: path.display().to_string(), error };
        let limits: super::orders::DiveLimits = serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
        limits.check().map_err(bad)?;
        Ok(Some(limits))
    }

    /// Keeps `limits` as the owner's (`limits.json`, written whole: a temporary file renamed
    /// over the old one, so a power cut leaves the old limits or the new, never half).
    ///
    /// # Errors
    /// The file cannot be written.
    pub fn save_limits(&self, limits: &super::orders::DiveLimits) -> Result<(), DataError> {
        let path = self.root.join(LIMITS_FILE);
        let temporary = self.root.join(format!(".{LIMITS_FILE}.partial"));
        let text = serde_json::to_string_pretty(limits).map_err(|e| io(&path, std::io::Error::other(e)))?;
        let write = || -> std::io::Result<()> {
            let mut f = std::fs::File::create(&temporary)?;
            std::io::Write::write_all(&mut f, text.as_bytes())?;
            f.sync_all()?;
            std::fs::rename(&temporary, &path)
        };
        write().map_err(|e| io(&path, e))
    }

    /// The page's token: kept in the folder (`.token`, owner-only), made on the first start, so
    /// what a ground station copied of it (Cockpit's actions) still works after a restart.
    pub fn token(&self) -> Result<String, DataError> {
        let path = self.root.join(".token");
        match std::fs::read_to_string(&path) {
            Ok(t) if t.trim().len() == 32 && t.trim().bytes().all(|b| b.is_ascii_hexdigit()) => {
                Ok(t.trim().to_string())
            }
            Ok(_) | Err(_) => {
                let token = format!("{:032x}", rand::random::<u128>());
                let mut options = std::fs::OpenOptions::new();
                options.write(true).create(true).truncate(true);
                #[cfg(unix)]
                std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
                let mut f = options.open(&path).map_err(|e| io(&path, e))?;
                std::io::Write::write_all(&mut f, token.as_bytes()).map_err(|e| io(&path, e))?;
                Ok(token)
            }
        }
    }

    /// A name `PREFIX-YYYYmmdd-HHMMSS` (UTC) not yet taken in `kind` (with `-2`, `-3`... if it is).
    pub fn new_name(&self, kind: &str, prefix: &str, extension: &str) -> Result<String, DataError> {
        let base = format!("{prefix}-{}", chrono::Utc::now().format("%Y%m%d-%H%M%S"));
        let dir = self.dir(kind)?;
        let taken = |n: &str| {
            dir.join(format!("{n}{extension}")).exists() || dir.join(format!("{n}{extension}.partial")).exists()
        };
        let mut name = base.clone();
        let mut k = 2;
        while taken(&name) {
            name = format!("{base}-{k}");
            k += 1;
        }
        Ok(format!("{name}{extension}"))
    }

    /// Every entry of every kind: name, size (a folder's: its files'), modified time, and a
    /// folder's files; a recording still being written (or left by a killed run) ends in
    /// `.partial`.
    pub fn list(&self) -> Value {
        let mut out = serde_json::Map::new();
        for kind in KINDS {
            let mut entries: Vec<Value> = Vec::new();
            let Ok(read) = std::fs::read_dir(self.root.join(kind)) else { continue };
            for entry in read.flatten() {
                let name = entry.file_name().to_string_lossy().into_owned();
                if check_name("name", &name).is_err() {
                    continue;
                }
                let Ok(meta) = entry.metadata() else { continue };
                let modified =
                    meta.modified().ok().and_then(|m| m.duration_since(UNIX_EPOCH).ok()).map(|d| d.as_secs());
                let (size, files) = if meta.is_dir() {
                    let mut files: Vec<(String, u64)> = std::fs::read_dir(entry.path())
                        .map(|r| {
                            r.flatten()
                                .filter_map(|f| {
                                    let m = f.metadata().ok().filter(|m| m.is_file())?;
                                    Some((f.file_name().to_string_lossy().into_owned(), m.len()))
                                })
                                .filter(|(n, _)| check_name("file", n).is_ok())
                                .collect()
                        })
                        .unwrap_or_default();
                    files.sort();
                    (files.iter().map(|f| f.1).sum(), Some(files.into_iter().map(|f| f.0).collect::<Vec<_>>()))
                } else {
                    (meta.len(), None)
                };
                entries.push(json!({"name": name, "size": size, "modified": modified, "files": files,
                                    "partial": name.ends_with(".partial")}));
            }
            entries.sort_by(|a, b| {
                b["modified"].as_u64().cmp(&a["modified"].as_u64()).then(a["name"].as_str().cmp(&b["name"].as_str()))
            });
            out.insert(kind.to_string(), Value::Array(entries));
        }
        Value::Object(out)
    }

    /// Deletes `kind/name` (a folder with its files).
    pub fn delete(&self, kind: &str, name: &str) -> Result<(), DataError> {
        let path = self.existing(kind, name, None)?;
        let meta = path.symlink_metadata().map_err(|e| io(&path, e))?;
        if meta.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) }
            .map_err(|e| io(&path, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_that_could_leave_the_folder_are_refused() {
        for bad in ["..", "../x", "a/b", "a\\b", ".hidden", "", "a b", "x\0", &"a".repeat(101)] {
            assert!(check_name("name", bad).is_err(), "{bad:?} was accepted");
        }
        for good in ["pool.mcap", "pool.mcap.partial", "fit-20261127-101500", "a_b-1.csv"] {
            check_name("name", good).unwrap();
        }
    }

    #[test]
    fn paths_stay_in_their_kind_and_deletes_take_only_what_exists() {
        let dir = tempfile::tempdir().unwrap();
        let data = DataFolder::open(dir.path()).unwrap();
        assert_eq!(data.path("models", "m", Some("report.png")).unwrap(), dir.path().join("models/m/report.png"));
        assert_eq!(data.path("secrets", "m", None), Err(DataError::Kind("secrets".into())));
        assert!(matches!(data.path("models", "m", Some("../../etc")), Err(DataError::Name { what: "file", .. })));
        assert_eq!(data.delete("recordings", "none.mcap"), Err(DataError::Missing("recordings/none.mcap".into())));
        std::fs::write(dir.path().join("recordings/a.mcap.partial"), b"x").unwrap();
        std::fs::create_dir(dir.path().join("models/fit-1")).unwrap();
        std::fs::write(dir.path().join("models/fit-1/model.pinc"), b"abc").unwrap();
        let list = data.list();
        assert_eq!(list["recordings"][0]["name"], "a.mcap.partial");
        assert_eq!(list["recordings"][0]["partial"], true);
        assert_eq!(list["models"][0]["files"], json!(["model.pinc"]));
        assert_eq!(list["models"][0]["size"], 3);
        data.delete("models", "fit-1").unwrap();
        assert!(!dir.path().join("models/fit-1").exists());
    }

    #[test]
    fn new_names_carry_the_utc_time_and_never_take_an_existing_one() {
        let dir = tempfile::tempdir().unwrap();
        let data = DataFolder::open(dir.path()).unwrap();
        let before = chrono::Utc::now().format("%Y%m%d-%H%M%S").to_string();
        let name = data.new_name("recordings", "excite", ".mcap").unwrap();
        let stamp = &name["excite-".len()..name.len() - ".mcap".len()];
        assert!(stamp.len() == 15 && stamp >= before.as_str(), "{name}");
        // Taken (also as a run still writing): the next free suffix.
        std::fs::write(dir.path().join("recordings").join(format!("{name}.partial")), b"x").unwrap();
        let second = data.new_name("recordings", "excite", ".mcap").unwrap();
        assert!(second == format!("excite-{stamp}-2.mcap") || second > name, "{second}");
    }
}
