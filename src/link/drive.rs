//! A command session on a live vehicle, shared by `pinc vehicle excite` and
//! `mpc_track --connect`: the cycle is driven by the state's arrival (one command per fresh
//! state sample at most, so the command rate never exceeds the sample rate), every message
//! passes the [`Safety`] watchdog, and any trigger sends the neutral command at once and
//! disarms if the session armed.

use super::autopilot_estimate::EkfStatus;
use super::command::{Command, CommandWay, Commander};
use super::ground_station::GroundStationPlace;
use super::link::{
    Autopilot, EKF_STATUS_REPORT_ID, GPS_RAW_INT_ID, LinkError, Received, SYS_STATUS_ID, SubMode, VehicleLink,
    is_ground_station,
};
use super::outputs::{OutputFunctions, function_params};
use super::params::{Params, read_params};
use super::safety::{Safety, SafetyLimits, SensorWatch, Trigger};
use super::state::{RawState, StateAssembler, message_time};
use crate::closed_loop::Level;
use crate::estimation::Measurement;
use crate::estimation::mavlink::Observation;
use crate::types::Input;
use mavlink::dialects::ardupilotmega::{MavCmd, MavMessage, MavResult, MavSeverity, STATUSTEXT_DATA};
use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// One fresh state sample and when it arrived.
#[derive(Debug, Clone)]
pub struct Fresh {
    /// The state.
    pub state: RawState,
    /// Host time it arrived.
    pub arrived: Instant,
}

/// What was sent for one cycle.
#[derive(Debug, Clone, Copy)]
pub struct Sent {
    /// The command.
    pub command: Command,
    /// Host time it went out.
    pub at: Instant,
    /// Autopilot time (s) it went out.
    pub autopilot_t: f64,
}

/// How a session stopped.
#[derive(Debug, Clone)]
pub struct Stopped {
    /// Why; `None`: the session ran to its end.
    pub trigger: Option<Trigger>,
    /// Autopilot time (s) of the trigger.
    pub t: f64,
    /// Autopilot time (s) the neutral command went out, if it could be sent.
    pub neutral_t: Option<f64>,
    /// Whether a disarm was sent (the session had armed).
    pub disarm_sent: bool,
    /// Notes not yet taken with [`Drive::take_notes`] (for a session that could not start,
    /// the arming refusals).
    pub notes: Vec<Note>,
}

/// A command session.
pub struct Drive {
    link: VehicleLink,
    autopilot: Autopilot,
    assembler: StateAssembler,
    commander: Commander,
    safety: Safety,
    stop: Arc<AtomicBool>,
    armed_by_us: bool,
    /// The newest autopilot stamp per message type, to count what arrives out of order.
    newest: HashMap<&'static str, f64>,
    /// Messages older than the newest of their type (dropped or reordered on the way).
    out_of_order: u64,
    last_sent: Option<f64>,
    notes: Vec<Note>,
    echo_notes: bool,
    /// The last `COMMAND_ACK` of an arm command, and the last `PreArm:`/`Arm:` text.
    arm_ack: Option<MavResult>,
    arm_text: Option<String>,
    observations: Vec<Observation>,
    /// The autopilot's parameters read at the start.
    params: Params,
    /// The newest `EKF_STATUS_REPORT`.
    ekf_status: Option<EkfStatus>,
    /// The flight mode of the autopilot's newest heartbeat (`custom_mode`).
    mode: u32,
    /// The flight mode the autopilot was in when the session found it: what a hand-back
    /// returns to.
    mode_before: u32,
    /// The newest `GPS_RAW_INT` fix type.
    gps_fix: Option<u8>,
    /// The newest `SYS_STATUS`'s health of a DVL (visual odometry), where one is present.
    vision_healthy: Option<bool>,
    /// When the EKF origin was last asked for.
    origin_asked: Option<Instant>,
    watch: SensorWatch,
    /// Silence (s) of depth or heading, and how long (s) a live depth reading may stay the same.
    sensor_silence: f64,
    frozen_depth: f64,
    /// The ground station's place pinc took for the session, given back at the stop.
    ground_station: Option<GroundStationPlace>,
}

