//! `pinc vehicle check`: the autopilot's firmware and the parameters pinc and the sensors fitted
//! need ([`crate::link::check`]); `--set` sets the failing ones, their old values saved first,
//! and `--restore FILE` sets such a file's values back.

use super::CheckArgs;
use crate::link::check::{self, CheckError, CheckSettings, Firmware, FirmwareCheck, Row, Sensors, show};
use crate::link::cli::open;
use crate::link::link::AUTOPILOT_VERSION_ID;
use crate::link::{Autopilot, Params, Received, VehicleLink, read_params};
use mavlink::dialects::ardupilotmega::MavMessage;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How long the parameters may take to answer: ArduSub answers within 0.35 s, requests are
/// repeated every half second, and a name the firmware does not have (one of the two
/// ground-station names) is never answered.
const PARAM_TIMEOUT: Duration = Duration::from_secs(3);
/// How long one value set may take to be confirmed.
const SET_TIMEOUT: Duration = Duration::from_secs(3);
/// How long to wait for `AUTOPILOT_VERSION` after the parameters.
const VERSION_TIMEOUT: Duration = Duration::from_millis(1500);

/// What the autopilot said of its version, from `AUTOPILOT_VERSION` or its boot banner.
#[derive(Default)]
struct Heard {
    version: Option<Firmware>,
    git: Option<String>,
    banner: Option<Firmware>,
}

impl Heard {
    fn take(&mut self, autopilot: Option<&Autopilot>, r: &Received) {
        if autopilot.is_some_and(|a| !a.sent(r)) {
            return;
        }
        match &r.message {
            MavMessage::AUTOPILOT_VERSION(v) => {
                self.version = Some(Firmware::from_sw_version(v.flight_sw_version));
                self.git = check::git_hash(v);
            }
            MavMessage::STATUSTEXT(t) => {
                let text: String = t.text.as_slice().iter().take_while(|b| **b != 0).map(|b| *b as char).collect();
                self.banner = self.banner.or(Firmware::from_banner(&text));
            }
            _ => {}
        }
    }

    /// Waits for `AUTOPILOT_VERSION` if it has not come (asked again once: requests travel
    /// over links that lose them).
    fn wait(&mut self, link: &mut VehicleLink, autopilot: &Autopilot) -> Result<(), String> {
        let start = Instant::now();
        let mut asked = false;
        while self.version.is_none() && start.elapsed() < VERSION_TIMEOUT {
            if !asked {
                link.request_message(AUTOPILOT_VERSION_ID).map_err(|e| e.to_string())?;
                asked = true;
            }
            if let Some(r) = link.recv_timeout(Duration::from_millis(50)).map_err(|e| e.to_string())? {
                self.take(Some(autopilot), &r);
            }
        }
        Ok(())
    }

    fn judge(&self, autopilot: &Autopilot) -> FirmwareCheck {
        check::judge_firmware(&autopilot.heartbeat, self.version.or(self.banner), self.git.clone())
    }
}

