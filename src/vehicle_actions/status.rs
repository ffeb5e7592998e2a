//! `pinc vehicle status`: what the autopilot is and sends.

use super::StatusArgs;
use crate::link::cli::{open, positive};
use crate::link::drive::{AUTOPILOT_ESTIMATE_RATE_HZ, read_autopilot_config};
use crate::link::link::{AUTOPILOT_VERSION_ID, EKF_STATUS_REPORT_ID, is_ground_station};
use crate::link::outputs::{OutputFunctions, function_name};
use crate::link::{Autopilot, Capability, Part, SubMode};
use crate::link::{EkfStatus, HeadingReference};
use crate::vehicle::Thrusters;
use mavlink::dialects::ardupilotmega::{AUTOPILOT_VERSION_DATA, MavMessage};
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
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

/// What the autopilot sent over the window.
struct Heard {
    ekf: Option<EkfStatus>,
    heartbeat: mavlink::dialects::ardupilotmega::HEARTBEAT_DATA,
    version: Option<AUTOPILOT_VERSION_DATA>,
    arrivals: BTreeMap<&'static str, Arrivals>,
}

/// Listens for `window`, asking for AUTOPILOT_VERSION (twice: requests travel over UDP);
/// every message of the autopilot's goes through the state's assembler.
fn listen(
    link: &mut crate::link::VehicleLink,
    autopilot: &Autopilot,
    assembler: &mut crate::link::StateAssembler,
    window: Duration,
) -> Result<Heard, String> {
    let mut heard =
        Heard { ekf: None, heartbeat: autopilot.heartbeat.clone(), version: None, arrivals: BTreeMap::new() };
    let start = Instant::now();
    let mut asked_again = false;
    while start.elapsed() < window {
        if !asked_again && heard.version.is_none() && start.elapsed() > window / 2 {
            link.request_message(AUTOPILOT_VERSION_ID).map_err(|e| e.to_string())?;
            asked_again = true;
        }
        let Some(r) = link.recv_timeout(Duration::from_millis(50)).map_err(|e| e.to_string())? else { continue };
        if !autopilot.sent(&r) {
            continue;
        }
        heard.arrivals.entry(mavlink::Message::message_name(&r.message)).or_default().add(r.at);
        assembler.update(&r, |_| {});
        match &r.message {
            MavMessage::HEARTBEAT(h) if !is_ground_station(h) => heard.heartbeat = h.clone(),
            MavMessage::AUTOPILOT_VERSION(v) => heard.version = Some(v.clone()),
            MavMessage::EKF_STATUS_REPORT(e) => heard.ekf = Some(EkfStatus::new(0.0, e)),
            _ => {}
        }
    }
    Ok(heard)
}

/// What `status` reports, worked out from what was heard and the parameters.
struct Status {
    autopilot: Autopilot,
    heard: Heard,
    params: crate::link::Params,
    malformed: u64,
    functions: OutputFunctions,
    ways: Vec<(crate::link::CommandWay, Result<(), crate::link::WayRefused>)>,
    heading: HeadingReference,
    not_ready: Vec<String>,
    now: crate::link::RawState,
    vertical_rate: Option<f64>,
    vertical_valid: bool,
}