/// How often the EKF origin is asked for while fixes come without it.
const ORIGIN_ASK_EVERY: Duration = Duration::from_secs(2);
/// `GPS_GLOBAL_ORIGIN`'s message id.
const GPS_GLOBAL_ORIGIN_ID: u32 = 49;
/// How often an arm command is repeated while the autopilot refuses it (ground stations
/// retry about once a second too).
const ARM_RETRY: Duration = Duration::from_secs(1);
/// The longest one wait for a message lasts, so that a trigger is seen within it.
const POLL: Duration = Duration::from_millis(5);
/// A pause this long ends a burst of messages (ArduSub's come within microseconds of each
/// other on loopback; its bursts are a sample period apart).
const BURST_GAP: Duration = Duration::from_millis(2);
/// The longest a sample waits for the rest of its burst.
const BURST_MAX: Duration = Duration::from_millis(10);
/// How long the parameters pinc needs may take to answer (ArduSub answers within 0.35 s;
/// requests are repeated every half second).
const PARAM_TIMEOUT: Duration = Duration::from_secs(3);
/// The rate `EKF_STATUS_REPORT` and `GPS_RAW_INT` are asked for.
pub const AUTOPILOT_ESTIMATE_RATE_HZ: f64 = 2.0;
/// The parameters every session reads besides the outputs' functions.
const SESSION_PARAMS: [&str; 5] =
    ["JS_GAIN_DEFAULT", "COMPASS_DEC", "COMPASS_AUTODEC", "EK3_SRC1_POSXY", "EK3_SRC1_VELXY"];
/// The rate `SYS_STATUS` is asked for: a DVL's health flag clears 0.3 s after its last
/// message (ArduPilot's visual odometry), and the goal should drop within a second of it.
pub const SYS_STATUS_RATE_HZ: f64 = 5.0;

/// Reads what a session needs of the autopilot's configuration: its outputs' functions, pilot
/// gain, declination parameters and horizontal position source (a name it does not answer
/// within the wait is absent). Every message received meanwhile goes to `seen`.
///
/// # Errors
/// The link breaks.
pub fn read_autopilot_config(
    link: &mut VehicleLink,
    autopilot: &Autopilot,
    seen: impl FnMut(&Received),
) -> Result<Params, LinkError> {
    let mut names = function_params();
    names.extend(SESSION_PARAMS.iter().map(|s| s.to_string()));
    read_params(link, autopilot, &names, PARAM_TIMEOUT, seen)
}

/// How a session starts and what it runs under.
#[derive(Debug, Clone)]
pub struct DriveSettings {
    /// The watchdog's limits.
    pub limits: SafetyLimits,
    /// Arm the vehicle if it is disarmed (pinc never arms otherwise).
    pub arm: bool,
    /// How long to keep asking while the autopilot refuses to arm (it does for its first
    /// seconds, until its EKF has aligned).
    pub arm_timeout: Duration,
    /// Print each note of level warning or above on stderr as it comes.
    pub echo_notes: bool,
    /// Take the pilot gain from the autopilot's `JS_GAIN_DEFAULT` (the commander's is only a
    /// fallback where the autopilot does not answer it).
    pub js_gain_from_autopilot: bool,
    /// Depth or heading silent this long (s) stops the session.
    pub sensor_silence: f64,
    /// A live depth reading unchanged this long (s) stops the session.
    pub frozen_depth: f64,
    /// The ground station whose place pinc takes for the session (its system id): the
    /// autopilot's ground-station id (`MAV_GCS_SYSID`, `SYSID_MYGCS` on older firmware) is set
    /// to pinc's own before anything is commanded, so the autopilot takes pilot axes from pinc
    /// alone, and set back at every stop ([`GroundStationPlace`]).
    pub replaces_ground_station: Option<u8>,
}

impl Default for DriveSettings {
    fn default() -> Self {
        Self {
            limits: SafetyLimits::default(),
            arm: false,
            arm_timeout: Duration::from_secs(30),
            echo_notes: false,
            js_gain_from_autopilot: false,
            sensor_silence: 0.5,
            frozen_depth: 1.0,
            replaces_ground_station: None,
        }
    }
}

/// Something the autopilot said (`STATUSTEXT`) or the session noticed, for the log.
#[derive(Debug, Clone, PartialEq)]
pub struct Note {
    /// Autopilot time (s).
    pub t: f64,
    /// Its level.
    pub level: Level,
    /// A sentence.
    pub text: String,
    /// Whether it is the autopilot's own `STATUSTEXT`.
    pub from_autopilot: bool,
}

