//! `pinc vehicle status`, `record` and `excite`: pinc as a MAVLink participant next to an
//! ArduSub autopilot (docs/VEHICLE.md).

use mavlink::dialects::ardupilotmega::{AUTOPILOT_VERSION_DATA, HEARTBEAT_DATA, MavMessage};
use pinc::closed_loop::Level;
use pinc::estimation::mavlink::Observation;
use pinc::estimation::{Estimate, Estimator, NoiseSettings};
use pinc::link::SigningKey;
use pinc::link::cli::{DriveArgs, LinkArgs, non_negative, open, positive};
use pinc::link::drive::{AUTOPILOT_ESTIMATE_RATE_HZ, read_autopilot_config, severity_level, statustext};
use pinc::link::link::{AUTOPILOT_VERSION_ID, EKF_STATUS_REPORT_ID, is_ground_station};
use pinc::link::outputs::{OutputFunctions, function_name};
use pinc::link::state::message_time;
use pinc::link::{
    Autopilot, Capability, Drive, Fresh, InputsFromOutputs, Part, Received, Recorder, Stopped, SubMode, Trigger,
};
use pinc::link::{DepthBand, EkfStatus, HeadingReference};
use pinc::vehicle::{Rk4Vehicle, Thrusters, VehicleParams};
use serde_json::{Value, json};
use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// `pinc vehicle` actions.
#[derive(clap::Subcommand)]
pub enum VehicleAction {
    /// Wait for the autopilot's heartbeat and print its type, firmware, mode, armed state and
    /// which parts of the state it sends at what rates; exit 1 when nothing answers.
    Status(StatusArgs),
    /// Record every MAVLink message, pinc's reconstructed state and the thruster outputs to
    /// an MCAP file that `pinc dataset import` reads.
    Record(RecordArgs),
    /// Play an excitation file (`pinc excitation`) open loop on the vehicle and record it as
    /// `record` does, with every safety stop (docs/VEHICLE.md).
    Excite(ExciteArgs),
    /// Give the autopilot a MAVLink 2 signing key (SETUP_SIGNING), then check that it answers
    /// signed; from then on connect with --signing-key FILE.
    SetupSigning(SetupSigningArgs),
}

/// Arguments of `pinc vehicle setup-signing`.
#[derive(clap::Args)]
pub struct SetupSigningArgs {
    /// Connection, as for the other actions (the link must not be signed yet, or signed with
    /// --signing-key, the key in force).
    #[command(flatten)]
    link: LinkArgs,
    /// The new key file: 64 hex digits, or a passphrase whose SHA-256 is the key.
    #[arg(long, value_name = "FILE")]
    key: PathBuf,
}

