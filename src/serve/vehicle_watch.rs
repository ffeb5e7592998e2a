//! The server's own link to the autopilot: what the page shows of the vehicle, a new link
//! when the autopilot goes quiet or reboots, and STOP's neutral and disarm (sent from here,
//! whatever a flight's own process does, so that the vehicle stops even if that process hangs).

use crate::estimation::Measurement;
use crate::estimation::mavlink::Observation;
use crate::link::cli::{LinkOptions, open};
use crate::link::ground_station::give_back_left_place;
use crate::link::link::{EKF_STATUS_REPORT_ID, is_ground_station};
use crate::link::{Autopilot, EkfStatus, SubMode};
use mavlink::dialects::ardupilotmega::MavMessage;
use serde_json::{Value, json};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// `HEARTBEAT`'s message id.
const HEARTBEAT_ID: u32 = 0;

/// A link with no heartbeat from the autopilot for this long is replaced.
const QUIET: Duration = Duration::from_secs(3);
/// How long STOP repeats neutral and the disarm (a command can be lost on UDP).
const STOP_REPEAT: Duration = Duration::from_secs(2);
/// Between two repeats.
const STOP_EVERY: Duration = Duration::from_millis(100);
/// The depth "hold here" takes is the mean of the readings over this long.
const DEPTH_MEAN: Duration = Duration::from_secs(1);
/// A depth, heading or position older than this is shown as missing.
const STALE: Duration = Duration::from_secs(2);
/// `EKF_STATUS_REPORT`'s rate (Hz): the estimator's health on the page.
const EKF_RATE_HZ: f64 = 2.0;
/// `HEARTBEAT`'s rate (Hz) on this link: the mode and the armed flag on the page, and when a
/// STOP's disarm took, to a tenth of a second (the autopilot's default is 1 Hz).
const HEARTBEAT_RATE_HZ: f64 = 10.0;

/// What the page shows of the link and the vehicle.
#[derive(Default)]
pub struct VehicleView {
    pub connected: bool,
    /// Why there is no link (the last attempt's error).
    pub error: Option<String>,
    pub links_opened: u32,
    pub system_id: Option<u8>,
    pub mode: Option<String>,
    pub armed: Option<bool>,
    last_heartbeat: Option<Instant>,
    depth: Option<(Instant, f64)>,
    /// The depth sensor's readings of the last [`DEPTH_MEAN`] (pinc's depth from pressure, as a
    /// flight's estimator measures it), for their mean: one reading is off by the sensor's noise
    /// (0.12 m on the simulator), which a hold taken there would keep.
    depths: std::collections::VecDeque<(Instant, f64)>,
    heading: Option<(Instant, f64)>,
    position: Option<(Instant, [f64; 2])>,
    ekf: Option<EkfStatus>,
    stop: Option<StopRecord>,
}

/// One STOP: when it was asked, when neutral and the disarm first went out, when a heartbeat
/// first said disarmed.
#[derive(Clone, Copy)]
struct StopRecord {
    asked: Instant,
    sent: Option<Instant>,
    disarmed: Option<Instant>,
}

fn fresh<T: Copy>(v: Option<(Instant, T)>) -> Option<T> {
    v.filter(|(at, _)| at.elapsed() < STALE).map(|(_, v)| v)
}

impl VehicleView {
    /// The mean of the depth readings over the last [`DEPTH_MEAN`].
    fn depth_mean(&self) -> Option<f64> {
        let recent: Vec<f64> =
            self.depths.iter().filter(|(at, _)| at.elapsed() <= DEPTH_MEAN).map(|(_, z)| *z).collect();
        (!recent.is_empty()).then(|| recent.iter().sum::<f64>() / recent.len() as f64)
    }

