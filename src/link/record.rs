//! The MCAP file of a vehicle session, in the form `pinc dataset import` reads: JSON messages
//! with `jsonschema` schemas (as the closed loop's log, [`crate::closed_loop::McapLog`]).
//!
//! Topics:
//! - `/mavlink/<NAME>`: every MAVLink message received, one topic per message type, its
//!   fields as the `mavlink` crate names them plus `type` and `header` (sender and sequence);
//! - `/vehicle/state`: pinc's reconstructed state, field `sim` = `{x y z psi u v w r}` (null
//!   where a part is stale or missing), each part's age and freshness, the depth's source and
//!   what controller the state allows;
//! - `/mpc/command`: field `input` = `{X Y Z Mz}` at every state time, null where the body
//!   input is not known (a plain recording commands nothing);
//! - `/vehicle/outputs`: the thruster outputs of `SERVO_OUTPUT_RAW`, channel -> PWM (us);
//! - `/log`: `foxglove.Log` lines (start, mode and arming changes, parts going stale, end).
//!
//! Times are the autopilot's (`time_boot_ms`). The file is written under a temporary name
//! (`RUN.mcap.partial`) and renamed when finished, so an interrupted run leaves no half file.

use super::link::Received;
use super::state::{Capability, DepthSource, RawState};
use crate::closed_loop::Level;
use crate::estimation::Estimate;
use crate::estimation::mavlink::servo_pwm;
use crate::types::INPUT_NAMES;
use crate::types::Input;
use mavlink::dialects::ardupilotmega::SERVO_OUTPUT_RAW_DATA;
use mcap::records::{MessageHeader, Metadata};
use serde_json::{Map, Value, json};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// What can go wrong while recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The file could not be created, written or renamed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The MCAP writer failed.
    #[error("{path}: MCAP: {source}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: mcap::McapError,
    },
    /// A message could not be encoded.
    #[error("{path}: JSON of {what}: {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// What was being encoded.
        what: String,
        /// The cause.
        source: serde_json::Error,
    },
}

/// Counts of a finished recording.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RecordStats {
    /// Messages on all topics.
    pub messages: u64,
    /// MAVLink messages per type.
    pub mavlink: BTreeMap<String, u64>,
    /// `/vehicle/state` samples.
    pub states: u64,
    /// `/log` lines.
    pub log_lines: u64,
}

/// A recording being written.
pub struct Recorder {
    writer: Option<mcap::Writer<BufWriter<File>>>,
    partial: PathBuf,
    path: PathBuf,
    channels: HashMap<String, u16>,
    sequence: u32,
    stats: RecordStats,
    /// Log time (ns) of the first message of the open chunk.
    chunk_start: Option<u64>,
}

/// The `.partial` name a recording is written under.
pub fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    name.push(".partial");
    path.with_file_name(name)
}

fn nanos(t: f64) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