/// Arguments of `pinc vehicle status`.
#[derive(clap::Args)]
pub struct StatusArgs {
    #[command(flatten)]
    link: LinkArgs,
    /// Seconds over which the message rates are measured.
    #[arg(long, default_value_t = 3.0)]
    window: f64,
    /// Vehicle file: which ways of commanding reach its thrusters' outputs [default: a
    /// BlueROV2's six thrusters on outputs 1-6].
    #[arg(long)]
    vehicle: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// Arguments of `pinc vehicle record`.
#[derive(clap::Args)]
pub struct RecordArgs {
    #[command(flatten)]
    link: LinkArgs,
    /// Output MCAP file (written as OUT.partial and renamed when complete).
    #[arg(long)]
    out: PathBuf,
    /// Seconds to record [default: until Ctrl-C].
    #[arg(long)]
    duration: Option<f64>,
    /// Vehicle file with [[thruster]] tables: the body input X,Y,Z,Mz of each state sample is
    /// rebuilt from SERVO_OUTPUT_RAW through its thrusters (for `pinc dataset import`), and the
    /// state estimate on its analytic vehicle is recorded on /estimate beside the raw state.
    #[arg(long)]
    vehicle: Option<PathBuf>,
    /// Rate (Hz) requested for SERVO_OUTPUT_RAW with --vehicle.
    #[arg(long, default_value_t = 50.0)]
    outputs_rate: f64,
}

/// Arguments of `pinc vehicle excite`.
#[derive(clap::Args)]
pub struct ExciteArgs {
    #[command(flatten)]
    link: LinkArgs,
    #[command(flatten)]
    drive: DriveArgs,
    /// Vehicle file with the thrusters' [[thruster]] tables (and their ArduSub `mix` factors
    /// for --command manual).
    #[arg(long)]
    vehicle: PathBuf,
    /// Excitation inputs: CSV with header X,Y,Z,Mz, one row per --dt (`pinc excitation`).
    #[arg(long)]
    inputs: PathBuf,
    /// Sample period of the inputs file (s).
    #[arg(long, default_value_t = pinc::DEFAULT_DT)]
    dt: f64,
    /// Output MCAP file (written as OUT.partial and renamed when complete).
    #[arg(long)]
    out: PathBuf,
    /// Keep the depth inside TOP,BOTTOM (m): where the vehicle leaves the band less its outer
    /// eighths, a depth feedback sets the heave force (surge, sway and yaw go on exciting)
    /// until it is back in the middle half; `/excite/heave` says which samples it set.
    #[arg(long, value_name = "TOP,BOTTOM", value_delimiter = ',')]
    depth_band: Option<Vec<f64>>,
    /// The band feedback's gain on the depth error (N/m).
    #[arg(long, default_value_t = 60.0)]
    band_kp: f64,
    /// The band feedback's gain on the heave rate (N per m/s).
    #[arg(long, default_value_t = 40.0)]
    band_kd: f64,
}

pub fn run_vehicle(action: VehicleAction) -> Result<(), String> {
    match action {
        VehicleAction::Status(a) => run_status(a),
        VehicleAction::Record(a) => run_record(a),
        VehicleAction::Excite(a) => run_excite(a),
        VehicleAction::SetupSigning(a) => run_setup_signing(a),
    }
}

/// `pinc vehicle setup-signing`: SETUP_SIGNING three times (it has no acknowledgement), then a
/// second link that signs with the new key must hear the autopilot's signed heartbeat.
fn run_setup_signing(a: SetupSigningArgs) -> Result<(), String> {
    let key = SigningKey::load(&a.key).map_err(|e| e.to_string())?;
    let (link, autopilot, _) = open(&a.link.connect, &a.link, |_| {})?;
    let message = MavMessage::SETUP_SIGNING(key.setup_message(autopilot.system_id, autopilot.component_id));
    for _ in 0..3 {
        link.send(&message).map_err(|e| e.to_string())?;
        std::thread::sleep(Duration::from_millis(100));
    }
    drop(link);
    std::thread::sleep(Duration::from_millis(500));
    let mut options = a.link.options.clone();
    options.signing_key = Some(a.key.clone());
    let checked = open(&a.link.connect, &options, |_| {});
    match checked {
        Ok((_, ap, _)) => {
            println!(
                "signing set up: system {} answers signed with the key of {}; connect with --signing-key {}",
                ap.system_id,
                a.key.display(),
                a.key.display()
            );
            Ok(())
        }
        Err(e) => Err(format!("SETUP_SIGNING was sent but the autopilot did not answer signed with the new key: {e}")),
    }
}

fn from_autopilot(r: &Received, ap: &Autopilot) -> bool {
    r.header.system_id as u8 == ap.system_id && r.header.component_id == ap.component_id
}

/// `MAV_TYPE_SUBMARINE` -> `SUBMARINE`.
fn enum_name(v: &impl std::fmt::Debug, prefix: &str) -> String {
    let s = format!("{v:?}");
    s.strip_prefix(prefix).unwrap_or(&s).to_string()
}

/// ArduPilot's `flight_sw_version`: major, minor, patch, release type in the four bytes.
fn firmware(v: &AUTOPILOT_VERSION_DATA) -> String {
    let f = v.flight_sw_version;
    let kind = match f & 0xff {
        0 => "dev",
        64 => "alpha",
        128 => "beta",
        192 => "rc",
        255 => "official",
        _ => "unknown type",
    };
    let hash: String = v.flight_custom_version.iter().take_while(|b| **b != 0).map(|b| *b as char).collect();
    let hash = if hash.is_empty() { String::new() } else { format!(", git {hash}") };
    format!("{}.{}.{} ({kind}{hash})", f >> 24, (f >> 16) & 0xff, (f >> 8) & 0xff)
}

/// Times of arrival of one message type (host clock), for its rate.
#[derive(Default)]
struct Arrivals {
    count: u64,
    first: Option<Instant>,
    last: Option<Instant>,
}

impl Arrivals {
    fn add(&mut self, at: Instant) {
        self.count += 1;
        self.first.get_or_insert(at);
        self.last = Some(at);
    }