pub(super) fn run_check(a: CheckArgs) -> Result<(), String> {
    if let Some(d) = a.declination
        && !(d.is_finite() && (-180.0..=180.0).contains(&d))
    {
        return Err(format!("--declination must be degrees east from -180 to 180, got {d}"));
    }
    let sensors = Sensors::parse(&a.sensors).map_err(|e| e.to_string())?;
    // A file to set back is read whole before anything is sent.
    let restore = match &a.restore {
        Some(path) => {
            let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
            let values = check::parse_parm(&text, path).map_err(|e| e.to_string())?;
            if values.is_empty() {
                return Err(format!("{}: no NAME,VALUE line to set back", path.display()));
            }
            Some((path.clone(), values))
        }
        None => None,
    };
    let mut heard = Heard::default();
    let (mut link, autopilot, _) = open(&a.link.connect, &a.link, |r| heard.take(None, r))?;
    if let Some((path, values)) = restore {
        return run_restore(&a, &mut link, &autopilot, &path, &values);
    }
    link.request_message(AUTOPILOT_VERSION_ID).map_err(|e| e.to_string())?;
    let settings = CheckSettings { gcs_sysid: a.link.gcs_sysid, declination_deg: a.declination };
    let names = check::names_to_read(sensors, &settings);
    let params = read_params(&mut link, &autopilot, &names, PARAM_TIMEOUT, |r| heard.take(Some(&autopilot), r))
        .map_err(|e| e.to_string())?;
    heard.wait(&mut link, &autopilot)?;
    let firmware = heard.judge(&autopilot);
    let rows = check::table(sensors, &settings, &params);
    let failed: Vec<&Row> = rows.iter().filter(|r| !r.passes()).collect();
    let set_command = format!("{} --set", command_line(&a, sensors));
    let report = Report { a: &a, autopilot: &autopilot, sensors, firmware: &firmware, rows: &rows };
    if failed.is_empty() || !a.set {
        if a.json {
            print_json(&report.json(json!({"set_command": (!failed.is_empty()).then_some(&set_command)})))?;
        } else {
            report.print();
        }
        if failed.is_empty() {
            if !a.json {
                println!("every check passes{}", if a.set { ": nothing to set" } else { "" });
            }
            return Ok(());
        }
        let changes: Vec<String> = failed.iter().map(|r| change(r)).collect();
        if !a.json {
            println!("{} of {} checks failed: {}", failed.len(), rows.len(), changes.join(", "));
            println!("set them (the old values saved to a file first): {set_command}");
        }
        let names: Vec<&str> = failed.iter().map(|r| r.name()).collect();
        return Err(format!(
            "{} of {} checks failed: {}; `{set_command}` sets them",
            failed.len(),
            rows.len(),
            names.join(", ")
        ));
    }
    if !a.json {
        report.print();
    }
    let done = set_failing(&a, &mut link, &autopilot, &failed)?;
    if a.json {
        print_json(&report.json(json!({
            "set": done.set.iter().map(|(n, from, to)| json!({"name": n, "from": from, "to": to})).collect::<Vec<_>>(),
            "backup": done.backup.display().to_string(),
            "reboot_needed": done.reboot,
            "passes_after_set": true,
        })))?;
    } else {
        if !done.reboot.is_empty() {
            println!(
                "reboot the autopilot before diving (a power cycle, or the ground station's reboot): {} {} read at \
                 boot",
                done.reboot.join(", "),
                if done.reboot.len() == 1 { "is" } else { "are" }
            );
        }
        println!("every check passes now; the old values are in {}", done.backup.display());
    }
    Ok(())
}

/// `pinc vehicle check` with the flags that chose what is checked (for the command it suggests).
fn command_line(a: &CheckArgs, sensors: Sensors) -> String {
    let mut cmd = format!("pinc vehicle check --connect {} --sensors {}", a.link.connect, sensors.name());
    if a.link.gcs_sysid != 255 {
        cmd += &format!(" --gcs-sysid {}", a.link.gcs_sysid);
    }
    if let Some(d) = a.declination {
        cmd += &format!(" --declination {d}");
    }
    if let Some(k) = &a.link.signing_key {
        cmd += &format!(" --signing-key {}", k.display());
    }
    cmd
}

/// "NAME found -> set_to" (or what is wanted where pinc cannot choose).
fn change(r: &Row) -> String {
    let found = r.found.map_or("(not answered)".into(), show);
    match r.requirement.set_to {
        Some(to) => format!("{} {found} -> {}", r.name(), show(to)),
        None => format!("{} {found} -> {} (yours to give)", r.name(), r.requirement.want),
    }
}

/// What `--set` did.
struct SetDone {
    /// Each parameter set: name, old value, new value.
    set: Vec<(String, f32, f32)>,
    /// Where the old values are.
    backup: PathBuf,
    /// The ones read at boot.
    reboot: Vec<String>,
}

