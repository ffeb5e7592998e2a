//! `pinc vehicle record`: listen and record.

use super::writer::{Writer, recording_estimator};
use super::{RecordArgs, SERVO_OUTPUT_RAW_ID, ctrl_c_flag, session_metadata};
use crate::closed_loop::Level;
use crate::link::cli::{open, positive};
use crate::link::{InputsFromOutputs, Received, Recorder};
use crate::vehicle::Thrusters;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
pub(super) fn run_record(a: RecordArgs) -> Result<(), String> {
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
        let state = if autopilot.sent(&r) { assembler.update(&r, |o| observed.push(o)) } else { None };
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
