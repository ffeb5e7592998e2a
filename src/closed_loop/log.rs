//! One MCAP file per closed-loop run, for Foxglove: JSON messages with `jsonschema` schemas
//! (so every field can be plotted), Foxglove's own schemas for the pose, the frame transform
//! and the log, and metadata records for the run's set-up and its summary.
//!
//! Topics (one message per sample unless noted):
//! - `/vehicle/state`: the true state in both forms, `sim` (`x y z psi u v w r`) and
//!   `network` (`x y z cos_psi sin_psi u v w r`), plus `psi_deg`;
//! - `/vehicle/pose`: `foxglove.PoseInFrame` in frame `ned` (z down);
//! - `/tf`: one `foxglove.FrameTransform` from `world` (z up) to `ned`, so the 3D panel
//!   shows the vehicle going down as it dives;
//! - `/mpc/reference`: depth and heading references;
//! - `/mpc/command`: the applied input, per-channel saturation, fallback and bound flags;
//! - `/mpc/prediction`: the horizon's predicted `x y z psi` as arrays, with their times;
//! - `/mpc/solver`: status, iterations, objective, microseconds per part of the cycle;
//! - `/log`: `foxglove.Log`, for fallbacks, envelope exits, deadline misses, bound
//!   violations, and the start and end of the run.
//!
//! Times are simulation time (the run starts at 0 ns).

use super::run::Sample;
use super::scenario::Scenario;
use super::summary::Summary;
use crate::mpc::MpcConfig;
use crate::runtime::Quantity;
use crate::types::{INPUT_NAMES, Input, NU, SIM_STATE_NAMES, STATE_NAMES};
use crate::vehicle::{VehicleParams, to_network};
use mcap::records::{MessageHeader, Metadata};
use serde::Serialize;
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

/// What can go wrong while writing a log.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    /// The file could not be created or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The MCAP writer failed.
    #[error("MCAP: {0}")]
    Mcap(#[from] mcap::McapError),
    /// A message could not be encoded.
    #[error("JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// The live view refused a channel.
    #[error("{0}")]
    View(String),
}

/// Severity of a `/log` message (Foxglove's levels).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    /// Start and end of the run.
    Info = 2,
    /// Envelope exits, deadline misses.
    Warning = 3,
    /// Fallbacks, bound violations.
    Error = 4,
}

/// The set-up of a run, written as the `run` metadata record.
#[derive(Debug, Clone)]
pub struct RunInfo<'a> {
    /// `"pinc"` or `"oracle"`.
    pub controller: &'a str,
    /// The model file whose envelope (and, for `pinc`, network) the controller uses.
    pub model_path: &'a Path,
    /// The scenario.
    pub scenario: &'a Scenario,
    /// The controller's configuration.
    pub config: &'a MpcConfig,
    /// Input bounds in force `(min, max)`.
    pub bounds: (Input, Input),
    /// Sample period (s).
    pub dt: f64,
    /// The plant's vehicle (before the scenario's disturbance).
    pub vehicle: &'a VehicleParams,
}

/// Counts of what a finished log holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogStats {
    /// Messages on all topics.
    pub messages: u64,
    /// `/log` messages among them.
    pub log_messages: u64,
}

/// Topics and their schemas, in the order their channel ids are assigned.
const TOPICS: [(&str, &str); 8] = [
    ("/vehicle/state", "pinc.VehicleState"),
    ("/vehicle/pose", "foxglove.PoseInFrame"),
    ("/tf", "foxglove.FrameTransform"),
    ("/mpc/reference", "pinc.Reference"),
    ("/mpc/command", "pinc.Command"),
    ("/mpc/prediction", "pinc.Prediction"),
    ("/mpc/solver", "pinc.Solver"),
    ("/log", "foxglove.Log"),
];
const STATE: usize = 0;
const POSE: usize = 1;
const TF: usize = 2;
const REFERENCE: usize = 3;
const COMMAND: usize = 4;
const PREDICTION: usize = 5;
const SOLVER: usize = 6;
const LOG: usize = 7;

/// Log time after which an MCAP writer closes its open chunk and flushes the file (ns): a log
/// or recording cut off (the process killed, the power lost) loses at most this much of what
/// it held, where the writer's size-based chunks (768 KiB) held about 5 s of a live session.
pub const CHUNK_INTERVAL_NS: u64 = 1_000_000_000;