    pub fn to_json(&self) -> Value {
        let ekf = self
            .ekf
            .as_ref()
            .map(|e| json!({"flags": e.flags, "not_ready": e.not_ready(), "position_measured": e.position_measured()}));
        let stop = self.stop.map(|s| {
            let after = |t: Option<Instant>| t.map(|t| t.saturating_duration_since(s.asked).as_secs_f64());
            json!({"ago_s": s.asked.elapsed().as_secs_f64(), "sent_after_s": after(s.sent),
                   "disarmed_after_s": after(s.disarmed)})
        });
        json!({
            "connected": self.connected,
            "error": self.error,
            "links_opened": self.links_opened,
            "system_id": self.system_id,
            "mode": self.mode,
            "armed": self.armed,
            "heartbeat_age_s": self.last_heartbeat.map(|t| t.elapsed().as_secs_f64()),
            "depth_m": fresh(self.depth),
            "depth_mean_1s_m": self.depth_mean(),
            "heading_deg": fresh(self.heading).map(|h: f64| h.to_degrees().rem_euclid(360.0)),
            "position_ne_m": fresh(self.position),
            "position_source": self.ekf.as_ref().is_some_and(EkfStatus::position_measured),
            "ekf": ekf,
            "stop": stop,
        })
    }
}

/// The autopilot's ground-station place a flight on Cockpit's joystick takes: where one was
/// killed before its stop (with the server, or the autopilot rebooting under it), the place
/// is still the flight's, and Cockpit's joystick ignored, until given back.
#[derive(Clone)]
pub struct LeftPlace {
    /// The flight's system id, and the ground station's.
    pub flight: u8,
    pub ground: u8,
    /// A flight running keeps its place.
    pub jobs: super::jobs::Jobs,
}

impl LeftPlace {
    fn give_back(&self, link: &mut crate::link::VehicleLink, autopilot: &Autopilot) {
        if self.jobs.running() {
            return;
        }
        let free = || !self.jobs.running();
        match give_back_left_place(link, autopilot, self.flight, self.ground, |_| {}, free) {
            Some(Ok(said)) => eprintln!("serve: {said}"),
            Some(Err(why)) => eprintln!("serve: {why}"),
            None => {}
        }
    }
}

/// The watcher's shared parts: the view and STOP's request.
#[derive(Clone, Default)]
pub struct Watcher {
    pub view: Arc<Mutex<VehicleView>>,
    stop: Arc<AtomicBool>,
}

impl Watcher {
    /// Neutral and a disarm from the server's link at once (its next 20 ms), repeated for 2 s.
    pub fn stop(&self) {
        self.view.lock().expect("view").stop = Some(StopRecord { asked: Instant::now(), sent: None, disarmed: None });
        self.stop.store(true, Ordering::Relaxed);
    }

    /// Keeps a link to `connect` open for ever (a thread): a new one after any error or
    /// silence, a second apart. Each new link first gives back the ground station's place a
    /// flight on the joystick left (`left`), while no flight runs.
    pub fn start(&self, connect: String, options: LinkOptions, left: LeftPlace) {
        let me = self.clone();
        std::thread::spawn(move || {
            loop {
                let reason = match open(&connect, &options, |_| {}) {
                    Ok((mut link, autopilot, assembler)) => {
                        left.give_back(&mut link, &autopilot);
                        me.watch(link, &autopilot, assembler)
                    }
                    Err(e) => e,
                };
                {
                    let mut v = me.view.lock().expect("view");
                    if v.connected {
                        eprintln!("serve: link to {connect} lost: {reason}; opening a new one");
                    }
                    v.connected = false;
                    v.error = Some(reason);
                }
                std::thread::sleep(Duration::from_secs(1));
            }
        });
    }