    fn rate(&self) -> Option<f64> {
        let (first, last) = (self.first?, self.last?);
        let span = (last - first).as_secs_f64();
        (self.count >= 2 && span > 0.0).then(|| (self.count - 1) as f64 / span)
    }
}

fn run_status(a: StatusArgs) -> Result<(), String> {
    let window = positive("--window", a.window)?;
    let thrusters = a.vehicle.as_ref().map(Thrusters::load).transpose().map_err(|e| e.to_string())?;
    let (mut link, autopilot, mut assembler) = open(&a.link.connect, &a.link, |_| {})?;
    link.request_message(AUTOPILOT_VERSION_ID).map_err(|e| e.to_string())?;
    link.set_message_rate(EKF_STATUS_REPORT_ID, AUTOPILOT_ESTIMATE_RATE_HZ).map_err(|e| e.to_string())?;
    let params = read_autopilot_config(&mut link, &autopilot, |r| {
        assembler.update(r, |_| {});
    })
    .map_err(|e| e.to_string())?;
    let mut ekf: Option<EkfStatus> = None;
    let mut heartbeat = autopilot.heartbeat.clone();
    let mut version: Option<AUTOPILOT_VERSION_DATA> = None;
    let mut arrivals: BTreeMap<&'static str, Arrivals> = BTreeMap::new();
    let start = Instant::now();
    let mut asked_again = false;
    while start.elapsed() < window {
        if !asked_again && version.is_none() && start.elapsed() > window / 2 {
            // Requests travel over UDP: one more try.
            link.request_message(AUTOPILOT_VERSION_ID).map_err(|e| e.to_string())?;
            asked_again = true;
        }
        let Some(r) = link.recv_timeout(Duration::from_millis(50)).map_err(|e| e.to_string())? else { continue };
        if !from_autopilot(&r, &autopilot) {
            continue;
        }
        arrivals.entry(mavlink::Message::message_name(&r.message)).or_default().add(r.at);
        assembler.update(&r, |_| {});
        match &r.message {
            MavMessage::HEARTBEAT(h) if !is_ground_station(h) => heartbeat = h.clone(),
            MavMessage::AUTOPILOT_VERSION(v) => version = Some(v.clone()),
            MavMessage::EKF_STATUS_REPORT(e) => ekf = Some(EkfStatus::new(0.0, e)),
            _ => {}
        }
    }
    // Which ways of commanding reach the thrusters, from the outputs' functions.
    let functions = OutputFunctions::from_params(&params);
    let outputs: Vec<(String, u8)> = match &thrusters {
        Some(t) => t.list.iter().map(|t| (format!("thruster {}", t.name), t.channel)).collect(),
        None => (1..=6).map(|n| (format!("thruster {n}"), n)).collect(),
    };
    let ways = functions.ways(&outputs);
    let heading = HeadingReference::of(&params, ekf.is_some_and(|e| e.absolute_position()));
    let not_ready = ekf.map_or_else(|| vec!["no EKF_STATUS_REPORT answered".to_string()], |e| e.not_ready());
    let now = assembler.estimate_now(Instant::now());
    let rate_of = |name: &str| arrivals.get(name).and_then(Arrivals::rate);
    let pressure_rate = rate_of("SCALED_PRESSURE2").or_else(|| rate_of("SCALED_PRESSURE"));
    let part_source = |p: Part| -> (&'static str, Option<f64>) {
        match p {
            Part::Heading | Part::YawRate => ("ATTITUDE", rate_of("ATTITUDE")),
            Part::Position | Part::Velocity => ("LOCAL_POSITION_NED", rate_of("LOCAL_POSITION_NED")),
            Part::Depth if now.part(Part::Position).fresh => ("LOCAL_POSITION_NED", rate_of("LOCAL_POSITION_NED")),
            Part::Depth => (
                if arrivals.contains_key("SCALED_PRESSURE2") { "SCALED_PRESSURE2" } else { "SCALED_PRESSURE" },
                pressure_rate,
            ),
        }
    };
    // The autopilot's vertical velocity, which the estimator takes while its EKF vouches for it.
    let vertical_rate = rate_of("GLOBAL_POSITION_INT");
    let vertical_valid = assembler.reader().vertical_velocity_valid();
    let mode = SubMode::name_of(heartbeat.custom_mode);
    let armed = Autopilot::armed(&heartbeat);
    let vehicle_type = enum_name(&heartbeat.mavtype, "MAV_TYPE_");
    let autopilot_name = enum_name(&heartbeat.autopilot, "MAV_AUTOPILOT_");
    let firmware_text = version.as_ref().map(firmware);
    if a.json {
        let parts: serde_json::Map<String, Value> = now
            .parts
            .iter()
            .map(|p| {
                let (source, rate) = part_source(p.part);
                (p.part.name().to_string(), json!({"seen": p.fresh, "source": source, "rate_hz": rate, "age_s": p.age}))
            })
            .collect();
        let messages: serde_json::Map<String, Value> =
            arrivals.iter().map(|(k, v)| (k.to_string(), json!({"count": v.count, "rate_hz": v.rate()}))).collect();
        let out = json!({
            "connect": a.link.connect, "system_id": autopilot.system_id, "component_id": autopilot.component_id,
            "vehicle_type": vehicle_type, "autopilot": autopilot_name, "firmware": firmware_text,
            "flight_sw_version": version.as_ref().map(|v| v.flight_sw_version),
            "mode": mode, "custom_mode": heartbeat.custom_mode, "armed": armed,
            "parts": parts, "messages": messages, "capability": capability_key(now.capability),
            "capability_text": now.capability.to_string(), "window_s": a.window,
            "malformed_frames": link.malformed(),
            "outputs": functions.by_output.iter().map(|(n, f)| (n.to_string(), json!({"function": f, "name": function_name(*f)}))).collect::<serde_json::Map<_, _>>(),
            "command_ways": ways.iter().map(|(w, r)| (w.name().to_string(), json!({"allowed": r.is_ok(), "why_not": r.as_ref().err().map(ToString::to_string)}))).collect::<serde_json::Map<_, _>>(),
            "js_gain": params.get("JS_GAIN_DEFAULT"),
            "heading_reference": heading.key(), "heading_reference_text": heading.describe(),
            "compass_dec_rad": params.get("COMPASS_DEC"), "compass_autodec": params.get("COMPASS_AUTODEC"),
            "ekf_flags": ekf.map(|e| e.flags), "ekf_not_ready": not_ready,
            "ekf_position_measured": ekf.map(|e| e.position_measured()),
            "vertical_velocity": {"source": "GLOBAL_POSITION_INT", "rate_hz": vertical_rate, "ekf_vouches": vertical_valid},
        });
        println!("{}", serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?);
        return Ok(());
    }
    println!("autopilot   system {} component {} on {}", autopilot.system_id, autopilot.component_id, a.link.connect);
    println!("type        {vehicle_type}, autopilot {autopilot_name}");
    println!("firmware    {}", firmware_text.as_deref().unwrap_or("unknown (no AUTOPILOT_VERSION answered)"));
    println!("mode        {mode}");
    println!("armed       {}", if armed { "yes" } else { "no" });
    println!("state parts over {:.1} s:", a.window);
    for p in &now.parts {
        let (source, rate) = part_source(p.part);
        let what = match (p.fresh, rate, p.age) {
            (true, Some(r), _) => format!("seen     {r:5.1} Hz from {source}"),
            (true, None, _) => format!("seen     once from {source}"),
            (false, _, Some(age)) => format!("stale    last {source} {age:.1} s ago"),
            (false, _, None) => format!("missing  no {source}"),
        };
        println!("  {:<9} {what}", p.part.name());
    }
    let vertical = match (vertical_rate, vertical_valid) {
        (Some(r), true) => {
            format!("{r:.1} Hz from GLOBAL_POSITION_INT, the EKF vouches for it: the estimator takes it")
        }
        (Some(r), false) => {
            format!(
                "{r:.1} Hz from GLOBAL_POSITION_INT, the EKF does not vouch for it (yet): the estimator leaves it out"
            )
        }
        (None, _) => "no GLOBAL_POSITION_INT: the estimator's heave rests on the depth and the model".to_string(),
    };
    println!("vertical    {vertical}");
    println!("controller  {}", now.capability);
    let outputs_line: Vec<String> =
        functions.by_output.iter().map(|(n, f)| format!("{n} {}", function_name(*f))).collect();
    println!(
        "outputs     {}",
        if outputs_line.is_empty() {
            "unknown (SERVOn_FUNCTION not answered)".to_string()
        } else {
            outputs_line.join(", ")
        }
    );
    for (way, r) in &ways {
        match r {
            Ok(()) => println!("command     --command {}: reaches every thruster", way.name()),
            Err(e) => println!("command     --command {}: refused: {e}", way.name()),
        }
    }
    if let Some(g) = params.get("JS_GAIN_DEFAULT") {
        println!("pilot gain  {g} (JS_GAIN_DEFAULT: pinc's --command manual uses it)");
    }
    println!("{}", heading.describe());
    if not_ready.is_empty() {
        println!("estimate    the autopilot's attitude and heading are usable (EKF_STATUS_REPORT)");
    } else {
        println!("estimate    not ready: {}", not_ready.join("; "));
    }
    if link.malformed() > 0 {
        println!("malformed   {} frames could not be parsed", link.malformed());
    }
    Ok(())
}

fn capability_key(c: Capability) -> &'static str {
    match c {
        Capability::Full => "full",
        Capability::DepthHeading => "depth_heading",
        Capability::None => "none",
    }
}

