//! `pinc vehicle status` and `pinc vehicle record`: pinc as a MAVLink participant next to an
//! ArduSub autopilot (docs/VEHICLE.md).

use mavlink::dialects::ardupilotmega::{AUTOPILOT_VERSION_DATA, HEARTBEAT_DATA, MavMessage};
use pinc::closed_loop::Level;
use pinc::link::link::{AUTOPILOT_VERSION_ID, is_ground_station};
use pinc::link::state::message_time;
use pinc::link::{
    Autopilot, Capability, LinkAddress, LinkConfig, Part, Received, Recorder, StateConfig, StateEstimator, SubMode,
    VehicleLink,
};
use serde_json::{Value, json};
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
}

/// What both actions share.
#[derive(clap::Args)]
pub struct LinkArgs {
    /// Connection: udpin:HOST:PORT (or udp:), udpout:HOST:PORT, tcp:HOST:PORT (or tcpout:),
    /// tcpin:HOST:PORT, serial:DEVICE:BAUD or DEVICE:BAUD.
    #[arg(long)]
    pub connect: String,
    /// Seconds to wait for the autopilot's heartbeat.
    #[arg(long, default_value_t = 10.0)]
    pub timeout: f64,
    /// Rate (Hz) requested for the state messages (default: pinc's control rate, 1 / 0.08 s).
    #[arg(long, default_value_t = 1.0 / pinc::DEFAULT_DT)]
    pub rate: f64,
    /// System id pinc sends from: the autopilot's SYSID_MYGCS.
    #[arg(long, default_value_t = 255)]
    pub gcs_sysid: u8,
    /// A state part older than this (s) is reported missing.
    #[arg(long, default_value_t = 0.5)]
    pub max_age: f64,
    /// Surface pressure (hPa) for depth from pressure.
    #[arg(long, default_value_t = 1013.25)]
    pub surface_pressure: f64,
    /// Water density (kg/m^3) for depth from pressure: 1000 x ArduSub's BARO_SPEC_GRAV.
    #[arg(long, default_value_t = 1000.0)]
    pub water_density: f64,
}

/// Arguments of `pinc vehicle status`.
#[derive(clap::Args)]
pub struct StatusArgs {
    #[command(flatten)]
    link: LinkArgs,
    /// Seconds over which the message rates are measured.
    #[arg(long, default_value_t = 3.0)]
    window: f64,
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
}

pub fn run_vehicle(action: VehicleAction) -> Result<(), String> {
    match action {
        VehicleAction::Status(a) => run_status(a),
        VehicleAction::Record(a) => run_record(a),
    }
}

fn positive(name: &str, v: f64) -> Result<Duration, String> {
    if v.is_finite() && v > 0.0 {
        Ok(Duration::from_secs_f64(v))
    } else {
        Err(format!("{name} must be a positive number of seconds, got {v}"))
    }
}

/// Opens the link and waits for the autopilot; `seen` gets every message meanwhile.
fn open(a: &LinkArgs, seen: impl FnMut(&Received)) -> Result<(VehicleLink, Autopilot, StateEstimator), String> {
    let address: LinkAddress = a.connect.parse().map_err(|e| format!("--connect: {e}"))?;
    let timeout = positive("--timeout", a.timeout)?;
    if !(a.rate.is_finite() && a.rate > 0.0) {
        return Err(format!("--rate must be a positive number of Hz, got {}", a.rate));
    }
    positive("--max-age", a.max_age)?;
    let config = LinkConfig { gcs_system_id: a.gcs_sysid, ..LinkConfig::default() };
    let mut link = VehicleLink::connect(&address, config).map_err(|e| e.to_string())?;
    let autopilot = link.wait_for_autopilot(timeout, seen).map_err(|e| e.to_string())?;
    link.request_state_streams(a.rate).map_err(|e| e.to_string())?;
    let estimator = StateEstimator::new(StateConfig {
        max_age: a.max_age,
        surface_pressure_hpa: a.surface_pressure,
        water_density: a.water_density,
    });
    Ok((link, autopilot, estimator))
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
    let (mut link, autopilot, mut estimator) = open(&a.link, |_| {})?;
    link.request_message(AUTOPILOT_VERSION_ID).map_err(|e| e.to_string())?;
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
        estimator.update(&r);
        match &r.message {
            MavMessage::HEARTBEAT(h) if !is_ground_station(h) => heartbeat = h.clone(),
            MavMessage::AUTOPILOT_VERSION(v) => version = Some(v.clone()),
            _ => {}
        }
    }
    let now = estimator.estimate_now(Instant::now());
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
    println!("controller  {}", now.capability);
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

fn run_record(a: RecordArgs) -> Result<(), String> {
    let duration = a.duration.map(|d| positive("--duration", d)).transpose()?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed))
            .map_err(|e| format!("cannot catch Ctrl-C: {e}"))?;
    }
    // Messages before the autopilot's clock is known wait here, to be written at their times.
    let mut pending: Vec<Received> = Vec::new();
    let (mut link, autopilot, mut estimator) = open(&a.link, |r| pending.push(r.clone()))?;
    let mut session = BTreeMap::new();
    session.insert("pinc_version".to_string(), env!("CARGO_PKG_VERSION").to_string());
    session.insert("connect".to_string(), a.link.connect.clone());
    session.insert("autopilot_system_id".to_string(), autopilot.system_id.to_string());
    session.insert("gcs_system_id".to_string(), a.link.gcs_sysid.to_string());
    session.insert("requested_rate_hz".to_string(), a.link.rate.to_string());
    session.insert("max_age_s".to_string(), a.link.max_age.to_string());
    session.insert("surface_pressure_hpa".to_string(), a.link.surface_pressure.to_string());
    session.insert("water_density".to_string(), a.link.water_density.to_string());
    session.insert("time_base".to_string(), "autopilot time_boot_ms".to_string());
    let mut rec = Recorder::create(&a.out, session).map_err(|e| e.to_string())?;
    let mut session = Session { last_heartbeat: None, capability: None, log: Vec::new() };
    let start = Instant::now();
    let mut clock_known = false;
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
        let state = if from_autopilot(&r, &autopilot) { estimator.update(&r) } else { None };
        if !clock_known && message_time(&r.message).is_none() {
            pending.push(r);
            continue;
        }
        // The first stamped message fixes the clock; what waited is written at its own time.
        for p in std::mem::take(&mut pending).into_iter().chain(std::iter::once(r)) {
            let t = estimator.autopilot_time(p.at).unwrap_or(0.0);
            // A write error ends here: the unfinished file is removed (`Recorder`'s drop).
            write_one(&mut rec, &mut session, &autopilot, t, &p)?;
        }
        clock_known = true;
        if let Some(s) = state {
            session.note_capability(s.t, s.capability);
            rec.state(&s, None).map_err(|e| e.to_string())?;
        }
        for (t, level, line) in session.log.drain(..) {
            rec.log(t, level, &line).map_err(|e| e.to_string())?;
        }
    };
    let end_t = estimator.autopilot_time(Instant::now()).unwrap_or(0.0);
    let reason = match &result {
        Ok(reason) => format!("recording ended: {reason}"),
        Err(e) => format!("recording ended on an error: {e}"),
    };
    rec.log(end_t, if result.is_ok() { Level::Info } else { Level::Error }, &reason).map_err(|e| e.to_string())?;
    let stats = rec.finish().map_err(|e| e.to_string())?;
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
                let text = s.text.to_str().unwrap_or("(not UTF-8)");
                session.log.push((t, Level::Info, format!("autopilot: {text}")));
            }
            _ => {}
        }
    }
    Ok(())
}