fn stamp(t: f64) -> Value {
    let ns = nanos(t);
    json!({"sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000})
}

fn null_if_nan(v: f64) -> Value {
    if v.is_finite() { v.into() } else { Value::Null }
}

impl Recorder {
    /// Starts `path` (as `path.partial` until [`Recorder::finish`]) with a `session` metadata
    /// record.
    ///
    /// # Errors
    /// The file cannot be created or written.
    pub fn create(path: &Path, session: BTreeMap<String, String>) -> Result<Self, RecordError> {
        let partial = partial_path(path);
        let file = File::create(&partial).map_err(|source| RecordError::Io { path: partial.clone(), source })?;
        let options = mcap::WriteOptions::new().library(concat!("pinc ", env!("CARGO_PKG_VERSION")));
        let mcap_err = |source| RecordError::Mcap { path: partial.clone(), source };
        let mut writer = options.create(BufWriter::new(file)).map_err(mcap_err)?;
        writer.write_metadata(&Metadata { name: "session".into(), metadata: session }).map_err(mcap_err)?;
        Ok(Self {
            writer: Some(writer),
            partial,
            path: path.to_owned(),
            channels: HashMap::new(),
            sequence: 0,
            stats: RecordStats::default(),
            chunk_start: None,
        })
    }

    fn channel(&mut self, topic: &str, schema: &str, properties: Value) -> Result<u16, RecordError> {
        if let Some(id) = self.channels.get(topic) {
            return Ok(*id);
        }
        let body = json!({"type": "object", "title": schema, "properties": properties});
        let data = serde_json::to_vec(&body).map_err(|source| RecordError::Json {
            path: self.partial.clone(),
            what: format!("the schema of {topic}"),
            source,
        })?;
        let partial = self.partial.clone();
        let err = |source| RecordError::Mcap { path: partial.clone(), source };
        let writer = self.writer.as_mut().expect("writer lives until finish");
        let schema_id = writer.add_schema(schema, "jsonschema", &data).map_err(err)?;
        let id = writer.add_channel(schema_id, topic, "json", &BTreeMap::new()).map_err(err)?;
        self.channels.insert(topic.to_owned(), id);
        Ok(id)
    }

    fn write(
        &mut self,
        topic: &str,
        schema: &str,
        properties: Value,
        t: f64,
        message: &Value,
    ) -> Result<(), RecordError> {
        let channel_id = self.channel(topic, schema, properties)?;
        let data = serde_json::to_vec(message).map_err(|source| RecordError::Json {
            path: self.partial.clone(),
            what: topic.to_owned(),
            source,
        })?;
        let header = MessageHeader { channel_id, sequence: self.sequence, log_time: nanos(t), publish_time: nanos(t) };
        self.sequence = self.sequence.wrapping_add(1);
        self.stats.messages += 1;
        let writer = self.writer.as_mut().expect("writer lives until finish");
        let mut e = writer.write_to_known_channel(&header, &data);
        let start = *self.chunk_start.get_or_insert(header.log_time);
        if e.is_ok() && header.log_time.saturating_sub(start) >= crate::closed_loop::CHUNK_INTERVAL_NS {
            // Closes the chunk and flushes the file: what it holds survives a cut.
            e = writer.flush();
            self.chunk_start = None;
        }
        e.map_err(|source| RecordError::Mcap { path: self.partial.clone(), source })
    }

    /// A MAVLink message on `/mavlink/<NAME>` at autopilot time `t` (s).
    ///
    /// # Errors
    /// Writing fails.
    pub fn mavlink(&mut self, t: f64, r: &Received) -> Result<(), RecordError> {
        let name = mavlink::Message::message_name(&r.message);
        let mut value = serde_json::to_value(&r.message).map_err(|source| RecordError::Json {
            path: self.partial.clone(),
            what: name.to_owned(),
            source,
        })?;
        if let Value::Object(m) = &mut value {
            m.insert(
                "header".into(),
                json!({"system_id": r.header.system_id, "component_id": r.header.component_id,
                       "sequence": r.header.sequence}),
            );
        }
        *self.stats.mavlink.entry(name.to_owned()).or_default() += 1;
        self.write(&format!("/mavlink/{name}"), &format!("mavlink.{name}"), json!({}), t, &value)
    }

    /// The state on `/vehicle/state` and, at the same time, the body input on `/mpc/command`
    /// (`None`: not known, written as nulls so that no dataset window spans it).
    ///
    /// # Errors
    /// Writing fails.
    pub fn state(&mut self, s: &RawState, input: Option<&Input>) -> Result<(), RecordError> {
        let t = s.t;
        let sim: Map<String, Value> =
            s.named().map(|(k, v)| (k.to_owned(), v.map_or(Value::Null, Value::from))).collect();
        let age: Map<String, Value> =
            s.parts.iter().map(|p| (p.part.name().to_owned(), p.age.map_or(Value::Null, Value::from))).collect();
        let fresh: Map<String, Value> = s.parts.iter().map(|p| (p.part.name().to_owned(), p.fresh.into())).collect();
        let capability = match s.capability {
            Capability::Full => "full",
            Capability::DepthHeading => "depth_heading",
            Capability::None => "none",
        };
        let depth_source = s.depth_source.map(|d| match d {
            DepthSource::Position => "position",
            DepthSource::Pressure => "pressure",
        });
        let state = json!({
            "timestamp": stamp(t), "t_autopilot_s": t, "sim": sim, "psi_deg": null_if_nan(s.sim[3].to_degrees()),
            "age_s": age, "fresh": fresh, "depth_source": depth_source, "capability": capability,
        });
        let num_or_null = json!({"type": ["number", "null"]});
        let names = |names: &[&str]| -> Value {
            Value::Object(names.iter().map(|n| (n.to_string(), num_or_null.clone())).collect())
        };
        let state_props = json!({"sim": {"type": "object", "properties": names(&crate::types::SIM_STATE_NAMES)}});
        self.write("/vehicle/state", "pinc.VehicleState", state_props, t, &state)?;
        self.stats.states += 1;
        let input: Map<String, Value> = INPUT_NAMES
            .iter()
            .enumerate()
            .map(|(j, n)| (n.to_string(), input.map_or(Value::Null, |u| null_if_nan(u[j]))))
            .collect();
        let command = json!({"timestamp": stamp(t), "input": input});
        let command_props = json!({"input": {"type": "object", "properties": names(&INPUT_NAMES)}});
        self.write("/mpc/command", "pinc.Command", command_props, t, &command)
    }

    /// The state estimate on `/estimate` (`crate::estimation`): `x y z psi u v w r`, each
    /// part's standard deviation, the input-equivalent disturbance and its spread.
    ///
    /// # Errors
    /// Writing fails.
    pub fn estimate(&mut self, e: &Estimate) -> Result<(), RecordError> {
        let named = |v: &[f64]| -> Map<String, Value> {
            crate::types::SIM_STATE_NAMES.iter().zip(v).map(|(k, x)| (k.to_string(), null_if_nan(*x))).collect()
        };
        let input = |v: &[f64]| -> Map<String, Value> {
            INPUT_NAMES.iter().zip(v).map(|(k, x)| (k.to_string(), null_if_nan(*x))).collect()
        };
        let m = json!({
            "timestamp": stamp(e.t), "t_autopilot_s": e.t, "sim": named(e.sim.as_slice()), "std": named(&e.std),
            "disturbance": input(e.disturbance.as_slice()), "disturbance_std": input(&e.disturbance_std),
        });
        self.write("/estimate", "pinc.Estimate", json!({}), e.t, &m)
    }

    /// The thruster outputs on `/vehicle/outputs`: channel number -> PWM (us), as the
    /// autopilot reports them (0: output not configured).
    ///
    /// # Errors
    /// Writing fails.
    pub fn outputs(&mut self, t: f64, o: &SERVO_OUTPUT_RAW_DATA) -> Result<(), RecordError> {
        let pwm = servo_pwm(o);
        // Port n carries channels 8n+1 ..= 8n+8.
        let first = 8 * u32::from(o.port) + 1;
        let channels: Map<String, Value> =
            pwm.iter().enumerate().map(|(i, p)| ((first + i as u32).to_string(), Value::from(*p))).collect();
        let m = json!({"timestamp": stamp(t), "time_usec": o.time_usec, "pwm": channels});
        self.write("/vehicle/outputs", "pinc.ThrusterOutputs", json!({}), t, &m)
    }

    /// One excitation sample's heave on `/excite/heave`: what the excitation asked, what was
    /// sent, and whether the depth band's feedback set it (`pinc vehicle excite --depth-band`):
    /// a fit can tell closed-loop heave from open-loop heave.
    ///
    /// # Errors
    /// Writing fails.
    pub fn excite_heave(&mut self, t: f64, excitation: f64, sent: f64, feedback: bool) -> Result<(), RecordError> {
        let m = json!({"timestamp": stamp(t), "excitation_z": excitation, "sent_z": sent, "feedback": feedback});
        self.write("/excite/heave", "pinc.ExciteHeave", json!({}), t, &m)
    }

    /// A `/log` line at autopilot time `t`.
    ///
    /// # Errors
    /// Writing fails.
    pub fn log(&mut self, t: f64, level: Level, message: &str) -> Result<(), RecordError> {
        self.stats.log_lines += 1;
        let m = json!({
            "timestamp": stamp(t), "level": level as u8, "message": message,
            "name": "pinc.vehicle", "file": "", "line": 0,
        });
        self.write("/log", "foxglove.Log", json!({}), t, &m)
    }

    /// Finishes the file and renames it to its final name.
    ///
    /// # Errors
    /// Writing, flushing or renaming fails (the partial file is then removed).
    pub fn finish(mut self) -> Result<RecordStats, RecordError> {
        let writer = self.writer.take().expect("finish runs once");
        let done = Self::close(writer, &self.partial, &self.path);
        if done.is_err() {
            let _ = std::fs::remove_file(&self.partial);
        }
        done.map(|()| std::mem::take(&mut self.stats))
    }

    fn close(mut writer: mcap::Writer<BufWriter<File>>, partial: &Path, path: &Path) -> Result<(), RecordError> {
        let mcap_err = |source| RecordError::Mcap { path: partial.to_owned(), source };
        writer.finish().map_err(mcap_err)?;
        // What is still buffered goes out now, with its error (dropping a `BufWriter` would
        // swallow it), and reaches the disk before the rename makes the file visible.
        let io_err = |source| RecordError::Io { path: partial.to_owned(), source };
        let file = writer.into_inner().into_inner().map_err(|e| io_err(e.into_error()))?;
        file.sync_all().map_err(io_err)?;
        drop(file);
        std::fs::rename(partial, path).map_err(|source| RecordError::Io { path: path.to_owned(), source })
    }
}

impl Drop for Recorder {
    /// A recording not finished leaves no file behind.
    fn drop(&mut self) {
        if let Some(w) = self.writer.take() {
            drop(w);
            let _ = std::fs::remove_file(&self.partial);
        }
    }
}

/// The body input of each state sample from the thruster outputs the autopilot reports
/// (`SERVO_OUTPUT_RAW`, read through a vehicle file's thrusters by
/// [`crate::estimation::mavlink::MavlinkMeasurements`]): the input over the sample period
/// after the state's time, `[t, t + period)`, each output held until the next (so outputs
/// faster than the states are averaged, as `pinc dataset import` averages inputs), known once
/// an output at or after `t + period` arrived.
#[derive(Debug, Clone)]
pub struct InputsFromOutputs {
    period: f64,
    max_gap: f64,
    /// (autopilot time s, input) of each output message, in time order.
    outputs: VecDeque<(f64, Input)>,
    pending: VecDeque<RawState>,
}

impl InputsFromOutputs {
    /// Inputs over samples of `period` s; an output older than `max_gap` s at a state's time
    /// (outputs stopped) leaves that state's input unknown.
    pub fn new(period: f64, max_gap: f64) -> Self {
        Self { period, max_gap, outputs: VecDeque::new(), pending: VecDeque::new() }
    }

    /// The input the outputs at autopilot time `t` (s) stand for. Out-of-order ones are
    /// dropped.
    pub fn applied(&mut self, t: f64, input: Input) {
        if self.outputs.back().is_some_and(|(last, _)| t <= *last) {
            return;
        }
        self.outputs.push_back((t, input));
    }

    /// A state sample whose input is wanted.
    pub fn state(&mut self, s: RawState) {
        self.pending.push_back(s);
    }

    /// The states whose input is known or will never be (autopilot time `now`), in order.
    pub fn ready(&mut self, now: f64) -> Vec<(RawState, Option<Input>)> {
        let eps = 1e-4;
        let mut out = Vec::new();
        while let Some(s) = self.pending.front() {
            let end = s.t + self.period;
            let covered = self.outputs.back().is_some_and(|(t, _)| *t >= end - eps);
            if !covered && now < end + self.max_gap {
                break;
            }
            let input = self.input_over(s.t, end);
            out.push((self.pending.pop_front().expect("front exists"), input));
        }
        // Keep the output in effect at the oldest pending state's time, drop older ones.
        let keep_from = self.pending.front().map_or(now - self.period, |s| s.t);
        while self.outputs.len() > 1 && self.outputs[1].0 <= keep_from + eps {
            self.outputs.pop_front();
        }
        out
    }

    /// Every pending state, with what is known (at the end of a recording).
    pub fn flush(&mut self) -> Vec<(RawState, Option<Input>)> {
        self.ready(f64::INFINITY)
    }

    fn input_over(&self, start: f64, end: f64) -> Option<Input> {
        let eps = 1e-4;
        let first = self.outputs.iter().rposition(|(t, _)| *t <= start + eps)?;
        let mut sum = Input::zeros();
        let mut covered = 0.0;
        let list: Vec<&(f64, Input)> = self.outputs.iter().skip(first).collect();
        for (i, (t, u)) in list.iter().enumerate() {
            let next = list.get(i + 1).map_or(end, |n| n.0);
            if next - t > self.max_gap {
                return None;
            }
            let (a, b) = (t.max(start), next.min(end));
            if b > a {
                sum += u * (b - a);
                covered += b - a;
            }
            if next >= end {
                break;
            }
        }
        (covered >= self.period - 2.0 * eps && sum.iter().all(|v| v.is_finite())).then(|| sum / covered)
    }
}

/// The eight PWM outputs (us) of one `SERVO_OUTPUT_RAW` message, in channel order.
#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::import::{McapTopics, read_mcap};
    use crate::estimation::mavlink::{MavlinkMeasurements, Observation};
    use crate::link::state::{Part, PartStatus};
    use crate::vehicle::Thrusters;
    use mavlink::dialects::ardupilotmega::MavMessage;

    fn estimate(t: f64, sim: [f64; 8]) -> RawState {
        let part = |part| PartStatus { part, stamp: Some(t), age: Some(0.0), fresh: true };
        RawState {
            t,
            sim,
            parts: Part::ALL.map(part),
            depth_source: Some(DepthSource::Position),
            capability: Capability::Full,
        }
    }

    #[test]
    fn dataset_import_reads_the_recorded_state_and_missing_inputs() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let mut rec = Recorder::create(&path, BTreeMap::new()).unwrap();
        assert!(partial_path(&path).exists() && !path.exists());
        let a = [1.0, 2.0, 3.0, 0.5, 0.1, 0.2, 0.3, 0.4];
        let mut b = a;
        b[4] = f64::NAN; // a stale velocity
        rec.state(&estimate(10.0, a), Some(&Input::from([1.0, 2.0, 3.0, 4.0]))).unwrap();
        rec.state(&estimate(10.08, b), None).unwrap();
        rec.log(10.1, Level::Info, "end").unwrap();
        let stats = rec.finish().unwrap();
        assert_eq!((stats.states, stats.log_lines, stats.messages), (2, 1, 5));
        assert!(path.exists() && !partial_path(&path).exists());
        let run = read_mcap(&path, &McapTopics::default()).unwrap();
        assert_eq!(run.t, [10.0, 10.08]);
        assert_eq!(run.states[0].as_slice(), a);
        assert!(run.states[1][4].is_nan() && run.states[1][5] == 0.2);
        assert_eq!(run.inputs[0].as_slice(), [1.0, 2.0, 3.0, 4.0]);
        assert!(run.inputs[1].iter().all(|v| v.is_nan()));
    }

    #[test]
    fn an_unfinished_recording_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let mut rec = Recorder::create(&path, BTreeMap::new()).unwrap();
        rec.log(0.0, Level::Info, "start").unwrap();
        drop(rec);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn inputs_average_the_outputs_held_over_each_sample() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ardusub/sitl_vectored.toml");
        let thrusters = Thrusters::load(path).unwrap();
        let mut p = InputsFromOutputs::new(0.08, 0.5);
        let mut reader = MavlinkMeasurements::new(1013.25, 1000.0, Some(thrusters.clone()));
        let mut outputs = |p: &mut InputsFromOutputs, now: f64, ms: u32, pwm5: u16| {
            let o = SERVO_OUTPUT_RAW_DATA {
                time_usec: ms * 1000,
                servo1_raw: 1500,
                servo2_raw: 1500,
                servo3_raw: 1500,
                servo4_raw: 1500,
                servo5_raw: pwm5,
                servo6_raw: pwm5,
                ..Default::default()
            };
            reader.observe(now, &MavMessage::SERVO_OUTPUT_RAW(o), |ob| {
                if let Observation::Applied(t, u) = ob {
                    p.applied(t, u);
                }
            });
        };
        let s = |t: f64| estimate(t, [0.0; 8]);
        // Outputs every 20 ms; the vertical thrusters' 1700 first reported at 1.02 s, so dated
        // 1.01 s (halfway from the report before, `change_time`): 7/8 of the period.
        outputs(&mut p, 1.0, 1000, 1500);
        p.state(s(1.0));
        assert!(p.ready(1.0).is_empty(), "the sample's period is not covered yet");
        for ms in [1020, 1040, 1060] {
            outputs(&mut p, f64::from(ms) / 1e3, ms, 1700);
        }
        assert!(p.ready(1.06).is_empty());
        outputs(&mut p, 1.08, 1080, 1700);
        let got = p.ready(1.08);
        assert_eq!(got.len(), 1);
        let z = got[0].1.unwrap()[2];
        let full = thrusters.input_from_commands(&[1500.0, 1500.0, 1500.0, 1500.0, 1700.0, 1700.0])[2];
        assert!((z - 0.875 * full).abs() < 1e-9, "{z} vs 7/8 of {full}");
        // Outputs stop: the next state's input is unknown once the gap passes.
        p.state(s(1.6));
        assert!(p.ready(2.0).is_empty());
        let late = p.ready(2.3);
        assert_eq!(late.len(), 1);
        assert!(late[0].1.is_none());
    }
}
