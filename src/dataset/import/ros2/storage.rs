//! Reading raw messages from a ROS 2 bag in either storage format: MCAP (`mcap` crate) or
//! sqlite3 (`.db3`, `rusqlite`). A bag is a folder with `metadata.yaml` and one storage file,
//! or that file given alone.

use super::super::ImportError;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// One topic of the bag.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topic {
    /// Its name.
    pub name: String,
    /// Its message type, as the bag writes it (`nav_msgs/msg/Odometry`).
    pub msg_type: String,
    /// Its serialization (`cdr`).
    pub encoding: String,
}

/// What [`Bag::for_each`] calls per message: topic index, receive time (ns), payload.
pub type Visit<'a> = dyn FnMut(usize, i64, &[u8]) -> Result<(), ImportError> + 'a;

enum Store {
    /// The file's bytes and, per MCAP channel id, the topic index.
    Mcap { bytes: Vec<u8>, channels: HashMap<u16, usize> },
    /// The open database and, per topic index, its `topics.id`.
    Sqlite { db: rusqlite::Connection, ids: Vec<i64> },
}

/// An open bag: its topics and its messages.
pub struct Bag {
    /// The storage file.
    pub file: PathBuf,
    /// Its topics, in the order the storage lists them.
    pub topics: Vec<Topic>,
    store: Store,
}

/// The storage file of `path`: the path itself, or the single `.mcap` / `.db3` file of a
/// bag folder.
fn storage_file(path: &Path) -> Result<PathBuf, ImportError> {
    if !path.is_dir() {
        return Ok(path.to_path_buf());
    }
    let entries = std::fs::read_dir(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let mut found = Vec::new();
    for e in entries.flatten() {
        let p = e.path();
        if matches!(p.extension().and_then(|x| x.to_str()), Some("mcap" | "db3")) {
            found.push(p);
        }
    }
    found.sort();
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => Err(ImportError::Malformed {
            path: path.to_path_buf(),
            message: "a bag folder without a .mcap or .db3 file (compressed bags are not read)".into(),
        }),
        n => Err(ImportError::Malformed {
            path: path.to_path_buf(),
            message: format!("{n} storage files: split bags are not read; give one file"),
        }),
    }
}

impl Bag {
    /// Opens the bag at `path` (folder or storage file) and lists its topics.
    ///
    /// # Errors
    /// The file cannot be read, is neither MCAP nor SQLite, or its tables are not a bag's.
    pub fn open(path: &Path) -> Result<Self, ImportError> {
        let file = storage_file(path)?;
        let malformed = |message: String| ImportError::Malformed { path: file.clone(), message };
        let bytes = std::fs::read(&file).map_err(|source| ImportError::Io { path: file.clone(), source })?;
        if bytes.starts_with(b"\x89MCAP") {
            let mut topics = Vec::new();
            let mut channels = HashMap::new();
            let add = |topics: &mut Vec<Topic>, channels: &mut HashMap<u16, usize>, c: &mcap::Channel| {
                let i = topics.len();
                topics.push(Topic {
                    name: c.topic.clone(),
                    msg_type: c.schema.as_ref().map(|s| s.name.clone()).unwrap_or_default(),
                    encoding: c.message_encoding.clone(),
                });
                channels.insert(c.id, i);
            };
            let summary = mcap::Summary::read(&bytes).map_err(|e| malformed(format!("damaged MCAP: {e}")))?;
            if let Some(s) = summary {
                let mut ids: Vec<_> = s.channels.keys().copied().collect();
                ids.sort_unstable();
                for id in ids {
                    add(&mut topics, &mut channels, &s.channels[&id]);
                }
            } else {
                // No summary section (a log cut short): the channels come from a first pass.
                let stream =
                    mcap::MessageStream::new(&bytes).map_err(|e| malformed(format!("not an MCAP file: {e}")))?;
                for m in stream {
                    let m = m.map_err(|e| malformed(format!("damaged MCAP: {e}")))?;
                    if !channels.contains_key(&m.channel.id) {
                        add(&mut topics, &mut channels, &m.channel);
                    }
                }
            }
            return Ok(Self { file, topics, store: Store::Mcap { bytes, channels } });
        }
        if !bytes.starts_with(b"SQLite format 3\0") {
            return Err(malformed("neither an MCAP file nor an SQLite (.db3) bag".into()));
        }
        drop(bytes);
        let flags = rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX;
        let db = rusqlite::Connection::open_with_flags(&file, flags).map_err(|e| malformed(format!("SQLite: {e}")))?;
        let mut topics = Vec::new();
        let mut ids = Vec::new();
        {
            let mut q = db
                .prepare("SELECT id, name, type, serialization_format FROM topics ORDER BY id")
                .map_err(|e| malformed(format!("not a ROS 2 bag (table topics): {e}")))?;
            let rows = q
                .query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get(1)?, r.get(2)?, r.get(3)?)))
                .map_err(|e| malformed(format!("table topics: {e}")))?;
            for row in rows {
                let (id, name, msg_type, encoding) = row.map_err(|e| malformed(format!("table topics: {e}")))?;
                ids.push(id);
                topics.push(Topic { name, msg_type, encoding });
            }
        }
        Ok(Self { file, topics, store: Store::Sqlite { db, ids } })
    }

    /// Calls `f(topic index, receive time in ns, serialized message)` for every message of the
    /// topics marked in `wanted`, in the order they were written.
    ///
    /// # Errors
    /// A damaged file, or the first error `f` returns.
    pub fn for_each(&self, wanted: &[bool], f: &mut Visit<'_>) -> Result<(), ImportError> {
        let malformed = |message: String| ImportError::Malformed { path: self.file.clone(), message };
        match &self.store {
            Store::Mcap { bytes, channels } => {
                let stream =
                    mcap::MessageStream::new(bytes).map_err(|e| malformed(format!("not an MCAP file: {e}")))?;
                for m in stream {
                    let m = m.map_err(|e| malformed(format!("damaged MCAP: {e}")))?;
                    if let Some(&i) = channels.get(&m.channel.id)
                        && wanted[i]
                    {
                        f(i, m.log_time as i64, &m.data)?;
                    }
                }
            }
            Store::Sqlite { db, ids } => {
                let by_id: HashMap<i64, usize> =
                    ids.iter().enumerate().filter(|&(i, _)| wanted[i]).map(|(i, &id)| (id, i)).collect();
                let mut q = db
                    .prepare("SELECT topic_id, timestamp, data FROM messages ORDER BY id")
                    .map_err(|e| malformed(format!("not a ROS 2 bag (table messages): {e}")))?;
                let mut rows = q.query([]).map_err(|e| malformed(format!("table messages: {e}")))?;
                while let Some(row) = rows.next().map_err(|e| malformed(format!("table messages: {e}")))? {
                    let topic: i64 = row.get(0).map_err(|e| malformed(format!("table messages: {e}")))?;
                    if let Some(&i) = by_id.get(&topic) {
                        let t: i64 = row.get(1).map_err(|e| malformed(format!("table messages: {e}")))?;
                        let data = row.get_ref(2).and_then(|v| v.as_blob().map_err(Into::into));
                        f(i, t, data.map_err(|e| malformed(format!("table messages: {e}")))?)?;
                    }
                }
            }
        }
        Ok(())
    }
}