/// A closed-loop log being written. Dropping it without [`McapLog::finish`] still leaves a
/// readable file (the writer finishes on drop), but without the summary record.
pub struct McapLog<W: Write + Seek = BufWriter<File>> {
    writer: mcap::Writer<W>,
    channels: [u16; TOPICS.len()],
    sequence: u32,
    log_messages: u64,
    /// Sample period, for the times of the predicted states.
    dt: f64,
    /// Whether the previous sample's rollout was inside the envelope (exits are logged when
    /// they start and when they end, not on every sample in between).
    was_inside: bool,
    /// The same for the predicted heading vector staying on the unit circle.
    was_on_circle: bool,
    /// The channels of a live run (`/link/cycle`, `/estimate`), each created on first use.
    live_channels: BTreeMap<&'static str, u16>,
    /// Log time (ns) of the first message of the open chunk.
    chunk_start: Option<u64>,
    /// Every message also served as it is written (`--foxglove`).
    #[cfg(feature = "live-view")]
    view: Option<super::live_view::LiveView>,
}

/// Foxglove's `time` type.
#[derive(Serialize)]
struct Stamp {
    sec: u64,
    nsec: u32,
}

fn stamp(t: f64) -> Stamp {
    let ns = nanos(t);
    Stamp { sec: ns / 1_000_000_000, nsec: (ns % 1_000_000_000) as u32 }
}

fn nanos(t: f64) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

/// SHA-256 of a file, as lowercase hex (what `sha256sum` prints).
///
/// # Errors
/// The file cannot be read.
pub fn file_sha256(path: &Path) -> Result<String, LogError> {
    use sha2::{Digest, Sha256};
    let bytes = std::fs::read(path).map_err(|source| LogError::Io { path: path.to_owned(), source })?;
    Ok(Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect())
}

impl McapLog {
    /// Creates `path` and writes the schemas, channels, frame transform and `run` metadata.
    ///
    /// # Errors
    /// The file cannot be created or written, or the model file cannot be hashed.
    pub fn create(path: &Path, info: &RunInfo) -> Result<Self, LogError> {
        let file = File::create(path).map_err(|source| LogError::Io { path: path.to_owned(), source })?;
        Self::new(BufWriter::new(file), info)
    }

    /// As [`McapLog::create`], every message also served on `view` as it is written.
    ///
    /// # Errors
    /// As [`McapLog::create`]; the view refuses a channel.
    #[cfg(feature = "live-view")]
    pub fn create_with_view(path: &Path, info: &RunInfo, view: super::live_view::LiveView) -> Result<Self, LogError> {
        let file = File::create(path).map_err(|source| LogError::Io { path: path.to_owned(), source })?;
        Self::start(BufWriter::new(file), info, Some(view))
    }
}

impl<W: Write + Seek> McapLog<W> {
    /// Starts a log on `out`.
    ///
    /// # Errors
    /// Writing fails, or the model file cannot be hashed.
    pub fn new(out: W, info: &RunInfo) -> Result<Self, LogError> {
        #[cfg(feature = "live-view")]
        return Self::start(out, info, None);
        #[cfg(not(feature = "live-view"))]
        Self::start(out, info)
    }

    fn start(
        out: W,
        info: &RunInfo,
        #[cfg(feature = "live-view")] mut view: Option<super::live_view::LiveView>,
    ) -> Result<Self, LogError> {
        // zstd chunks where feature `tools` builds zstd in (mcap's default then), uncompressed
        // otherwise: the main job's build compiles no compression library.
        let options = mcap::WriteOptions::new().library(concat!("pinc ", env!("CARGO_PKG_VERSION")));
        let mut writer = options.create(out)?;
        let mut channels = [0u16; TOPICS.len()];
        for (i, (topic, schema)) in TOPICS.iter().enumerate() {
            let data = serde_json::to_vec(&schema_of(schema))?;
            let schema_id = writer.add_schema(schema, "jsonschema", &data)?;
            channels[i] = writer.add_channel(schema_id, topic, "json", &BTreeMap::new())?;
            #[cfg(feature = "live-view")]
            if let Some(v) = &mut view {
                v.add_channel(channels[i], topic, schema, &data).map_err(LogError::View)?;
            }
        }
        writer.write_metadata(&Metadata { name: "run".into(), metadata: run_metadata(info)? })?;
        let mut log = Self {
            writer,
            channels,
            sequence: 0,
            log_messages: 0,
            dt: info.dt,
            was_inside: true,
            was_on_circle: true,
            live_channels: BTreeMap::new(),
            chunk_start: None,
            #[cfg(feature = "live-view")]
            view,
        };
        // NED seen from a z-up world: a half turn about x.
        log.write(
            TF,
            0.0,
            &json!({
                "timestamp": stamp(0.0), "parent_frame_id": "world", "child_frame_id": "ned",
                "translation": {"x": 0.0, "y": 0.0, "z": 0.0},
                "rotation": {"x": 1.0, "y": 0.0, "z": 0.0, "w": 0.0},
            }),
        )?;
        let what = format!(
            "{} MPC, scenario {}, horizon {}, model {}",
            info.controller,
            info.scenario.name(),
            info.config.horizon,
            info.model_path.display()
        );
        log.log(0.0, Level::Info, &what)?;
        Ok(log)
    }