/// The log level of a `STATUSTEXT` severity, and its name.
pub fn severity_level(s: MavSeverity) -> (Level, &'static str) {
    match s {
        MavSeverity::MAV_SEVERITY_EMERGENCY => (Level::Error, "EMERGENCY"),
        MavSeverity::MAV_SEVERITY_ALERT => (Level::Error, "ALERT"),
        MavSeverity::MAV_SEVERITY_CRITICAL => (Level::Error, "CRITICAL"),
        MavSeverity::MAV_SEVERITY_ERROR => (Level::Error, "ERROR"),
        MavSeverity::MAV_SEVERITY_WARNING => (Level::Warning, "WARNING"),
        MavSeverity::MAV_SEVERITY_NOTICE => (Level::Warning, "NOTICE"),
        MavSeverity::MAV_SEVERITY_INFO => (Level::Info, "INFO"),
        MavSeverity::MAV_SEVERITY_DEBUG => (Level::Info, "DEBUG"),
    }
}

/// The text of a `STATUSTEXT` (up to its first NUL).
pub fn statustext(s: &STATUSTEXT_DATA) -> String {
    s.text.to_str().map_or_else(|_| String::from_utf8_lossy(s.text.as_slice()).into_owned(), str::to_string)
}

impl Drive {
    /// Starts a session on an open link whose autopilot was found: MANUAL mode, then, with
    /// `settings.arm`, arming: the arm command is repeated every second while the autopilot
    /// refuses (each refusal's `COMMAND_ACK` result and `PreArm:`/`Arm:` text becomes a
    /// note), until a heartbeat says armed or `arm_timeout` passes. Every message received
    /// meanwhile goes to `seen` with its autopilot time.
    ///
    /// # Errors
    /// The vehicle is disarmed and `arm` is false; the autopilot did not arm within the
    /// timeout (the error names its last reason); a trigger fires meanwhile (Ctrl-C, the
    /// link).
    #[allow(clippy::too_many_arguments)]
    pub fn start(
        link: VehicleLink,
        autopilot: Autopilot,
        assembler: StateAssembler,
        commander: Commander,
        settings: DriveSettings,
        stop: Arc<AtomicBool>,
        mut seen: impl FnMut(&Received, f64),
    ) -> Result<Self, Stopped> {
        let now = Instant::now();
        let mode = autopilot.heartbeat.custom_mode;
        let mut safety = Safety::new(settings.limits.clone(), now);
        safety.heartbeat(now, Autopilot::armed(&autopilot.heartbeat));
        let mut assembler = assembler;
        assembler.set_thrusters(commander.thrusters().clone());
        let mut d = Self {
            link,
            autopilot,
            assembler,
            commander,
            safety,
            stop,
            armed_by_us: false,
            newest: HashMap::new(),
            out_of_order: 0,
            last_sent: None,
            notes: Vec::new(),
            echo_notes: settings.echo_notes,
            arm_ack: None,
            arm_text: None,
            observations: Vec::with_capacity(64),
            params: Params::default(),
            ekf_status: None,
            mode,
            mode_before: mode,
            gps_fix: None,
            vision_healthy: None,
            origin_asked: None,
            watch: SensorWatch::default(),
            sensor_silence: settings.sensor_silence,
            frozen_depth: settings.frozen_depth,
            ground_station: None,
        };
        // The autopilot's configuration first: nothing is sent to the thrusters unless its
        // outputs take commands the way asked.
        let mut early = Vec::new();
        match read_autopilot_config(&mut d.link, &d.autopilot, |r| early.push(r.clone())) {
            Ok(p) => d.params = p,
            Err(e) => return Err(d.refuse(Trigger::Link(e.to_string()))),
        }
        for r in &early {
            // Its heartbeats while it answered (or left unanswered, 3 s) the parameters.
            if let Some(trigger) = d.pass_on(r, &mut seen) {
                return Err(d.stop_with_trigger(trigger));
            }
        }
        let outputs = OutputFunctions::from_params(&d.params);
        if let Err(refused) = outputs.check(d.commander.way(), d.commander.thrusters()) {
            return Err(d.refuse(Trigger::Refused(refused.to_string())));
        }
        if settings.js_gain_from_autopilot
            && let Some(gain) = d.params.get("JS_GAIN_DEFAULT")
            && d.commander.way() == CommandWay::Manual
        {
            let t = d.now_t();
            match d.commander.with_js_gain(gain) {
                Ok(c) => {
                    d.commander = c;
                    d.note(t, Level::Info, format!("pilot gain {gain} from the autopilot (JS_GAIN_DEFAULT)"));
                }
                Err(e) => return Err(d.refuse(Trigger::Refused(format!("the autopilot's JS_GAIN_DEFAULT: {e}")))),
            }
        }
        for (id, hz) in [
            (EKF_STATUS_REPORT_ID, AUTOPILOT_ESTIMATE_RATE_HZ),
            (GPS_RAW_INT_ID, AUTOPILOT_ESTIMATE_RATE_HZ),
            (SYS_STATUS_ID, SYS_STATUS_RATE_HZ),
        ] {
            if let Err(e) = d.link.set_message_rate(id, hz) {
                return Err(d.stop_with_trigger(Trigger::Link(e.to_string())));
            }
        }
        if let Some(ground) = settings.replaces_ground_station
            && let Err(t) = d.take_ground_station_place(ground, &mut seen)
        {
            return Err(d.stop_with_trigger(t));
        }
        if let Err(e) = d.link.set_mode(SubMode::Manual) {
            return Err(d.stop_with_trigger(Trigger::Link(e.to_string())));
        }
        if !d.safety.armed() {
            if !settings.arm {
                return Err(d.stop_with_trigger(Trigger::Error(
                    "the vehicle is disarmed: arm it from the ground station, or pass --arm to let pinc arm it".into(),
                )));
            }
            if let Err(t) = d.arm(settings.arm_timeout, &mut seen) {
                return Err(d.stop_with_trigger(t));
            }
        }
        Ok(d)
    }