pub(super) fn run_status(a: StatusArgs) -> Result<(), String> {
    let window = positive("--window", a.window)?;
    let thrusters = a.vehicle.as_ref().map(Thrusters::load).transpose().map_err(|e| e.to_string())?;
    let (mut link, autopilot, mut assembler) = open(&a.link.connect, &a.link, |_| {})?;
    link.request_message(AUTOPILOT_VERSION_ID).map_err(|e| e.to_string())?;
    link.set_message_rate(EKF_STATUS_REPORT_ID, AUTOPILOT_ESTIMATE_RATE_HZ).map_err(|e| e.to_string())?;
    let params = read_autopilot_config(&mut link, &autopilot, |r| {
        assembler.update(r, |_| {});
    })
    .map_err(|e| e.to_string())?;
    let heard = listen(&mut link, &autopilot, &mut assembler, window)?;
    // Which ways of commanding reach the thrusters, from the outputs' functions.
    let functions = OutputFunctions::from_params(&params);
    let outputs: Vec<(String, u8)> = match &thrusters {
        Some(t) => t.list.iter().map(|t| (format!("thruster {}", t.name), t.channel)).collect(),
        None => (1..=6).map(|n| (format!("thruster {n}"), n)).collect(),
    };
    let status = Status {
        malformed: link.malformed(),
        ways: functions.ways(&outputs),
        functions,
        heading: HeadingReference::of(&params, heard.ekf.is_some_and(|e| e.absolute_position())),
        not_ready: heard.ekf.map_or_else(|| vec!["no EKF_STATUS_REPORT answered".to_string()], |e| e.not_ready()),
        now: assembler.estimate_now(Instant::now()),
        // The autopilot's vertical velocity, which the estimator takes while its EKF vouches for it.
        vertical_rate: heard.arrivals.get("GLOBAL_POSITION_INT").and_then(Arrivals::rate),
        vertical_valid: assembler.reader().vertical_velocity_valid(),
        autopilot,
        heard,
        params,
    };
    if a.json {
        print_json(&a, &status)
    } else {
        print_text(&a, &status);
        Ok(())
    }
}

/// The message and rate each part of the state comes from.
fn part_source(heard: &Heard, now: &crate::link::RawState, p: Part) -> (&'static str, Option<f64>) {
    let rate_of = |name: &str| heard.arrivals.get(name).and_then(Arrivals::rate);
    match p {
        Part::Heading | Part::YawRate => ("ATTITUDE", rate_of("ATTITUDE")),
        Part::Position | Part::Velocity => ("LOCAL_POSITION_NED", rate_of("LOCAL_POSITION_NED")),
        Part::Depth if now.part(Part::Position).fresh => ("LOCAL_POSITION_NED", rate_of("LOCAL_POSITION_NED")),
        Part::Depth => (
            if heard.arrivals.contains_key("SCALED_PRESSURE2") { "SCALED_PRESSURE2" } else { "SCALED_PRESSURE" },
            rate_of("SCALED_PRESSURE2").or_else(|| rate_of("SCALED_PRESSURE")),
        ),
    }
}

fn print_json(a: &StatusArgs, st: &Status) -> Result<(), String> {
    let parts: serde_json::Map<String, Value> = st
        .now
        .parts
        .iter()
        .map(|p| {
            let (source, rate) = part_source(&st.heard, &st.now, p.part);
            (p.part.name().to_string(), json!({"seen": p.fresh, "source": source, "rate_hz": rate, "age_s": p.age}))
        })
        .collect();
    let messages: serde_json::Map<String, Value> = st
        .heard
        .arrivals
        .iter()
        .map(|(k, v)| (k.to_string(), json!({"count": v.count, "rate_hz": v.rate()})))
        .collect();
    let h = &st.heard.heartbeat;
    let out = json!({
        "connect": a.link.connect, "system_id": st.autopilot.system_id, "component_id": st.autopilot.component_id,
        "vehicle_type": enum_name(&h.mavtype, "MAV_TYPE_"), "autopilot": enum_name(&h.autopilot, "MAV_AUTOPILOT_"),
        "firmware": st.heard.version.as_ref().map(firmware),
        "flight_sw_version": st.heard.version.as_ref().map(|v| v.flight_sw_version),
        "mode": SubMode::name_of(h.custom_mode), "custom_mode": h.custom_mode, "armed": Autopilot::armed(h),
        "parts": parts, "messages": messages, "capability": capability_key(st.now.capability),
        "capability_text": st.now.capability.to_string(), "window_s": a.window,
        "malformed_frames": st.malformed,
        "outputs": st.functions.by_output.iter().map(|(n, f)| (n.to_string(), json!({"function": f, "name": function_name(*f)}))).collect::<serde_json::Map<_, _>>(),
        "command_ways": st.ways.iter().map(|(w, r)| (w.name().to_string(), json!({"allowed": r.is_ok(), "why_not": r.as_ref().err().map(ToString::to_string)}))).collect::<serde_json::Map<_, _>>(),
        "js_gain": st.params.get("JS_GAIN_DEFAULT"),
        "heading_reference": st.heading.key(), "heading_reference_text": st.heading.describe(),
        "compass_dec_rad": st.params.get("COMPASS_DEC"), "compass_autodec": st.params.get("COMPASS_AUTODEC"),
        "ekf_flags": st.heard.ekf.map(|e| e.flags), "ekf_not_ready": st.not_ready,
        "ekf_position_measured": st.heard.ekf.map(|e| e.position_measured()),
        "vertical_velocity": {"source": "GLOBAL_POSITION_INT", "rate_hz": st.vertical_rate, "ekf_vouches": st.vertical_valid},
    });
    println!("{}", serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?);
    Ok(())
}