    /// The timing of one cycle on a live vehicle, on `/link/cycle`: the state's age when its
    /// command went out (autopilot time then minus the state's stamp), the time from the
    /// state's arrival to the command's send, and the send's autopilot time.
    ///
    /// # Errors
    /// Writing fails.
    pub fn link_cycle(
        &mut self,
        t: f64,
        state_age_s: f64,
        latency_s: f64,
        sent_autopilot_s: f64,
    ) -> Result<(), LogError> {
        let m = json!({"state_age_s": state_age_s, "latency_s": latency_s, "sent_autopilot_s": sent_autopilot_s});
        self.live("/link/cycle", "pinc.LinkCycle", t, m)
    }

    /// A message of a live run on `topic` (created on first use, schema `schema`): the JSON
    /// object `fields` with the `timestamp` of `t` added.
    ///
    /// # Errors
    /// Writing fails.
    pub fn live(&mut self, topic: &'static str, schema: &'static str, t: f64, fields: Value) -> Result<(), LogError> {
        let channel_id = match self.live_channels.get(topic) {
            Some(id) => *id,
            None => {
                // The fields vary by vehicle (a truth where a simulator gives one): the schema
                // names the time stamp only and lets the rest be.
                let schema_json = object(json!({
                    "timestamp": object(json!({"sec": {"type": "integer"}, "nsec": {"type": "integer"}})),
                }));
                let data = serde_json::to_vec(&schema_json)?;
                let schema_id = self.writer.add_schema(schema, "jsonschema", &data)?;
                let id = self.writer.add_channel(schema_id, topic, "json", &BTreeMap::new())?;
                #[cfg(feature = "live-view")]
                if let Some(v) = &mut self.view {
                    v.add_channel(id, topic, schema, &data).map_err(LogError::View)?;
                }
                self.live_channels.insert(topic, id);
                id
            }
        };
        let mut m = match fields {
            Value::Object(m) => m,
            other => {
                let mut m = serde_json::Map::new();
                m.insert("value".into(), other);
                m
            }
        };
        m.insert("timestamp".into(), serde_json::to_value(stamp(t))?);
        self.write_on(channel_id, t, &m)
    }

    fn write(&mut self, topic: usize, t: f64, message: &impl Serialize) -> Result<(), LogError> {
        self.write_on(self.channels[topic], t, message)
    }

    fn write_on(&mut self, channel_id: u16, t: f64, message: &impl Serialize) -> Result<(), LogError> {
        let data = serde_json::to_vec(message)?;
        let header = MessageHeader { channel_id, sequence: self.sequence, log_time: nanos(t), publish_time: nanos(t) };
        self.sequence = self.sequence.wrapping_add(1);
        self.writer.write_to_known_channel(&header, &data)?;
        let start = *self.chunk_start.get_or_insert(header.log_time);
        if header.log_time.saturating_sub(start) >= CHUNK_INTERVAL_NS {
            // Closes the chunk and flushes the file: a run cut off keeps what it logged.
            self.writer.flush()?;
            self.chunk_start = None;
        }
        #[cfg(feature = "live-view")]
        if let Some(v) = &self.view {
            v.log(channel_id, header.log_time, &data);
        }
        Ok(())
    }

    /// A `/log` message at time `t`.
    ///
    /// # Errors
    /// Writing fails.
    pub fn log(&mut self, t: f64, level: Level, message: &str) -> Result<(), LogError> {
        self.log_messages += 1;
        let m = json!({
            "timestamp": stamp(t), "level": level as u8, "message": message,
            "name": "pinc.mpc", "file": "", "line": 0,
        });
        self.write(LOG, t, &m)
    }