/// Saves the old values of `failed`, then sets each to its wanted value, confirmed.
fn set_failing(
    a: &CheckArgs,
    link: &mut VehicleLink,
    autopilot: &Autopilot,
    failed: &[&Row],
) -> Result<SetDone, String> {
    // Everything is judged before anything changes: a value pinc cannot choose, or a name the
    // autopilot does not answer, leaves the autopilot as it was.
    let mut plan = Vec::new();
    for r in failed {
        let (Some(from), Some(to)) = (r.found, r.requirement.set_to) else {
            let why = if r.found.is_none() {
                "the autopilot does not answer it (not a parameter of this firmware?)".to_string()
            } else if r.name() == "COMPASS_DEC" {
                "pinc cannot know the site's declination: give it with --declination DEG (degrees east, e.g. from \
                 NOAA's calculator)"
                    .to_string()
            } else {
                format!("pinc cannot choose its value ({})", r.requirement.want)
            };
            return Err(format!("cannot set {}: {why}; nothing was changed", r.name()));
        };
        plan.push((r.name().to_string(), from as f32, to as f32));
    }
    let now = chrono::Utc::now();
    let backup = a.backup.clone().unwrap_or_else(|| check::default_backup_path(&now));
    let header = [
        format!(
            "pinc vehicle check --set, {}: the values it changed, as they were (system {} on {})",
            now.format("%Y-%m-%d %H:%M:%S UTC"),
            autopilot.system_id,
            a.link.connect
        ),
        format!("set them back: pinc vehicle check --connect {} --restore {}", a.link.connect, backup.display()),
    ];
    let old: Vec<(String, f32)> = plan.iter().map(|(n, from, _)| (n.clone(), *from)).collect();
    check::write_new_file_atomically(&backup, &check::parm_text(&header, &old))
        .map_err(|e| format!("saving the old values: {e}; nothing was changed"))?;
    if !a.json {
        println!("saved the old values of {} parameters to {}", plan.len(), backup.display());
    }
    let mut set = Vec::new();
    for (name, from, to) in plan {
        if let Err(e) = check::set_param(link, autopilot, &name, to, SET_TIMEOUT, |_| {}) {
            return Err(not_all(&e, &set, &backup, &a.link.connect));
        }
        if !a.json {
            println!("set {name} {from} -> {to} (confirmed)");
        }
        set.push((name, from, to));
    }
    let reboot = set.iter().filter(|(n, _, _)| check::read_at_boot(n)).map(|(n, _, _)| n.clone()).collect();
    Ok(SetDone { set, backup, reboot })
}

/// The one-line reason of a `--set` that stopped part way.
fn not_all(e: &CheckError, set: &[(String, f32, f32)], backup: &Path, connect: &str) -> String {
    let before = if set.is_empty() {
        "nothing set before it".to_string()
    } else {
        format!("set before it: {}", set.iter().map(|(n, _, _)| n.as_str()).collect::<Vec<_>>().join(", "))
    };
    format!(
        "{e}; {before}; the old values are in {} (`pinc vehicle check --connect {connect} --restore {}` sets them back)",
        backup.display(),
        backup.display()
    )
}