fn print_text(a: &StatusArgs, st: &Status) {
    let h = &st.heard.heartbeat;
    let firmware_text = st.heard.version.as_ref().map(firmware);
    println!(
        "autopilot   system {} component {} on {}",
        st.autopilot.system_id, st.autopilot.component_id, a.link.connect
    );
    println!(
        "type        {}, autopilot {}",
        enum_name(&h.mavtype, "MAV_TYPE_"),
        enum_name(&h.autopilot, "MAV_AUTOPILOT_")
    );
    println!("firmware    {}", firmware_text.as_deref().unwrap_or("unknown (no AUTOPILOT_VERSION answered)"));
    println!("mode        {}", SubMode::name_of(h.custom_mode));
    println!("armed       {}", if Autopilot::armed(h) { "yes" } else { "no" });
    println!("state parts over {:.1} s:", a.window);
    for p in &st.now.parts {
        let (source, rate) = part_source(&st.heard, &st.now, p.part);
        let what = match (p.fresh, rate, p.age) {
            (true, Some(r), _) => format!("seen     {r:5.1} Hz from {source}"),
            (true, None, _) => format!("seen     once from {source}"),
            (false, _, Some(age)) => format!("stale    last {source} {age:.1} s ago"),
            (false, _, None) => format!("missing  no {source}"),
        };
        println!("  {:<9} {what}", p.part.name());
    }
    let vertical = match (st.vertical_rate, st.vertical_valid) {
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
    println!("controller  {}", st.now.capability);
    let outputs_line: Vec<String> =
        st.functions.by_output.iter().map(|(n, f)| format!("{n} {}", function_name(*f))).collect();
    println!(
        "outputs     {}",
        if outputs_line.is_empty() {
            "unknown (SERVOn_FUNCTION not answered)".to_string()
        } else {
            outputs_line.join(", ")
        }
    );
    for (way, r) in &st.ways {
        match r {
            Ok(()) => println!("command     --command {}: reaches every thruster", way.name()),
            Err(e) => println!("command     --command {}: refused: {e}", way.name()),
        }
    }
    if let Some(g) = st.params.get("JS_GAIN_DEFAULT") {
        println!("pilot gain  {g} (JS_GAIN_DEFAULT: pinc's --command manual uses it)");
    }
    println!("{}", st.heading.describe());
    if st.not_ready.is_empty() {
        println!("estimate    the autopilot's attitude and heading are usable (EKF_STATUS_REPORT)");
    } else {
        println!("estimate    not ready: {}", st.not_ready.join("; "));
    }
    if st.malformed > 0 {
        println!("malformed   {} frames could not be parsed", st.malformed);
    }
}

fn capability_key(c: Capability) -> &'static str {
    match c {
        Capability::Full => "full",
        Capability::DepthHeading => "depth_heading",
        Capability::None => "none",
    }
}