/// The session metadata every recording starts with.
fn session_metadata(a: &LinkArgs, autopilot: &Autopilot) -> BTreeMap<String, String> {
    let mut session = BTreeMap::new();
    session.insert("pinc_version".to_string(), env!("CARGO_PKG_VERSION").to_string());
    session.insert("connect".to_string(), a.connect.clone());
    session.insert("autopilot_system_id".to_string(), autopilot.system_id.to_string());
    session.insert("gcs_system_id".to_string(), a.gcs_sysid.to_string());
    session.insert("requested_rate_hz".to_string(), a.rate.to_string());
    session.insert("max_age_s".to_string(), a.max_age.to_string());
    session.insert("surface_pressure_hpa".to_string(), a.surface_pressure.to_string());
    session.insert("water_density".to_string(), a.water_density.to_string());
    session.insert("time_base".to_string(), "autopilot time_boot_ms".to_string());
    session
}

fn ctrl_c_flag() -> Result<Arc<AtomicBool>, String> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed)).map_err(|e| format!("cannot catch Ctrl-C: {e}"))?;
    Ok(stop)
}

/// The state estimator of a recording: the analytic vehicle of the vehicle file, fed what
/// every message measured; its estimate is written beside each raw state sample.
fn recording_estimator(vehicle: &std::path::Path, dt: f64) -> Result<Estimator<Rk4Vehicle>, String> {
    let params = VehicleParams::load(vehicle).map_err(|e| e.to_string())?;
    Ok(Estimator::new(Rk4Vehicle { params, ..Rk4Vehicle::with_dt(dt) }, NoiseSettings::default()))
}