/// `--restore FILE`: each value of the file set, confirmed; a name the autopilot does not
/// answer stops it before anything changes.
fn run_restore(
    a: &CheckArgs,
    link: &mut VehicleLink,
    autopilot: &Autopilot,
    path: &Path,
    values: &[(String, f32)],
) -> Result<(), String> {
    let names: Vec<String> = values.iter().map(|(n, _)| n.clone()).collect();
    let now: Params = read_params(link, autopilot, &names, PARAM_TIMEOUT, |_| {}).map_err(|e| e.to_string())?;
    let missing: Vec<&str> = names.iter().filter(|n| now.get(n).is_none()).map(String::as_str).collect();
    if !missing.is_empty() {
        return Err(format!(
            "{}: the autopilot does not answer {} (not parameters of this firmware?); nothing was changed",
            path.display(),
            missing.join(", ")
        ));
    }
    let mut restored: Vec<Value> = Vec::new();
    let mut done: Vec<(String, f32, f32)> = Vec::new();
    for (name, value) in values {
        let from = now.get(name).map_or(f32::NAN, |v| v as f32);
        if from == *value {
            if !a.json {
                println!("{name} already {value}");
            }
            restored.push(json!({"name": name, "from": from, "to": value, "changed": false}));
            continue;
        }
        if let Err(e) = check::set_param(link, autopilot, name, *value, SET_TIMEOUT, |_| {}) {
            let before = done.iter().map(|(n, _, _)| n.as_str()).collect::<Vec<_>>().join(", ");
            return Err(format!(
                "{e}; restored before it: {}",
                if before.is_empty() { "nothing".to_string() } else { before }
            ));
        }
        if !a.json {
            println!("restored {name} {from} -> {value} (confirmed)");
        }
        restored.push(json!({"name": name, "from": from, "to": value, "changed": true}));
        done.push((name.clone(), from, *value));
    }
    let reboot: Vec<&str> = done.iter().map(|(n, _, _)| n.as_str()).filter(|n| check::read_at_boot(n)).collect();
    if a.json {
        print_json(&json!({
            "connect": a.link.connect, "system_id": autopilot.system_id, "restored_from": path.display().to_string(),
            "restored": restored, "reboot_needed": reboot,
        }))?;
    } else {
        println!("{} of {} values of {} set back", done.len(), values.len(), path.display());
        if !reboot.is_empty() {
            println!("reboot the autopilot for {} to take effect (read at boot)", reboot.join(", "));
        }
    }
    Ok(())
}

fn print_json(v: &Value) -> Result<(), String> {
    println!("{}", serde_json::to_string_pretty(v).map_err(|e| e.to_string())?);
    Ok(())
}

/// What the check found, for printing.
struct Report<'a> {
    a: &'a CheckArgs,
    autopilot: &'a Autopilot,
    sensors: Sensors,
    firmware: &'a FirmwareCheck,
    rows: &'a [Row],
}

impl Report<'_> {
    fn print(&self) {
        println!(
            "autopilot   system {} component {} on {}",
            self.autopilot.system_id, self.autopilot.component_id, self.a.link.connect
        );
        println!("firmware    {}", self.firmware.text);
        println!("sensors     {}; pinc sends as ground station {}", self.sensors.name(), self.a.link.gcs_sysid);
        for r in self.rows {
            let found = r.found.map_or("-".into(), show);
            println!(
                "{}  {:<16} found {:<12} want {}{}",
                if r.passes() { "PASS" } else { "FAIL" },
                r.name(),
                found,
                r.requirement.want,
                if r.found.is_none() { " (not answered)" } else { "" }
            );
            println!("      {}", r.requirement.why);
        }
    }

    /// The report as JSON, with `extra`'s fields.
    fn json(&self, extra: Value) -> Value {
        let checks: Vec<Value> = self
            .rows
            .iter()
            .map(|r| {
                json!({
                    "name": r.name(), "found": r.found.map(|v| v as f32), "wanted": r.requirement.want.to_string(),
                    "pass": r.passes(), "why": r.requirement.why, "set_to": r.requirement.set_to.map(|v| v as f32),
                    "read_at_boot": r.requirement.at_boot,
                })
            })
            .collect();
        let f = self.firmware;
        let mut out = json!({
            "connect": self.a.link.connect, "system_id": self.autopilot.system_id,
            "firmware": {
                "version": f.version.map(|v| v.to_string()), "git": f.git, "tried": f.tried, "text": f.text,
                "tried_with": format!("ArduSub {} (git {})", check::TRIED_WITH, check::TRIED_WITH_GIT),
            },
            "sensors": self.sensors.name(), "gcs_sysid": self.a.link.gcs_sysid,
            "checks": checks,
            "failed": self.rows.iter().filter(|r| !r.passes()).map(Row::name).collect::<Vec<_>>(),
            "passed": self.rows.iter().all(Row::passes),
        });
        if let (Some(o), Value::Object(e)) = (out.as_object_mut(), extra) {
            o.extend(e);
        }
        out
    }
}