    /// Everything about one sample of the loop, and `/log` messages for what went wrong.
    ///
    /// # Errors
    /// Writing fails.
    pub fn record(&mut self, s: &Sample) -> Result<(), LogError> {
        self.record_vehicle(s)?;
        self.record_controller(s)?;
        self.record_events(s)
    }

    /// `/vehicle/state` and `/vehicle/pose`: the true state in both forms.
    fn record_vehicle(&mut self, s: &Sample) -> Result<(), LogError> {
        let (t, st) = (s.t, &s.state);
        let net = to_network(st);
        let sim: BTreeMap<&str, f64> = SIM_STATE_NAMES.into_iter().zip(st.iter().copied()).collect();
        let network: BTreeMap<&str, f64> = STATE_NAMES.into_iter().zip(net.iter().copied()).collect();
        self.write(
            STATE,
            t,
            &json!({"timestamp": stamp(t), "sim": sim, "network": network, "psi_deg": st[3].to_degrees()}),
        )?;
        let (half_s, half_c) = (0.5 * st[3]).sin_cos();
        self.write(
            POSE,
            t,
            &json!({
                "timestamp": stamp(t), "frame_id": "ned",
                "pose": {
                    "position": {"x": st[0], "y": st[1], "z": st[2]},
                    "orientation": {"x": 0.0, "y": 0.0, "z": half_s, "w": half_c},
                },
            }),
        )
    }

    /// `/mpc/reference`, `/mpc/command`, `/mpc/prediction` and `/mpc/solver`.
    fn record_controller(&mut self, s: &Sample) -> Result<(), LogError> {
        let t = s.t;
        let r = &s.reference;
        self.write(
            REFERENCE,
            t,
            &json!({"timestamp": stamp(t), "depth_m": r.depth, "heading_rad": r.heading,
                    "heading_deg": r.heading.to_degrees(),
                    // The horizontal goal, where there is one (null: depth and heading only).
                    "north_m": r.horizontal.map(|h| h.north), "east_m": r.horizontal.map(|h| h.east),
                    "velocity_north_m_s": r.horizontal.map(|h| h.velocity[0]),
                    "velocity_east_m_s": r.horizontal.map(|h| h.velocity[1])}),
        )?;
        let c = &s.cycle;
        let named =
            |v: &dyn Fn(usize) -> Value| -> BTreeMap<&str, Value> { (0..NU).map(|j| (INPUT_NAMES[j], v(j))).collect() };
        self.write(
            COMMAND,
            t,
            &json!({
                "timestamp": stamp(t), "input": named(&|j| c.input[j].into()),
                "saturated": named(&|j| c.saturated[j].into()),
                "fallback": c.fallback.is_some(), "bound_violation": s.bound_violation,
            }),
        )?;
        let dt = self.dt;
        let pred = &s.prediction;
        let column = |i: usize| pred.iter().map(|x| x[i]).collect::<Vec<f64>>();
        self.write(
            PREDICTION,
            t,
            &json!({
                "timestamp": stamp(t),
                "t": (0..pred.len()).map(|k| t + k as f64 * dt).collect::<Vec<f64>>(),
                "x": column(0), "y": column(1), "z": column(2),
                "psi": pred.iter().map(|x| x[4].atan2(x[3])).collect::<Vec<f64>>(),
            }),
        )?;
        self.write(
            SOLVER,
            t,
            &json!({
                "timestamp": stamp(t), "status": format!("{:?}", c.status), "iterations": c.iterations,
                "objective": finite_or_null(c.objective),
                "rollout_linearise_us": c.linearise_us, "update_us": c.update_us,
                "solve_us": c.solve_us, "cycle_us": c.cycle_us, "deadline_missed": c.deadline_missed,
                "fallback": c.fallback.map(|f| f.to_string()), "envelope_exits": c.envelope.exits,
                "heading_off_circle": c.envelope.heading_off_circle,
            }),
        )
    }