/// Writes a session into its recording: every message, the state samples with their body
/// input (from the thruster outputs when a vehicle file is given), the `/log` lines.
struct Writer {
    rec: Recorder,
    estimation: Option<Estimator<Rk4Vehicle>>,
    notes: Session,
    autopilot: Autopilot,
    inputs: Option<InputsFromOutputs>,
    /// Messages before the autopilot's clock is known, written at their times once it is.
    pending: Vec<Received>,
    clock: Option<(f64, Instant)>,
}

impl Writer {
    fn new(rec: Recorder, autopilot: Autopilot, inputs: Option<InputsFromOutputs>, pending: Vec<Received>) -> Self {
        let notes = Session { last_heartbeat: None, capability: None, log: Vec::new() };
        Self { rec, estimation: None, notes, autopilot, inputs, pending, clock: None }
    }

    /// One message received, at autopilot time `t` (meaningless until a stamped message came).
    fn message(&mut self, r: &Received, t: f64) -> Result<(), String> {
        if self.clock.is_none() {
            if message_time(&r.message).is_none() || !from_autopilot(r, &self.autopilot) {
                self.pending.push(r.clone());
                return Ok(());
            }
            self.clock = Some((t, r.at));
        }
        let (t0, at0) = self.clock.expect("set above");
        for p in std::mem::take(&mut self.pending) {
            let back = at0.saturating_duration_since(p.at).as_secs_f64();
            self.one(&p, (t0 - back).max(0.0))?;
        }
        self.one(r, t)
    }

    fn one(&mut self, r: &Received, t: f64) -> Result<(), String> {
        // A write error ends the session: the unfinished file is removed (`Recorder`'s drop).
        write_one(&mut self.rec, &mut self.notes, &self.autopilot, t, r)?;
        self.flush_log()
    }

    /// What the autopilot's messages measured and the inputs they say were applied (read
    /// once, by the state's assembler), up to autopilot time `now` (s).
    fn observed(&mut self, now: f64, observations: impl IntoIterator<Item = Observation>) -> Result<(), String> {
        if self.clock.is_none() {
            return Ok(()); // nothing is on the autopilot's time line yet
        }
        let mut outputs = false;
        for o in observations {
            match o {
                Observation::Measured(m) => {
                    if let Some(e) = &mut self.estimation {
                        e.measure(m);
                    }
                }
                Observation::Applied(t, u) => {
                    outputs = true;
                    if let Some(e) = &mut self.estimation {
                        e.applied(t, u);
                    }
                    if let Some(p) = &mut self.inputs {
                        p.applied(t, u);
                    }
                }
                Observation::Unfused(_) => {}
            }
        }
        // New outputs may complete the input of states waiting for it (a state's own arrival
        // releases those whose outputs stopped).
        if let (true, Some(p)) = (outputs, &mut self.inputs) {
            for (s, u) in p.ready(now) {
                self.rec.state(&s, u.as_ref()).map_err(|e| e.to_string())?;
            }
        }
        Ok(())
    }

    /// A fresh state sample; the state estimate at it, once the estimator runs.
    fn state(&mut self, s: &pinc::link::RawState) -> Result<Option<Estimate>, String> {
        self.notes.note_capability(s.t, s.capability);
        let mut out = None;
        if let Some(e) = &mut self.estimation {
            match e.advance(s.t) {
                Ok(Some(estimate)) => {
                    self.rec.estimate(&estimate).map_err(|e| e.to_string())?;
                    out = Some(estimate);
                }
                Ok(None) => {}
                Err(err) => self.notes.log.push((s.t, Level::Warning, format!("state estimator: {err}"))),
            }
        }
        match &mut self.inputs {
            None => self.rec.state(s, None).map_err(|e| e.to_string())?,
            Some(p) => {
                p.state(s.clone());
                for (s, u) in p.ready(s.t) {
                    self.rec.state(&s, u.as_ref()).map_err(|e| e.to_string())?;
                }
            }
        }
        self.flush_log()?;
        Ok(out)
    }