    /// Makes pinc the autopilot's ground station in place of `ground` (whose `MANUAL_CONTROL`
    /// the autopilot then ignores; pinc reads it as the pilot's sticks); [`Drive::stop`] gives
    /// the place back.
    fn take_ground_station_place(&mut self, ground: u8, seen: &mut impl FnMut(&Received, f64)) -> Result<(), Trigger> {
        let t = self.now_t();
        let mut heard = Vec::new();
        let taken = GroundStationPlace::take(&mut self.link, &self.autopilot, ground, |r| heard.push(r.clone()));
        // Its heartbeats meanwhile (up to 1.5 s for a name the firmware does not have) keep the
        // watchdog's clock: unheard, the arming after it met a heartbeat 2.5 s old.
        let mut stop = None;
        for r in &heard {
            stop = stop.or(self.pass_on(r, seen));
        }
        match taken {
            Ok((place, said)) => {
                self.announce(t, Level::Info, said);
                self.ground_station = Some(place);
                stop.map_or(Ok(()), Err)
            }
            Err((place, trigger)) => {
                // The stop that follows sets back what may have been set.
                self.ground_station = place;
                Err(trigger)
            }
        }
    }

    /// Asks the autopilot to arm until a heartbeat says armed, repeating while it refuses.
    fn arm(&mut self, timeout: Duration, seen: &mut impl FnMut(&Received, f64)) -> Result<(), Trigger> {
        let start = Instant::now();
        let mut attempts = 0u32;
        let mut next_try = start;
        let mut last_reason: Option<String> = None;
        while !self.safety.armed() {
            let now = Instant::now();
            if now >= start + timeout {
                return Err(Trigger::Error(format!(
                    "the autopilot did not arm within {:.0} s ({attempts} arm command(s)); last reason: {}",
                    timeout.as_secs_f64(),
                    last_reason.as_deref().unwrap_or("none given (no COMMAND_ACK or Arm/PreArm text arrived)")
                )));
            }
            if now >= next_try {
                self.arm_ack = None;
                self.arm_text = None;
                self.link.arm(true).map_err(|e| Trigger::Link(e.to_string()))?;
                self.armed_by_us = true;
                attempts += 1;
                next_try = now + ARM_RETRY;
            }
            self.poll(seen, POLL)?;
            if let Some(result) = self.arm_ack.take()
                && result != MavResult::MAV_RESULT_ACCEPTED
                && result != MavResult::MAV_RESULT_IN_PROGRESS
            {
                // The autopilot's text comes just before its answer; wait a moment for a late one.
                let until = Instant::now() + Duration::from_millis(50);
                while self.arm_text.is_none() && Instant::now() < until {
                    self.poll(seen, POLL)?;
                }
                let result_name = format!("{result:?}");
                let result_name = result_name.strip_prefix("MAV_RESULT_").unwrap_or(&result_name).to_string();
                let reason = match &self.arm_text {
                    Some(text) => format!("{text} (COMMAND_ACK {result_name})"),
                    None => format!("COMMAND_ACK {result_name}"),
                };
                let t = self.now_t();
                self.note(t, Level::Warning, format!("arming refused: {reason}; asking again in 1 s"));
                last_reason = Some(reason);
            }
        }
        let t = self.now_t();
        let waited = start.elapsed().as_secs_f64();
        self.note(t, Level::Info, format!("armed after {waited:.1} s ({attempts} arm command(s))"));
        Ok(())
    }