    /// `/log` messages: fallbacks and bound violations (errors), deadline misses and the
    /// prediction leaving the training envelope (warnings), its return (info).
    fn record_events(&mut self, s: &Sample) -> Result<(), LogError> {
        let (t, c) = (s.t, &s.cycle);
        if let Some(f) = c.fallback {
            self.log(t, Level::Error, &format!("fallback to the shifted previous plan: {f}"))?;
        }
        if s.bound_violation {
            self.log(t, Level::Error, &format!("applied input {:?} outside the bounds", c.input.as_slice()))?;
        }
        if c.deadline_missed {
            self.log(t, Level::Warning, &format!("cycle took {:.0} us, past the deadline", c.cycle_us))?;
        }
        match (self.was_inside, c.envelope.first) {
            (true, Some(e)) => {
                let what = match e.quantity {
                    Quantity::State(i) => format!("state {}", STATE_NAMES[i]),
                    Quantity::Input(i) => format!("input {}", INPUT_NAMES[i]),
                };
                let message = format!(
                    "prediction leaves the training envelope at step {} of the horizon: {what} = {:.4} outside \
                     [{:.4}, {:.4}] ({} of {} steps outside)",
                    e.step,
                    e.value,
                    e.min,
                    e.max,
                    c.envelope.exits,
                    s.prediction.len().saturating_sub(1)
                );
                self.log(t, Level::Warning, &message)?;
            }
            (false, None) => self.log(t, Level::Info, "prediction back inside the training envelope")?,
            _ => {}
        }
        self.was_inside = c.envelope.inside();
        match (self.was_on_circle, c.envelope.heading_worst) {
            (true, Some(h)) => {
                let message = format!(
                    "predicted heading vector off the unit circle by {:+.2} % at step {} of the horizon ({} of {} \
                     steps beyond {} %)",
                    h.deviation * 100.0,
                    h.step,
                    c.envelope.heading_off_circle,
                    s.prediction.len().saturating_sub(1),
                    crate::runtime::HEADING_TOLERANCE * 100.0
                );
                self.log(t, Level::Warning, &message)?;
            }
            (false, None) => self.log(t, Level::Info, "predicted heading vector back on the unit circle")?,
            _ => {}
        }
        self.was_on_circle = c.envelope.heading_on_circle();
        Ok(())
    }

    /// Writes the `summary` metadata record and the file's summary section.
    ///
    /// # Errors
    /// Writing fails.
    pub fn finish(mut self, summary: &Summary, t_end: f64) -> Result<LogStats, LogError> {
        let line = format!(
            "run ended after {} samples: RMS depth {:.4} m, RMS heading {:.3} deg, {} fallbacks",
            summary.samples, summary.rms_depth_m, summary.rms_heading_deg, summary.fallbacks
        );
        self.log(t_end, Level::Info, &line)?;
        let fields = serde_json::to_value(summary)?;
        let metadata = fields.as_object().into_iter().flatten().map(|(k, v)| (k.clone(), v.to_string())).collect();
        self.writer.write_metadata(&Metadata { name: "summary".into(), metadata })?;
        let written = self.writer.finish()?;
        // `finish` wrote the summary section and footer; what is still buffered goes out now,
        // with its error (dropping a `BufWriter` would swallow it).
        self.writer.into_inner().flush().map_err(mcap::McapError::from)?;
        let messages = written.stats.map_or(0, |s| s.message_count);
        #[cfg(feature = "live-view")]
        if let Some(v) = self.view.take() {
            v.stop();
        }
        Ok(LogStats { messages, log_messages: self.log_messages })
    }
}

fn finite_or_null(v: f64) -> Value {
    if v.is_finite() { v.into() } else { Value::Null }
}

/// Metadata values are strings; numbers and arrays are written as JSON.
fn run_metadata(info: &RunInfo) -> Result<BTreeMap<String, String>, LogError> {
    let c = info.config;
    let vec4 = |v: &Input| serde_json::to_string(v.as_slice());
    let mut m = BTreeMap::new();
    let mut put = |k: &str, v: String| m.insert(k.to_owned(), v);
    put("pinc_version", env!("CARGO_PKG_VERSION").into());
    put("controller", info.controller.into());
    put("model_path", info.model_path.display().to_string());
    put("model_sha256", file_sha256(info.model_path)?);
    put("scenario", info.scenario.name().into());
    put("scenario_duration_s", info.scenario.duration().to_string());
    put("scenario_damping_scale", info.scenario.damping_scale.to_string());
    put("scenario_current_xy", serde_json::to_string(&info.scenario.current)?);
    put("horizon", c.horizon.to_string());
    put("dt_s", info.dt.to_string());
    put("plant_vehicle", serde_json::to_string(info.vehicle)?);
    put("input_min", vec4(&info.bounds.0)?);
    put("input_max", vec4(&info.bounds.1)?);
    put("input_names", serde_json::to_string(&INPUT_NAMES)?);
    put("weight_depth", c.depth.to_string());
    put("weight_heading", c.heading.to_string());
    put("weight_velocity_uvwr", serde_json::to_string(&c.velocity)?);
    put("weight_input", serde_json::to_string(&c.input)?);
    put("weight_input_rate", serde_json::to_string(&c.input_rate)?);
    put("weight_terminal_factor", c.terminal.to_string());
    put("rate_limit", serde_json::to_string(&c.rate_limit)?);
    put("qp_solver", c.qp.name().into());
    put("solver_time_limit_s", c.solver_time_limit.to_string());
    put("solver_max_iter", c.solver_max_iter.to_string());
    put("deadline_s", c.deadline.to_string());
    put("envelope_fallback", c.envelope_fallback.to_string());
    Ok(m)
}