    fn flush_log(&mut self) -> Result<(), String> {
        for (t, level, line) in self.notes.log.drain(..) {
            self.rec.log(t, level, &line).map_err(|e| e.to_string())?;
        }
        Ok(())
    }

    fn log(&mut self, t: f64, level: Level, line: &str) -> Result<(), String> {
        self.rec.log(t, level, line).map_err(|e| e.to_string())
    }

    /// Writes what is pending and the last line, and finishes the file.
    fn finish(mut self, t: f64, level: Level, line: &str) -> Result<pinc::link::RecordStats, String> {
        if let Some(p) = &mut self.inputs {
            for (s, u) in p.flush() {
                self.rec.state(&s, u.as_ref()).map_err(|e| e.to_string())?;
            }
        }
        self.flush_log()?;
        self.rec.log(t, level, line).map_err(|e| e.to_string())?;
        self.rec.finish().map_err(|e| e.to_string())
    }
}

fn run_record(a: RecordArgs) -> Result<(), String> {
    let duration = a.duration.map(|d| positive("--duration", d)).transpose()?;
    let stop = ctrl_c_flag()?;
    let thrusters = a.vehicle.as_ref().map(Thrusters::load).transpose().map_err(|e| e.to_string())?;
    let inputs = thrusters.is_some().then(|| InputsFromOutputs::new(1.0 / a.link.rate, a.link.max_age));
    let mut pending: Vec<Received> = Vec::new();
    let (mut link, autopilot, mut assembler) = open(&a.link.connect, &a.link, |r| pending.push(r.clone()))?;
    if let Some(t) = thrusters {
        assembler.set_thrusters(t);
    }
    if inputs.is_some() {
        link.set_message_rate(SERVO_OUTPUT_RAW_ID, a.outputs_rate).map_err(|e| e.to_string())?;
    }
    let mut session = session_metadata(&a.link, &autopilot);
    if let Some(v) = &a.vehicle {
        session.insert("vehicle_file".to_string(), v.display().to_string());
    }
    let rec = Recorder::create(&a.out, session).map_err(|e| e.to_string())?;
    let mut w = Writer::new(rec, autopilot.clone(), inputs, pending);
    if let Some(v) = &a.vehicle {
        w.estimation = Some(recording_estimator(v, 1.0 / a.link.rate)?);
    }
    let start = Instant::now();
    let mut observed = Vec::new();
    let result = loop {
        if stop.load(Ordering::Relaxed) {
            break Ok("Ctrl-C");
        }
        if duration.is_some_and(|d| start.elapsed() >= d) {
            break Ok("duration reached");
        }
        let r = match link.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(r)) => r,
            Ok(None) => continue,
            Err(e) => break Err(e.to_string()),
        };
        let state = if from_autopilot(&r, &autopilot) { assembler.update(&r, |o| observed.push(o)) } else { None };
        let t = assembler.autopilot_time(r.at).unwrap_or(0.0);
        w.message(&r, t)?;
        w.observed(t, observed.drain(..))?;
        if let Some(s) = state {
            w.state(&s)?;
        }
    };
    let end_t = assembler.autopilot_time(Instant::now()).unwrap_or(0.0);
    let reason = match &result {
        Ok(reason) => format!("recording ended: {reason}"),
        Err(e) => format!("recording ended on an error: {e}"),
    };
    let stats = w.finish(end_t, if result.is_ok() { Level::Info } else { Level::Error }, &reason)?;
    let types: Vec<String> = stats.mavlink.iter().map(|(k, v)| format!("{k} {v}")).collect();
    println!(
        "{} MAVLink messages ({}), {} state samples over {:.1} s -> {} ({reason})",
        stats.mavlink.values().sum::<u64>(),
        types.join(", "),
        stats.states,
        start.elapsed().as_secs_f64(),
        a.out.display()
    );
    result.map(|_| ())
}

/// Id of `SERVO_OUTPUT_RAW`.
const SERVO_OUTPUT_RAW_ID: u32 = 36;