    fn note(&mut self, t: f64, level: Level, text: String) {
        self.push_note(Note { t, level, text, from_autopilot: false });
    }

    /// A note said on stderr whatever its level (with the notes echoed): what the session
    /// changed on the autopilot, and whether it was undone.
    fn announce(&mut self, t: f64, level: Level, text: String) {
        if self.echo_notes && level < Level::Warning {
            eprintln!("{text}");
        }
        self.note(t, level, text);
    }

    fn push_note(&mut self, note: Note) {
        if self.echo_notes && note.level >= Level::Warning {
            eprintln!("{}", note.text);
        }
        self.notes.push(note);
    }

    /// The notes since the last call: the autopilot's `STATUSTEXT`s and what the session
    /// noticed (arming refusals).
    pub fn take_notes(&mut self) -> Vec<Note> {
        std::mem::take(&mut self.notes)
    }

    /// The measurements and applied inputs of every message since the last call, in arrival
    /// order (for a state estimator).
    pub fn drain_observations(&mut self) -> std::vec::Drain<'_, Observation> {
        self.observations.drain(..)
    }

    /// The autopilot.
    pub fn autopilot(&self) -> &Autopilot {
        &self.autopilot
    }

    /// The link.
    pub fn link(&self) -> &VehicleLink {
        &self.link
    }

    /// The raw state's assembler.
    pub fn assembler(&self) -> &StateAssembler {
        &self.assembler
    }

    /// The autopilot's parameters read at the start (its outputs' functions, pilot gain and
    /// declination).
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Whether the autopilot's position is a measurement now (not dead-reckoned or held):
    /// [`super::autopilot_estimate::position_measured`].
    pub fn position_measured(&self) -> bool {
        super::autopilot_estimate::position_measured(
            self.ekf_status.as_ref(),
            &self.params,
            self.gps_fix,
            self.vision_healthy,
        )
    }

    /// Whether the autopilot's own position controllers (GUIDED, POSHOLD) have their position:
    /// measured, and absolute where its source is one (`EK3_SRC1_POSXY` 3: a GPS, a USBL read
    /// as one; a DVL's EKF flies relative to its start until it takes the fixes up, measured
    /// 25-37 s after arming with the USBL stand-in, and then jumps to them).
    pub fn position_ready_for_its_hold(&self) -> bool {
        let absolute_source = self.params.get("EK3_SRC1_POSXY") == Some(3.0);
        self.position_measured()
            && (!absolute_source || self.ekf_status.as_ref().is_some_and(|s| s.absolute_position()))
    }

    /// Whether the autopilot's horizontal position is integrated from velocities alone
    /// (`EK3_SRC1_POSXY` 0: a DVL without position resets), not measured absolutely.
    pub fn position_integrated(&self) -> bool {
        self.params.get("EK3_SRC1_POSXY") == Some(0.0)
    }

    /// The flight mode of the autopilot's newest heartbeat (ArduSub's `custom_mode`).
    pub fn mode(&self) -> u32 {
        self.mode
    }

    /// The newest `EKF_STATUS_REPORT`, if one came.
    pub fn ekf_status(&self) -> Option<&EkfStatus> {
        self.ekf_status.as_ref()
    }

    /// The commander.
    pub fn commander(&self) -> &Commander {
        &self.commander
    }

    /// The way commands go.
    pub fn way(&self) -> CommandWay {
        self.commander.way()
    }

    /// Messages that arrived older than the newest of their type so far (and were dropped by
    /// the state's reconstruction).
    pub fn out_of_order(&self) -> u64 {
        self.out_of_order
    }

    /// Autopilot time now (s).
    pub fn now_t(&self) -> f64 {
        self.assembler.autopilot_time(Instant::now()).unwrap_or(0.0)
    }

    /// The autopilot's heartbeat in `r` (not a ground station's), if it is one: its mode, and
    /// the watchdog fed; the trigger when the heartbeat says the vehicle is lost.
    fn heard(&mut self, r: &Received) -> Option<Trigger> {
        let MavMessage::HEARTBEAT(h) = &r.message else { return None };
        if is_ground_station(h) {
            return None;
        }
        self.mode = h.custom_mode;
        self.safety.heartbeat(r.at, Autopilot::armed(h))
    }

    /// Reads one message of the autopilot, once: the raw state, the observations for the
    /// estimator, the sensor watch; counts a message older than the newest of its type.
    fn read(&mut self, r: &Received) -> Option<RawState> {
        if let Some(t) = message_time(&r.message) {
            let newest = self.newest.entry(mavlink::Message::message_name(&r.message)).or_insert(f64::MIN);
            if t < *newest {
                self.out_of_order += 1;
            }
            *newest = newest.max(t);
        }
        let (observations, watch) = (&mut self.observations, &mut self.watch);
        self.assembler.update(r, |o| {
            match o {
                Observation::Measured(Measurement::Depth { t, z }) => watch.depth(t, z, true),
                Observation::Measured(Measurement::Position { t, z, .. }) if z.is_finite() => {
                    watch.depth(t, z, false);
                }
                Observation::Measured(Measurement::Heading { t, .. }) => watch.heading(t),
                _ => {}
            }
            observations.push(o);
        })
    }

    /// Asks the autopilot for its EKF origin (`GPS_GLOBAL_ORIGIN`), at most every
    /// [`ORIGIN_ASK_EVERY`], while fixes come and it is not known: a fix in degrees is placed
    /// in the local frame from it.
    fn ask_origin(&mut self, at: Instant) {
        if self.assembler.reader().origin().is_some()
            || self.origin_asked.is_some_and(|then| at.saturating_duration_since(then) < ORIGIN_ASK_EVERY)
        {
            return;
        }
        self.origin_asked = Some(at);
        // A refusal or a lost request is asked again; the link's own failure shows elsewhere.
        self.link.request_message(GPS_GLOBAL_ORIGIN_ID).ok();
    }

    /// Handles one message (or a short silence): the watchdog, the state.
    fn poll(&mut self, seen: &mut impl FnMut(&Received, f64), most: Duration) -> Result<Option<Fresh>, Trigger> {
        if self.stop.load(Ordering::Relaxed) {
            return Err(Trigger::Interrupted);
        }
        let wait = self.safety.next_deadline().saturating_duration_since(Instant::now()).clamp(Duration::ZERO, most);
        let r = self.link.recv_timeout(wait).map_err(|e: LinkError| Trigger::Link(e.to_string()))?;
        let mut fresh = None;
        if let Some(r) = r {
            let from_autopilot = self.autopilot.sent(&r);
            // A DVL's deltas and a USBL's fixes come from their own systems (BlueOS's
            // extensions, ground stations beside pinc), forwarded by the autopilot:
            // measurements, never the state's clock.
            let state = match &r.message {
                _ if from_autopilot => self.read(&r),
                MavMessage::VISION_POSITION_DELTA(_) => self.read(&r).and(None),
                MavMessage::GPS_INPUT(_) | MavMessage::GLOBAL_VISION_POSITION_ESTIMATE(_) => {
                    self.ask_origin(r.at);
                    self.read(&r).and(None)
                }
                _ => None,
            };
            let t = self.assembler.autopilot_time(r.at).unwrap_or(0.0);
            seen(&r, t);
            if from_autopilot {
                match &r.message {
                    MavMessage::EKF_STATUS_REPORT(e) => self.ekf_status = Some(EkfStatus::new(t, e)),
                    MavMessage::GPS_RAW_INT(g) => self.gps_fix = Some(g.fix_type as u8),
                    MavMessage::SYS_STATUS(s) => {
                        self.vision_healthy = super::autopilot_estimate::vision_health(
                            s.onboard_control_sensors_present.bits(),
                            s.onboard_control_sensors_health.bits(),
                        )
                    }
                    MavMessage::STATUSTEXT(s) => {
                        let text = statustext(s);
                        if text.starts_with("PreArm") || text.starts_with("Arm") {
                            self.arm_text = Some(text.clone());
                        }
                        let (level, name) = severity_level(s.severity);
                        self.push_note(Note {
                            t,
                            level,
                            text: format!("autopilot {name}: {text}"),
                            from_autopilot: true,
                        });
                    }
                    MavMessage::COMMAND_ACK(a) if a.command == MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => {
                        self.arm_ack = Some(a.result);
                    }
                    _ => {}
                }
                if let Some(trigger) = self.heard(&r) {
                    return Err(trigger);
                }
                if let Some(s) = state {
                    if let Some(trigger) = self.safety.state(r.at, s.sim[2], s.sim[7]) {
                        return Err(trigger);
                    }
                    // Depth and heading are what a controller cannot do without: their silence
                    // stops it (the state sample's own clock goes on while either keeps coming).
                    if let Some(trigger) = self.watch.check(s.t, self.sensor_silence, self.frozen_depth) {
                        return Err(trigger);
                    }
                    fresh = Some(Fresh { state: s, arrived: r.at });
                }
            }
        }
        match self.safety.check(Instant::now(), self.link.malformed()) {
            Some(trigger) => Err(trigger),
            None => Ok(fresh),
        }
    }

    /// Waits for the next fresh state sample, passing every message to `seen` with its
    /// autopilot time.
    ///
    /// # Errors
    /// A safety trigger.
    pub fn next_state(&mut self, mut seen: impl FnMut(&Received, f64)) -> Result<Fresh, Trigger> {
        let mut fresh = loop {
            if let Some(f) = self.poll(&mut seen, POLL)? {
                break f;
            }
        };
        // ArduSub sends a sample's messages in one burst, ATTITUDE (the clock) first and the
        // depth and vertical velocity of the same stamp after it: the rest of the burst is read
        // before the sample is handed on, or the estimator would fuse them a sample late.
        let until = Instant::now() + BURST_MAX;
        while Instant::now() < until {
            let before = self.link.received();
            match self.poll(&mut seen, BURST_GAP)? {
                Some(f) => fresh = f,
                None if self.link.received() == before => break,
                None => {}
            }
        }
        Ok(fresh)
    }

    /// Sends the command for `input` (at most once per state sample: a second send for the
    /// same state is refused, so the command rate never exceeds the sample rate).
    ///
    /// # Errors
    /// Sending fails (a link trigger), or a command for this state was already sent.
    pub fn send(&mut self, fresh: &Fresh, input: &Input) -> Result<Sent, Trigger> {
        self.send_command(fresh, self.commander.command(input))
    }

    /// Sends the neutral command for this cycle (waiting for a state part, say).
    ///
    /// # Errors
    /// As [`Drive::send`].
    pub fn send_neutral(&mut self, fresh: &Fresh) -> Result<Sent, Trigger> {
        self.send_command(fresh, self.commander.neutral())
    }

    /// The pilot's `sticks` as `MANUAL_CONTROL`'s pilot axes (the autopilot's own holds take
    /// them as a ground station's joystick): full deflection 1000, heave down below 500.
    pub fn send_sticks(&mut self, fresh: &Fresh, sticks: crate::pilot::Sticks) -> Result<Sent, Trigger> {
        let (x, y, z, r) = sticks.to_manual_control();
        self.send_command(fresh, Command::Manual { x, y, z, r })
    }

    fn send_command(&mut self, fresh: &Fresh, command: Command) -> Result<Sent, Trigger> {
        if self.last_sent.is_some_and(|t| fresh.state.t <= t) {
            return Err(Trigger::Error(format!("a second command for the state at {:.3} s", fresh.state.t)));
        }
        self.commander.send(&self.link, &command).map_err(|e| Trigger::Link(e.to_string()))?;
        let at = Instant::now();
        self.last_sent = Some(fresh.state.t);
        Ok(Sent { command, at, autopilot_t: self.assembler.autopilot_time(at).unwrap_or(fresh.state.t) })
    }

    /// Stops on `trigger`: the neutral command at once, then a disarm if the session armed.
    pub fn abort(&mut self, trigger: Trigger) -> Stopped {
        self.stop(Some(trigger))
    }

    /// Ends a session that ran to its end: neutral, and a disarm if the session armed.
    pub fn finish(&mut self) -> Stopped {
        self.stop(None)
    }

    /// Ends a session by handing the vehicle back as the pilot had it (asked, not a stop):
    /// neutral, the flight mode the autopilot was in before the session (asked while pinc is
    /// still its ground station), a disarm only if the session armed it, and the ground-station
    /// place given back.
    pub fn hand_back(&mut self) -> Stopped {
        let t = self.now_t();
        let _ = self.commander.send(&self.link, &self.commander.neutral());
        let before = self.mode_before;
        let mode = SubMode::ALL.into_iter().find(|m| *m as u32 == before && *m != SubMode::Manual);
        let said = match mode {
            _ if self.armed_by_us => "pinc had armed it: neutral and disarm".to_string(),
            Some(m) => match self.link.set_mode(m) {
                Ok(()) => format!("its mode {} asked back, still armed", m.name()),
                Err(e) => format!("its mode {} could not be asked back ({e}): left in MANUAL, armed", m.name()),
            },
            None => format!("left in {}, armed, as it was", SubMode::name_of(before)),
        };
        self.announce(t, Level::Info, format!("the vehicle handed back to the pilot: {said}"));
        self.stop(None)
    }

    fn stop_with_trigger(&mut self, trigger: Trigger) -> Stopped {
        self.stop(Some(trigger))
    }

    /// Ends a session that has sent nothing yet (a refusal of the autopilot's configuration):
    /// no command goes out.
    fn refuse(&mut self, trigger: Trigger) -> Stopped {
        Stopped {
            trigger: Some(trigger),
            t: self.now_t(),
            neutral_t: None,
            disarm_sent: false,
            notes: std::mem::take(&mut self.notes),
        }
    }

    fn stop(&mut self, trigger: Option<Trigger>) -> Stopped {
        let t = self.now_t();
        let neutral = self.commander.send(&self.link, &self.commander.neutral());
        let neutral_t = neutral.is_ok().then(|| self.now_t());
        let disarm_sent = self.armed_by_us && self.link.arm(false).is_ok();
        // Once more after a moment: UDP may lose one.
        std::thread::sleep(Duration::from_millis(20));
        let _ = self.commander.send(&self.link, &self.commander.neutral());
        if self.armed_by_us {
            let _ = self.link.arm(false);
        }
        if let Some(place) = self.ground_station.take() {
            let (level, said) = match place.give_back(&mut self.link, &self.autopilot) {
                Ok(said) => (Level::Info, said),
                Err(said) => (Level::Error, said),
            };
            let t = self.now_t();
            self.announce(t, level, said);
        }
        Stopped { trigger, t, neutral_t, disarm_sent, notes: std::mem::take(&mut self.notes) }
    }

    /// Waits `duration` while passing messages on (after a stop: the last messages into the
    /// recording, and what they measured to [`Drive::drain_observations`]).
    pub fn drain(&mut self, duration: Duration, mut seen: impl FnMut(&Received, f64)) {
        let until = Instant::now() + duration;
        while Instant::now() < until {
            match self.link.recv_timeout(POLL) {
                Ok(Some(r)) => {
                    // After the stop: nothing more to trigger.
                    let _ = self.pass_on(&r, &mut seen);
                }
                Ok(None) => {}
                Err(_) => break,
            }
        }
    }

    /// A message received outside the cycle's poll: the autopilot's read into the state and its
    /// heartbeat to the watchdog (what that triggers is returned), and every one to `seen` with
    /// its autopilot time.
    fn pass_on(&mut self, r: &Received, seen: &mut impl FnMut(&Received, f64)) -> Option<Trigger> {
        let trigger = if self.autopilot.sent(r) {
            self.read(r);
            self.heard(r)
        } else {
            None
        };
        let t = self.assembler.autopilot_time(r.at).unwrap_or(0.0);
        seen(r, t);
        trigger
    }
}