fn num() -> Value {
    json!({"type": "number"})
}

fn object(properties: Value) -> Value {
    json!({"type": "object", "properties": properties})
}

fn numbers(names: &[&str]) -> Value {
    object(names.iter().map(|n| (n.to_string(), num())).collect::<serde_json::Map<_, _>>().into())
}

fn flags() -> Value {
    object(
        INPUT_NAMES
            .iter()
            .map(|n| (n.to_string(), json!({"type": "boolean"})))
            .collect::<serde_json::Map<_, _>>()
            .into(),
    )
}

fn array() -> Value {
    json!({"type": "array", "items": {"type": "number"}})
}

/// The JSON schema of each topic's messages.
fn schema_of(name: &str) -> Value {
    let time = object(json!({"sec": {"type": "integer"}, "nsec": {"type": "integer"}}));
    let vec3 = numbers(&["x", "y", "z"]);
    let quat = numbers(&["x", "y", "z", "w"]);
    let mut s = match name {
        "pinc.VehicleState" => object(json!({
            "timestamp": time, "sim": numbers(&SIM_STATE_NAMES),
            "network": numbers(&STATE_NAMES), "psi_deg": num(),
        })),
        "foxglove.PoseInFrame" => object(json!({
            "timestamp": time, "frame_id": {"type": "string"},
            "pose": object(json!({"position": vec3, "orientation": quat})),
        })),
        "foxglove.FrameTransform" => object(json!({
            "timestamp": time, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
            "translation": vec3, "rotation": quat,
        })),
        "pinc.Reference" => {
            let maybe = json!({"type": ["number", "null"]});
            object(json!({"timestamp": time, "depth_m": num(), "heading_rad": num(), "heading_deg": num(),
                "north_m": maybe, "east_m": maybe, "velocity_north_m_s": maybe, "velocity_east_m_s": maybe}))
        }
        "pinc.Command" => object(json!({
            "timestamp": time, "input": numbers(&INPUT_NAMES), "saturated": flags(),
            "fallback": {"type": "boolean"}, "bound_violation": {"type": "boolean"},
        })),
        "pinc.Prediction" => {
            object(json!({"timestamp": time, "t": array(), "x": array(), "y": array(), "z": array(), "psi": array()}))
        }
        "pinc.Solver" => object(json!({
            "timestamp": time, "status": {"type": "string"}, "iterations": {"type": "integer"},
            "objective": {"type": ["number", "null"]}, "rollout_linearise_us": num(), "update_us": num(),
            "solve_us": num(), "cycle_us": num(), "deadline_missed": {"type": "boolean"},
            "fallback": {"type": ["string", "null"]}, "envelope_exits": {"type": "integer"},
            "heading_off_circle": {"type": "integer"},
        })),
        "foxglove.Log" => object(json!({
            "timestamp": time,
            "level": {"type": "integer", "oneOf": [
                {"title": "UNKNOWN", "const": 0}, {"title": "DEBUG", "const": 1}, {"title": "INFO", "const": 2},
                {"title": "WARNING", "const": 3}, {"title": "ERROR", "const": 4}, {"title": "FATAL", "const": 5},
            ]},
            "message": {"type": "string"}, "name": {"type": "string"}, "file": {"type": "string"},
            "line": {"type": "integer", "minimum": 0},
        })),
        other => unreachable!("no schema for {other}"),
    };
    s["title"] = name.into();
    s
}