fn run_excite(a: ExciteArgs) -> Result<(), String> {
    let dt = positive("--dt", a.dt)?.as_secs_f64();
    let file = std::fs::File::open(&a.inputs).map_err(|e| format!("{}: {e}", a.inputs.display()))?;
    let inputs = crate::trajectory_csv::read_inputs(file).map_err(|e| format!("{}: {e}", a.inputs.display()))?;
    if inputs.is_empty() {
        return Err(format!("{}: no input rows", a.inputs.display()));
    }
    let commander = a.drive.commander(&a.vehicle)?;
    // The band's force limit: the largest heave the excitation itself asks for.
    let heave_limit = inputs.iter().map(|u| u[2].abs()).fold(0.0, f64::max).max(1.0);
    let mut band = match a.depth_band.as_deref() {
        Some(&[top, bottom]) => Some(DepthBand::new(top, bottom, a.band_kp, a.band_kd, heave_limit)?),
        Some(other) => return Err(format!("--depth-band: two depths TOP,BOTTOM (m), got {other:?}")),
        None => None,
    };
    let settings = a.drive.settings()?;
    let limits = settings.limits.clone();
    let wait_position = non_negative("--wait-position", a.drive.wait_position)?;
    let stop = ctrl_c_flag()?;
    let recorded = Some(InputsFromOutputs::new(1.0 / a.link.rate, a.link.max_age));
    let mut pending: Vec<Received> = Vec::new();
    let (link, autopilot, estimator) = open(&a.link.connect, &a.link, |r| pending.push(r.clone()))?;
    link.set_message_rate(SERVO_OUTPUT_RAW_ID, a.drive.outputs_rate).map_err(|e| e.to_string())?;
    let mut session = session_metadata(&a.link, &autopilot);
    session.insert("vehicle_file".to_string(), a.vehicle.display().to_string());
    session.insert("inputs_file".to_string(), a.inputs.display().to_string());
    session.insert("command".to_string(), a.drive.command_way.clone());
    session.insert("limits".to_string(), limits.describe());
    let rec = Recorder::create(&a.out, session).map_err(|e| e.to_string())?;
    let mut writer = Writer::new(rec, autopilot.clone(), recorded, pending);
    writer.estimation = Some(recording_estimator(&a.vehicle, dt)?);
    let w = RefCell::new(writer);
    let write_error: RefCell<Option<String>> = RefCell::new(None);
    let keep = |result: Result<(), String>| {
        if let Err(e) = result {
            write_error.borrow_mut().get_or_insert(e);
        }
    };
    let seen = |r: &Received, t: f64| keep(w.borrow_mut().message(r, t));
    let started = Drive::start(link, autopilot, estimator, commander, settings, stop, seen);
    let mut drive = match started {
        Ok(d) => d,
        Err(mut stopped) => {
            for n in std::mem::take(&mut stopped.notes).into_iter().filter(|n| !n.from_autopilot) {
                keep(w.borrow_mut().log(n.t, n.level, &n.text));
            }
            return end_excite(w.into_inner(), &stopped, write_error.into_inner(), 0, inputs.len());
        }
    };
    let line =
        format!("excitation: {} inputs at {dt} s from {} by {}", inputs.len(), a.inputs.display(), a.drive.command_way);
    keep(w.borrow_mut().log(drive.now_t(), Level::Info, &line));
    let mut played = 0usize;
    let mut t0: Option<f64> = None;
    let waited = Instant::now();
    let mut cycle = || -> Result<(), Trigger> {
        loop {
            let fresh: Fresh = drive.next_state(seen)?;
            let observed = w.borrow_mut().observed(fresh.state.t, drive.drain_observations());
            if let Err(e) = observed {
                return Err(Trigger::Error(e));
            }
            // The autopilot's own texts are in the recording already (the writer logs them).
            for n in drive.take_notes().into_iter().filter(|n| !n.from_autopilot) {
                keep(w.borrow_mut().log(n.t, n.level, &n.text));
            }
            if let Some(e) = write_error.borrow().as_ref() {
                return Err(Trigger::Error(e.clone()));
            }
            let estimate = match w.borrow_mut().state(&fresh.state) {
                Ok(e) => e,
                Err(e) => return Err(Trigger::Error(e)),
            };
            if t0.is_none() {
                if fresh.state.capability != Capability::Full && waited.elapsed() < wait_position {
                    drive.send_neutral(&fresh)?;
                    continue;
                }
                if fresh.state.capability != Capability::Full {
                    let line = format!(
                        "no full state after {:.0} s: playing anyway ({})",
                        a.drive.wait_position, fresh.state.capability
                    );
                    keep(w.borrow_mut().log(fresh.state.t, Level::Warning, &line));
                }
                t0 = Some(fresh.state.t);
            }
            let k = ((fresh.state.t - t0.expect("set")) / dt).round() as usize;
            let Some(u) = inputs.get(k) else { return Ok(()) };
            let mut u = *u;
            if let Some(b) = &mut band {
                // The estimate's depth and heave rate; the raw depth at rest before it starts.
                let (z, w_rate) = estimate.map_or((fresh.state.sim[2], 0.0), |e| (e.sim[2], e.sim[6]));
                let h = b.heave(z, w_rate, u[2]);
                if h.switched {
                    let line = if h.feedback {
                        format!("depth {z:.2} m: the band's feedback takes the heave")
                    } else {
                        format!("depth {z:.2} m: back in the band's middle, the excitation takes the heave again")
                    };
                    keep(w.borrow_mut().log(fresh.state.t, Level::Info, &line));
                }
                keep(w.borrow_mut().rec.excite_heave(fresh.state.t, u[2], h.z, h.feedback).map_err(|e| e.to_string()));
                u[2] = h.z;
            }
            drive.send(&fresh, &u)?;
            played = k + 1;
        }
    };
    let outcome = cycle();
    let stopped = match outcome {
        Ok(()) => drive.finish(),
        Err(trigger) => drive.abort(trigger),
    };
    // The last outputs (the neutral ones among them) into the recording.
    drive.drain(Duration::from_millis(300), seen);
    let now = drive.now_t();
    keep(w.borrow_mut().observed(now, drive.drain_observations()));
    if drive.out_of_order() > 0 {
        let line = format!("{} messages arrived out of order and were dropped", drive.out_of_order());
        keep(w.borrow_mut().log(stopped.t, Level::Warning, &line));
    }
    drop(drive);
    end_excite(w.into_inner(), &stopped, write_error.into_inner(), played, inputs.len())
}

