//! Recorded runs from MCAP logs with JSON messages: by default the logs `mpc_track` writes
//! (`/vehicle/state` field `sim`, `/mpc/command` field `input`); any log with a state topic
//! and a command topic in that form works with its own topic and field names.

use super::{ImportError, McapTopics, Recording};
use crate::types::{INPUT_NAMES, Input, NS, NU, SIM_STATE_NAMES, SimState};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The numbers `names` of the object at `field` (a dotted path) in `msg`.
fn numbers<const N: usize>(msg: &Value, field: &str, names: [&str; N]) -> Result<[f64; N], String> {
    let mut obj = msg;
    for part in field.split('.') {
        obj = obj.get(part).ok_or_else(|| format!("no field {field:?}"))?;
    }
    let mut out = [0.0; N];
    for (o, name) in out.iter_mut().zip(names) {
        // JSON has no NaN: a null is a missing value (the row is skipped and counted).
        *o = match obj.get(name) {
            Some(Value::Null) => f64::NAN,
            Some(v) => v.as_f64().ok_or_else(|| format!("field {field}.{name} is not a number: {v}"))?,
            None => return Err(format!("field {field:?} has no {name:?}")),
        };
    }
    Ok(out)
}

/// Reads one run: one row per state message, in log-time order, with the command logged at
/// the same time (a state without one gets a NaN input, so no window spans it).
///
/// # Errors
/// The file cannot be read or is not MCAP, a topic is missing (the error lists the topics the
/// file has), a message is not JSON or lacks a field.
pub fn read_mcap(path: &Path, topics: &McapTopics) -> Result<Recording, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    let bytes = std::fs::read(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
    let (stream, mut cut) = super::mcap_cut::message_stream(&bytes).map_err(malformed)?;
    let mut states: BTreeMap<u64, SimState> = BTreeMap::new();
    let mut commands: BTreeMap<u64, Input> = BTreeMap::new();
    let mut seen = BTreeSet::new();
    for message in stream {
        let message = message.map_err(|e| malformed(format!("damaged MCAP: {e}")))?;
        if let Some(c) = &mut cut {
            c.saw(message.log_time);
        }
        let topic = message.channel.topic.as_str();
        seen.insert(topic.to_string());
        let (is_state, field) = if topic == topics.state_topic {
            (true, &topics.state_field)
        } else if topic == topics.command_topic {
            (false, &topics.command_field)
        } else {
            continue;
        };
        let at = |m: String| malformed(format!("{topic} at log time {} ns: {m}", message.log_time));
        if message.channel.message_encoding != "json" {
            return Err(at(format!("message encoding {:?}, only json is read", message.channel.message_encoding)));
        }
        let value: Value = serde_json::from_slice(&message.data).map_err(|e| at(format!("not JSON: {e}")))?;
        if is_state {
            let s = numbers::<NS>(&value, field, SIM_STATE_NAMES).map_err(at)?;
            states.insert(message.log_time, SimState::from(s));
        } else {
            let u = numbers::<NU>(&value, field, INPUT_NAMES).map_err(at)?;
            commands.insert(message.log_time, Input::from(u));
        }
    }
    for (topic, empty) in [(&topics.state_topic, states.is_empty()), (&topics.command_topic, commands.is_empty())] {
        if empty {
            let have: Vec<&str> = seen.iter().map(String::as_str).collect();
            return Err(malformed(format!("no messages on topic {topic} (the file has: {})", have.join(", "))));
        }
    }
    let mut rec = Recording::empty(path);
    rec.notes.extend(cut.map(|c| c.to_string()));
    for (time, s) in states {
        rec.t.push(time as f64 * 1e-9);
        rec.states.push(s);
        rec.inputs.push(commands.get(&time).copied().unwrap_or(Input::from([f64::NAN; NU])));
    }
    Ok(rec)
}