    /// Reads the autopilot until the link fails or goes quiet; why it ended.
    fn watch(
        &self,
        mut link: crate::link::VehicleLink,
        autopilot: &Autopilot,
        mut assembler: crate::link::StateAssembler,
    ) -> String {
        let rates = link
            .set_message_rate(EKF_STATUS_REPORT_ID, EKF_RATE_HZ)
            .and_then(|()| link.set_message_rate(HEARTBEAT_ID, HEARTBEAT_RATE_HZ));
        if let Err(e) = rates {
            return e.to_string();
        }
        {
            let mut v = self.view.lock().expect("view");
            v.connected = true;
            v.error = None;
            v.links_opened += 1;
            v.system_id = Some(autopilot.system_id);
            v.last_heartbeat = Some(Instant::now());
        }
        let mut stopping: Option<(Instant, Instant)> = None; // (first sent, last sent)
        loop {
            if self.stop.swap(false, Ordering::Relaxed) {
                stopping = None;
            }
            let due = match stopping {
                // A STOP asked while there was no link expires: no disarm minutes later.
                None => self
                    .view
                    .lock()
                    .expect("view")
                    .stop
                    .is_some_and(|s| s.sent.is_none() && s.asked.elapsed() < STOP_REPEAT),
                Some((first, last)) => first.elapsed() < STOP_REPEAT && last.elapsed() >= STOP_EVERY,
            };
            if due {
                // Neutral pilot axes (throttle 500 is neutral in ArduSub), then the disarm.
                let sent = link.manual_control(0, 0, 500, 0).and_then(|()| link.arm(false));
                let now = Instant::now();
                if let Err(e) = sent {
                    return format!("STOP could not be sent: {e}");
                }
                let first = stopping.map_or(now, |(first, _)| first);
                stopping = Some((first, now));
                let mut v = self.view.lock().expect("view");
                if let Some(s) = v.stop.as_mut() {
                    s.sent.get_or_insert(now);
                }
            }
            let r = match link.recv_timeout(Duration::from_millis(20)) {
                Ok(Some(r)) => r,
                Ok(None) => {
                    let quiet = self.view.lock().expect("view").last_heartbeat.is_none_or(|t| t.elapsed() > QUIET);
                    if quiet {
                        return format!("no heartbeat from the autopilot for {} s", QUIET.as_secs());
                    }
                    continue;
                }
                Err(e) => return e.to_string(),
            };
            if !autopilot.sent(&r) {
                continue;
            }
            // The depth sensor's own readings, as a flight's estimator takes them (with a position
            // source the state's depth is the autopilot's EKF's, on another density's scale).
            let mut measured_depth = None;
            let fresh = assembler.update(&r, |o| {
                if let Observation::Measured(Measurement::Depth { z, .. }) = o {
                    measured_depth = Some(z);
                }
            });
            let mut v = self.view.lock().expect("view");
            match &r.message {
                MavMessage::HEARTBEAT(h) if !is_ground_station(h) => {
                    let armed = Autopilot::armed(h);
                    v.last_heartbeat = Some(r.at);
                    v.armed = Some(armed);
                    v.mode = Some(SubMode::name_of(h.custom_mode));
                    if let Some(s) = v.stop.as_mut()
                        && s.sent.is_some()
                        && !armed
                    {
                        s.disarmed.get_or_insert(r.at);
                    }
                }
                MavMessage::EKF_STATUS_REPORT(e) => v.ekf = Some(EkfStatus::new(0.0, e)),
                _ => {}
            }
            if let Some(z) = measured_depth.filter(|z| z.is_finite()) {
                v.depths.push_back((r.at, z));
                while v.depths.front().is_some_and(|(at, _)| r.at.saturating_duration_since(*at) > DEPTH_MEAN) {
                    v.depths.pop_front();
                }
            }
            if let Some(state) = fresh {
                let [n, e, z, psi, ..] = state.sim;
                if z.is_finite() {
                    v.depth = Some((r.at, z));
                }
                if psi.is_finite() {
                    v.heading = Some((r.at, psi));
                }
                if n.is_finite() && e.is_finite() {
                    v.position = Some((r.at, [n, e]));
                }
            }
        }
    }
}