/// Writes the stop into the recording and on stderr, finishes the file; an error (exit 1)
/// for any safety stop.
fn end_excite(
    w: Writer,
    stopped: &Stopped,
    write_error: Option<String>,
    played: usize,
    total: usize,
) -> Result<(), String> {
    let (level, line) = match &stopped.trigger {
        None => (Level::Info, format!("excitation finished: {played} of {total} inputs played")),
        Some(t) => (
            Level::Error,
            format!(
                "{t}; neutral command sent{}{}; {played} of {total} inputs played",
                stopped.neutral_t.map_or(" (failed)".to_string(), |n| format!(" at {n:.3} s")),
                if stopped.disarm_sent { ", disarm sent" } else { "" }
            ),
        ),
    };
    let stats = w.finish(stopped.t, level, &line);
    if let Some(t) = &stopped.trigger {
        eprintln!("{line}");
        let _ = t;
    }
    let stats = stats?;
    if let Some(e) = write_error {
        return Err(format!("recording: {e}"));
    }
    match &stopped.trigger {
        None => {
            println!("{line}; {} state samples recorded", stats.states);
            Ok(())
        }
        Some(_) => Err("stopped by a safety trigger (see above)".into()),
    }
}

/// What the recording logs about the session as it goes.
struct Session {
    last_heartbeat: Option<HEARTBEAT_DATA>,
    capability: Option<Capability>,
    log: Vec<(f64, Level, String)>,
}

impl Session {
    fn note_heartbeat(&mut self, t: f64, h: &HEARTBEAT_DATA) {
        let (mode, armed) = (SubMode::name_of(h.custom_mode), Autopilot::armed(h));
        let line = match &self.last_heartbeat {
            None => Some(format!("autopilot in {mode}, {}", if armed { "armed" } else { "disarmed" })),
            Some(old) => {
                let mut changes = Vec::new();
                if old.custom_mode != h.custom_mode {
                    changes.push(format!("mode {} -> {mode}", SubMode::name_of(old.custom_mode)));
                }
                if Autopilot::armed(old) != armed {
                    changes.push(if armed { "armed".to_string() } else { "disarmed".to_string() });
                }
                (!changes.is_empty()).then(|| changes.join(", "))
            }
        };
        if let Some(line) = line {
            self.log.push((t, Level::Info, line));
        }
        self.last_heartbeat = Some(h.clone());
    }

    fn note_capability(&mut self, t: f64, c: Capability) {
        if self.capability != Some(c) {
            let level = if c == Capability::Full { Level::Info } else { Level::Warning };
            self.log.push((t, level, format!("state: {c}")));
            self.capability = Some(c);
        }
    }
}

fn write_one(
    rec: &mut Recorder,
    session: &mut Session,
    autopilot: &Autopilot,
    t: f64,
    r: &Received,
) -> Result<(), String> {
    rec.mavlink(t, r).map_err(|e| e.to_string())?;
    if from_autopilot(r, autopilot) {
        match &r.message {
            MavMessage::SERVO_OUTPUT_RAW(o) => rec.outputs(t, o).map_err(|e| e.to_string())?,
            MavMessage::HEARTBEAT(h) => session.note_heartbeat(t, h),
            MavMessage::STATUSTEXT(s) => {
                let (level, name) = severity_level(s.severity);
                session.log.push((t, level, format!("autopilot {name}: {}", statustext(s))));
            }
            _ => {}
        }
    }
    Ok(())
}
