//! One session's cycles, each in stages: what the autopilot measured and applied into the
//! estimator ([`Flight::observe`]), the estimate and the state to control on
//! ([`Flight::estimate`]), waiting until the autopilot and the estimate are ready
//! ([`Flight::wait_to_start`]), the command (pinc's MPC: [`Flight::mpc_cycle`]; the autopilot's
//! hold: [`Flight::hold_cycle`]), and the cycle's record ([`Flight::record`]).

use super::noise_window::NoiseWindow;
use super::targets::send_targets;
use super::truth::Truth;
use super::{AnyEstimator, AutopilotHold, EKF_STATUS_WAIT, Flyer, SessionOptions, Setup};
use crate::closed_loop::{Level, LogError, McapLog, Sample, Scenario};
use crate::estimation::mavlink::Observation;
use crate::estimation::{Estimate, Measurement, Navigation};
use crate::link::autopilot_estimate::HeadingReference;
use crate::link::drive::{Drive, Fresh, Note, Sent, Stopped};
use crate::link::link::{Autopilot, Received, SubMode};
use crate::link::safety::Trigger;
use crate::link::state::Capability;
use crate::mpc::CycleReport;
use crate::runtime::EnvelopeStatus;
use crate::traits::DiscreteModel;
use crate::types::{Input, NU, SimState};
use crate::vehicle::to_network;
use serde_json::{Value, json};
use std::cell::RefCell;
use std::time::{Duration, Instant};

/// How long (s) after the autopilot takes an integrated position source up again its
/// positions set the offset to pinc's dead reckoning rather than being fused, while its
/// estimate settles.
const RELATCH_S: f64 = 5.0;
/// The positioning sensor's own fixes navigate while the newest is at most this old (s, from
/// when it was measured: a 4 Hz USBL 0.5 s late is 0.5-0.75 s old); past it the autopilot's
/// position is the fallback.
const OWN_FIXES_FRESH_S: f64 = 3.0;
/// The least DVL velocity noise (m/s) taken from its readings: a still vehicle's readings can
/// look quieter than the sensor is.
const DVL_NOISE_FLOOR: f64 = 0.005;
/// With the sensor's own fixes control starts once they have navigated this long (s): the
/// point held is where the estimate puts the vehicle then, and its error then stays in every
/// figure after (beside a DVL: the station 0.095-0.128 m RMS after 10 s of fixes, 0.049-0.056 m after 20).
const FIXES_SETTLE_S: f64 = 20.0;
/// The process noise on the horizontal position (m per step) while navigating on the sensors'
/// own messages: the position is the integral of the velocity the model and the DVL give, with
/// little error of its own; the default (0.005) is for the autopilot's filtered position, and
/// beside a USBL's noisy fixes it let the estimate wander 5 cm (one standard deviation, per
/// axis) where 0.001 lets it wander 2-3.
const OWN_FIXES_POSITION_PROCESS_STD: f64 = 0.001;

/// What a session keeps as it flies: the log, the notes still to write, the samples and
/// every count the summary reports.
pub(super) struct Flight<'l> {
    pub(super) log: &'l mut McapLog,
    /// Raised (SIGUSR1) to end the flight by handing the vehicle back; whether it was.
    pub(super) hand_back: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    pub(super) handed_back: bool,
    pub(super) log_error: Option<LogError>,
    pub(super) notes: Vec<Note>,
    pub(super) hold: Option<AutopilotHold>,
    dt: f64,
    position_free: bool,
    wait_position: Duration,
    give_up: Duration,
    /// Input bounds, for the delivered-to-commanded ratios and the bound check.
    lo: Input,
    hi: Input,
    pub(super) samples: Vec<Sample>,
    waited: Instant,
    /// Autopilot time of the first cycle: the scenario's time 0.
    pub(super) t0: Option<f64>,
    horizontal_before: Option<bool>,
    /// The navigation's standing last cycle (its changes are said).
    navigation_before: Navigation,
    /// When a DVL's velocity (`VISION_POSITION_DELTA`) last came.
    pub(super) own_velocity_at: Option<f64>,
    /// DVL velocities fused (the autopilot's position not measured) and left out (it is: its
    /// position and velocity carry the same DVL already).
    pub(super) dvl_fused: u64,
    pub(super) dvl_left_out: u64,
    /// The positioning sensor's own fixes (`GPS_INPUT`, `GLOBAL_VISION_POSITION_ESTIMATE`:
    /// time measured, north, east, m) and the std the sensor stated for the newest.
    pub(super) fixes: NoiseWindow,
    pub(super) fix_std_stated: Option<f64>,
    /// The DVL's velocities (time, surge, sway, m/s).
    pub(super) dvl_velocities: NoiseWindow,
    /// The autopilot's positions and velocities left out while pinc navigates on the sensors'
    /// own messages (they carry the same fixes, filtered).
    pub(super) autopilot_left_out: u64,
    /// Since when (autopilot time, s) pinc navigates on the sensor's own fixes, and the
    /// position's process noise set before (restored when they stop).
    own_fixes_since: Option<f64>,
    /// The autopilot's origin changes seen so far (each one relatches its position).
    origin_changes_seen: u64,
    position_process_std: f64,
    /// Where the autopilot's integrated position (no absolute source) lies from pinc's: taken
    /// when the autopilot measures again after a loss, since it goes on from where its own
    /// dead reckoning froze. Its positions are fused less this.
    pub(super) autopilot_offset: [f64; 2],
    /// Until when (autopilot time, s) the offset is taken from each autopilot position rather
    /// than the position fused: the autopilot's estimate settles for a few seconds after it
    /// takes its source up again.
    relatch_until: Option<f64>,
    /// Autopilot positions the offset was taken from since it came back.
    relatched: u64,
    /// The autopilot has measured its position at least once this session.
    measured_once: bool,
    /// Each navigation change (scenario time s, `measured` / `dead_reckoning` / `lost`, the
    /// dead reckoning's added uncertainty m).
    pub(super) navigation_changes: Vec<(f64, &'static str, f64)>,
    /// The largest dead-reckoning uncertainty reached (m).
    pub(super) dead_reckoning_max: f64,
    pub(super) ages: Vec<f64>,
    pub(super) latencies: Vec<f64>,
    pub(super) estimates: Vec<Estimate>,
    pub(super) truths: Vec<Truth>,
    pub(super) truth_positions: Vec<super::truth::Position>,
    pub(super) control_after: Option<f64>,
    /// Per channel: sum of applied x asked, of asked^2, and the count (a least-squares gain of
    /// the outputs on the commands), and the last command with its autopilot time.
    pub(super) delivered: [(f64, f64, usize); NU],
    last_command: Option<(f64, Input)>,
    last_applied: Input,
    /// The autopilot's word on its own estimate: the reasons it is not ready (said once each),
    /// whether its position is measured, and the heading it reports.
    pub(super) not_ready_said: Vec<String>,
    position_measured_before: Option<bool>,
    pub(super) dead_reckoned: u64,
    /// The autopilot's vertical velocities taken (its reader counts those its EKF did not
    /// vouch for).
    pub(super) vertical_velocities: u64,
    pub(super) heading_reference: Option<HeadingReference>,
    hold_xy: (f64, f64),
    /// When the hold's mode was last asked for, and since when the autopilot is in it.
    mode_asked: Option<f64>,
    pub(super) mode_entered: Option<f64>,
    /// The raw depth sensor's reading at each cycle (autopilot time), against the truth.
    pub(super) raw_depths: Vec<(f64, f64)>,
    /// The autopilot's own position (`LOCAL_POSITION_NED`) at each cycle, while it measures
    /// one: `(scenario time, north, east)`, what both pinc and the autopilot's hold steer by.
    pub(super) raw_positions: Vec<(f64, f64, f64)>,
    pub(super) js_gain: f64,
    /// The scenario's horizontal plan (its zero: [`Flight::plan_offset`]).
    pub(super) plan: Option<crate::closed_loop::path_plan::HorizontalPlan>,
    /// Whether the horizontal goal is dropped (the position source lost), said when it changes.
    goal_dropped: bool,
    /// When the horizontal goal was dropped and taken up again (scenario time, s).
    pub(super) goal_changes: Vec<(f64, bool)>,
    max_distance: Option<f64>,
    dead_reckoning_bound: f64,
    stream_samples: bool,
    /// How much of the flight its figures keep (s), and the cycles let go before that (the log
    /// holds them) with their deadline misses.
    pub(super) history_s: f64,
    pub(super) forgotten_cycles: usize,
    pub(super) forgotten_deadline_misses: usize,
}

/// A flight keeps its last 5 minutes of cycles, estimates and truth for its figures by default
/// (`--history`); the log holds the whole flight. An hour of pilot assist so holds its memory
/// flat.
pub const DEFAULT_HISTORY_S: f64 = 300.0;

/// The state to control on, or why not yet.
pub(super) struct Estimated {
    estimate: Option<Estimate>,
    /// The horizontal estimate can be steered on: measured, or dead reckoned within the bound.
    horizontal: bool,
    navigation: Navigation,
    state: Option<SimState>,
}

impl<'l> Flight<'l> {
    pub(super) fn new<M>(setup: &Setup<M>, log: &'l mut McapLog) -> Self {
        Self {
            log,
            hand_back: None,
            handed_back: false,
            log_error: None,
            notes: Vec::new(),
            hold: setup.hold,
            dt: setup.dt,
            position_free: setup.position_free,
            wait_position: setup.wait_position,
            give_up: setup.give_up,
            lo: Input::repeat(f64::NEG_INFINITY),
            hi: Input::repeat(f64::INFINITY),
            samples: Vec::new(),
            waited: Instant::now(),
            t0: None,
            horizontal_before: None,
            navigation_before: Navigation::Lost,
            own_velocity_at: None,
            dvl_fused: 0,
            dvl_left_out: 0,
            fixes: NoiseWindow::default(),
            fix_std_stated: None,
            dvl_velocities: NoiseWindow::default(),
            autopilot_left_out: 0,
            own_fixes_since: None,
            origin_changes_seen: 0,
            position_process_std: 0.0,
            autopilot_offset: [0.0, 0.0],
            relatch_until: None,
            relatched: 0,
            measured_once: false,
            navigation_changes: Vec::new(),
            dead_reckoning_max: 0.0,
            ages: Vec::new(),
            latencies: Vec::new(),
            estimates: Vec::new(),
            truths: Vec::new(),
            truth_positions: Vec::new(),
            control_after: None,
            delivered: [(0.0, 0.0, 0); NU],
            last_command: None,
            last_applied: Input::zeros(),
            not_ready_said: Vec::new(),
            position_measured_before: None,
            dead_reckoned: 0,
            vertical_velocities: 0,
            heading_reference: None,
            hold_xy: (0.0, 0.0),
            mode_asked: None,
            mode_entered: None,
            raw_depths: Vec::new(),
            raw_positions: Vec::new(),
            js_gain: 1.0,
            plan: None,
            goal_dropped: false,
            goal_changes: Vec::new(),
            max_distance: setup.max_distance,
            dead_reckoning_bound: setup.dead_reckoning_bound,
            stream_samples: setup.stream_samples,
            history_s: setup.history_s,
            forgotten_cycles: 0,
            forgotten_deadline_misses: 0,
        }
    }

    /// Where control started in the autopilot's local frame (north, east).
    pub(super) fn hold_xy(&self) -> (f64, f64) {
        self.hold_xy
    }

    /// Where the plan's zero lies in the autopilot's local frame: the start's position for a
    /// plan measured from the start, the EKF origin's (zero) otherwise.
    pub(super) fn plan_offset(&self) -> [f64; 2] {
        use crate::closed_loop::path_plan::PathFrame;
        match self.plan.as_ref().map(|p| p.frame) {
            Some(PathFrame::Origin) => [0.0, 0.0],
            _ => [self.hold_xy.0, self.hold_xy.1],
        }
    }

    /// With a horizontal goal: past `--max-distance` from the start is a stop; a lost position
    /// source drops the goal (said, logged) until it comes back. Returns whether the goal is
    /// kept this cycle.
    fn horizontal_goal(&mut self, now: &Estimated, state: &SimState, t: f64, at: f64) -> Result<bool, Trigger> {
        if self.plan.is_none() {
            return Ok(false);
        }
        if let Some(limit) = self.max_distance
            && now.horizontal
        {
            let distance = (state[0] - self.hold_xy.0).hypot(state[1] - self.hold_xy.1);
            if distance > limit {
                return Err(Trigger::Distance { distance, limit });
            }
        }
        // The goal is kept while pinc's own estimate is measured or dead reckoned within its
        // bound (a GPS without its fix, a DVL that lost the bottom: the model and the current
        // estimated before carry the estimate); past the bound it is dropped.
        let dropped = !now.navigation.usable();
        self.say_navigation(now.navigation, t, at);
        if dropped != self.goal_dropped {
            let text = if dropped {
                format!(
                    "horizontal goal dropped at {t:.2} s: no position or velocity measured and dead reckoning past its \
                     bound ({:.2} m); holding depth and heading",
                    self.dead_reckoning_bound
                )
            } else {
                format!("horizontal goal taken up again at {t:.2} s: a position or velocity is fused")
            };
            eprintln!("{text}");
            let level = if dropped { Level::Warning } else { Level::Info };
            self.notes.push(Note { t: at, level, text, from_autopilot: false });
            self.goal_dropped = dropped;
            self.goal_changes.push((t, dropped));
        }
        Ok(!dropped)
    }

    /// Each change of the navigation's standing (measured, dead reckoning, lost) said in the
    /// terminal and the log, and kept for the summary with the dead reckoning's added spread.
    fn say_navigation(&mut self, navigation: Navigation, t: f64, at: f64) {
        if let Navigation::DeadReckoning { std, .. } = navigation {
            self.dead_reckoning_max = self.dead_reckoning_max.max(std);
        }
        if navigation.name() != self.navigation_before.name() && self.t0.is_some() {
            let std = match navigation {
                Navigation::DeadReckoning { std, .. } => std,
                _ => match self.navigation_before {
                    Navigation::DeadReckoning { std, .. } => std,
                    _ => 0.0,
                },
            };
            let text = match (navigation, self.navigation_before) {
                (Navigation::DeadReckoning { since, .. }, _) => format!(
                    "dead reckoning from {t:.2} s: nothing horizontal measured since {:.2} s; the goal is kept \
                     while the added uncertainty stays within {:.2} m",
                    since - self.t0.unwrap_or(0.0),
                    self.dead_reckoning_bound
                ),
                (Navigation::Measured, Navigation::DeadReckoning { .. }) => {
                    format!("navigation measured again at {t:.2} s after dead reckoning (added uncertainty {std:.2} m)")
                }
                (Navigation::Lost, Navigation::DeadReckoning { .. }) => format!(
                    "dead reckoning past its bound at {t:.2} s ({:.2} m of added uncertainty)",
                    self.dead_reckoning_bound
                ),
                (n, _) => format!("navigation {} at {t:.2} s", n.name()),
            };
            eprintln!("{text}");
            let level = if navigation.usable() { Level::Info } else { Level::Warning };
            self.notes.push(Note { t: at, level, text, from_autopilot: false });
            self.navigation_changes.push((t, navigation.name(), std));
        }
        self.navigation_before = navigation;
    }

    /// A log line at autopilot time `at` (on the scenario's clock once it started); the first
    /// write error is kept and the session goes on.
    pub(super) fn log_line(&mut self, at: f64, level: Level, text: &str) {
        let t = self.t0.map_or(0.0, |s| (at - s).max(0.0));
        self.log_error = self.log_error.take().or(self.log.log(t, level, text).err());
    }

    /// `text` in the terminal and, at autopilot time `at`, the log.
    fn say(&mut self, at: f64, level: Level, text: String) {
        eprintln!("{text}");
        self.notes.push(Note { t: at, level, text, from_autopilot: false });
    }

    /// The notes gathered so far, into the log.
    pub(super) fn write_notes(&mut self) {
        for n in std::mem::take(&mut self.notes) {
            self.log_line(n.t, n.level, &n.text);
        }
    }

    /// The session's first lines: who flies, on which estimate, under which limits, and the
    /// fit report's warnings of a fitted model.
    pub(super) fn say_start<M>(&mut self, o: &SessionOptions, setup: &Setup<M>, autopilot: &Autopilot) {
        let estimator_line = if o.estimator.no_estimator {
            "no state estimator (the raw state; body velocities from the autopilot's EKF)".to_string()
        } else {
            format!(
                "state estimator on the {} model (depth std {} m, heading std {} rad, position std {} m)",
                o.estimator.estimator_model, setup.noise.depth_std, setup.noise.heading_std, setup.noise.position_std
            )
        };
        let flown_by = match setup.hold {
            Some(h) => format!("the autopilot's own {} flies the references", h.name()),
            None => format!("pinc's MPC flies the references, commands by {}", setup.commander.way().name()),
        };
        let line = format!(
            "live vehicle on {} (system {}), {flown_by}; {estimator_line}; {}",
            o.connect,
            autopilot.system_id,
            setup.settings.limits.describe()
        );
        self.log_line(0.0, Level::Info, &line);
        // A fitted model whose report failed flies, but says why it may fly badly first.
        for w in o.fitted.map_or(&[][..], |f| &f.warnings[..]) {
            let line = format!("the model's fit report failed: {w}");
            eprintln!("warning: {line}");
            self.log_line(0.0, Level::Warning, &line);
        }
    }

    /// The drive could not start (arming refused, the link): said, and nothing flown.
    pub(super) fn refused(mut self, mut stopped: Stopped) -> super::LiveRun {
        self.notes.append(&mut stopped.notes);
        self.write_notes();
        let reason = stopped.trigger.map_or_else(|| "stopped".to_string(), |t| t.to_string());
        self.log_line(0.0, Level::Error, &reason);
        eprintln!("{reason}");
        super::LiveRun {
            samples: Vec::new(),
            log_error: self.log_error,
            stopped: Some(reason),
            live: None,
            navigation: None,
        }
    }

    /// The cycles, from the first fresh state to the scenario's end or a stop.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn fly<M: DiscreteModel + Clone>(
        &mut self,
        drive: &mut Drive,
        estimator: &mut AnyEstimator<M>,
        flyer: &mut Flyer<M>,
        scenario: &Scenario,
        mut pilot: Option<&mut super::pilot_feed::PilotFeed>,
        o: &SessionOptions,
        truths: &RefCell<super::truth::Feed>,
        mut seen: impl FnMut(&Received, f64),
    ) -> Result<(), Trigger> {
        self.js_gain = drive.commander().js_gain();
        if let Flyer::Mpc(mpc) = &*flyer {
            (self.lo, self.hi) = mpc.bounds();
        }
        let n = match &*flyer {
            Flyer::Mpc(mpc) => mpc.config().horizon,
            Flyer::Autopilot { .. } => 1,
        };
        let mut refs = vec![scenario.reference(0.0); n];
        self.plan = scenario.horizontal.clone();
        // A four-axis controller's stand-in while the position source is lost: the same model
        // and settings on depth and heading alone (no steering on a dead-reckoned position).
        let mut depth_heading = match &*flyer {
            Flyer::Mpc(mpc) if mpc.config().tracks_position() => {
                let cfg = crate::mpc::MpcConfig { position: 0.0, ..mpc.config().clone() };
                Some(crate::mpc::Mpc::new(mpc.model().clone(), cfg).map_err(|e| Trigger::Error(e.to_string()))?)
            }
            _ => None,
        };
        // A scenario held from where control starts ("hold here"), once it has started.
        let given = scenario;
        let mut started: Option<Scenario> = None;
        loop {
            let fresh = drive.next_state(&mut seen)?;
            self.notes.extend(drive.take_notes());
            self.observe(drive, estimator, fresh.state.t);
            let now = self.estimate(estimator, &fresh, o)?;
            if self.hand_back.as_ref().is_some_and(|f| f.load(std::sync::atomic::Ordering::Relaxed)) {
                self.handed_back = true;
                self.say(fresh.state.t, Level::Info, "asked to hand the vehicle back: the flight ends".into());
                return Ok(());
            }
            let start = match self.t0 {
                Some(s) => s,
                None => match self.wait_to_start(drive, estimator, &fresh, &now, o)? {
                    Some(s) => s,
                    None => continue,
                },
            };
            self.write_notes();
            let Some(state) = now.state else {
                let why = if o.estimator.no_estimator {
                    format!("the raw state lost a part: {}", fresh.state.capability)
                } else {
                    "the state estimate stopped (a gap in the measurements longer than 2 s)".to_string()
                };
                return Err(Trigger::Error(why));
            };
            if given.from_start && started.is_none() {
                started = Some(self.hold_from_press(given, &state, o, fresh.state.t));
            }
            let scenario = started.as_ref().unwrap_or(given);
            // An estimate that no longer follows what the vehicle measures steers a vehicle it
            // has lost: stop.
            if let Some(lost) = each!(&*estimator, tr => tr.ekf().health().lost()) {
                return Err(Trigger::EstimateLost(lost.to_string()));
            }
            let t = fresh.state.t - start;
            if t >= scenario.duration() - 1e-9 {
                return Ok(());
            }
            let goal = self.horizontal_goal(&now, &state, t, fresh.state.t)?;
            let offset = self.plan_offset();
            let mut reference = scenario.reference_from(t, offset);
            if let Some(feed) = pilot.as_deref_mut() {
                for said in feed.take_readings(t) {
                    self.say(fresh.state.t, Level::Warning, said);
                }
            }
            let (cycle, prediction, sent) = match flyer {
                Flyer::Mpc(mpc) => {
                    if let Some(feed) = pilot.as_deref_mut() {
                        let changes = feed.assist.changes().len();
                        reference = feed.assist.references(t, &to_network(&state), goal, self.dt, &mut refs);
                        for c in &feed.assist.changes()[changes..] {
                            let text = format!(
                                "pilot: {} {:?} at {:.2} s ({:.3}, {:.3})",
                                c.axis, c.phase, c.t, c.at[0], c.at[1]
                            );
                            self.say(fresh.state.t, Level::Info, text);
                        }
                    } else {
                        for (j, r) in refs.iter_mut().enumerate() {
                            *r = scenario.reference_from(t + (j + 1) as f64 * self.dt, offset);
                            if !goal {
                                r.horizontal = None;
                            }
                        }
                    }
                    let mpc = match (&mut depth_heading, goal) {
                        (Some(dh), false) => dh,
                        _ => &mut **mpc,
                    };
                    self.mpc_cycle(drive, estimator, mpc, &fresh, &state, &refs)?
                }
                Flyer::Autopilot { hold, .. } => {
                    let sticks = pilot.as_deref().map(|feed| feed.assist.commanded(t));
                    self.hold_cycle(drive, estimator, *hold, &fresh, scenario, (t, offset), sticks)?
                }
            };
            self.record(
                &fresh,
                &sent,
                &now,
                estimator,
                truths,
                Sample { t, state, reference, cycle, prediction, bound_violation: false },
            );
        }
    }

    /// A scenario held from where it starts, as flown: from where "hold here" was pressed
    /// (`--hold-at`), else from the state where control starts; said in the log.
    fn hold_from_press(&mut self, given: &Scenario, state: &SimState, o: &SessionOptions, at: f64) -> Scenario {
        let (depth, heading) = o.hold_at.map_or((state[2], state[3]), |h| (h.depth, h.heading));
        let at_press = o.hold_at.and_then(|h| h.north_east);
        if let Some(p) = at_press {
            self.hold_xy = p;
        }
        let text = format!(
            "holding {}: depth {depth:.2} m, heading {:.1} deg{}",
            if o.hold_at.is_some() { "where it was pressed" } else { "here" },
            heading.to_degrees().rem_euclid(360.0),
            match (&self.plan, at_press) {
                (None, _) => String::new(),
                (Some(_), Some((n, e))) => format!(", north {n:.2} m, east {e:.2} m"),
                (Some(_), None) => ", the position where control started".into(),
            }
        );
        self.say(at, Level::Info, text);
        given.started_at(depth, heading)
    }

    /// What the autopilot measured and applied since the last cycle, into the estimator: a
    /// position it does not measure (lost, dead-reckoned or held) is left out, and the outputs
    /// are set against what pinc asked.
    fn observe<M: DiscreteModel>(&mut self, drive: &mut Drive, estimator: &mut AnyEstimator<M>, t: f64) {
        let position_measured = drive.position_measured();
        if self.position_measured_before.is_some_and(|b| b != position_measured) {
            self.notes.push(Note {
                t,
                level: if position_measured { Level::Info } else { Level::Warning },
                text: if position_measured {
                    "the autopilot measures its position again (EKF_STATUS_REPORT): its position is fused".into()
                } else {
                    "the autopilot no longer measures its position (its GPS lost the fix, or EKF_STATUS_REPORT \
                     says dead reckoning or held): LOCAL_POSITION_NED is no longer fused"
                        .into()
                },
                from_autopilot: false,
            });
        }
        // An integrated position (no absolute source: a DVL's EKF) that comes back after a loss
        // (measured again, not for the first time) goes on from where the autopilot's dead
        // reckoning froze, metres off: pinc's own dead reckoning is kept and the autopilot's
        // position taken from there (an absolute one, a GPS, is taken as it is).
        let returned = position_measured && self.position_measured_before == Some(false) && self.measured_once;
        self.measured_once |= position_measured;
        if returned && drive.position_integrated() && each!(&*estimator, tr => tr.navigation(t)).usable() {
            self.relatch_until = Some(t + RELATCH_S);
        }
        // The autopilot's frame moved (its origin said again elsewhere) while its position is
        // fused: its positions set the offset again rather than move the vehicle.
        let origin_changes = drive.assembler().reader().origin_changes();
        if origin_changes > self.origin_changes_seen && position_measured && self.t0.is_some() {
            self.relatch_until = Some(t + RELATCH_S);
            self.say(t, Level::Warning, format!(
                "the autopilot's EKF origin changed at {t:.2} s: its positions are taken from pinc's estimate on (the \
                 point held stays over the ground)"
            ));
        }
        self.origin_changes_seen = origin_changes;
        self.position_measured_before = Some(position_measured);
        let own_fixes = self.own_fixes_now(drive, estimator, t);
        let relatching = self.relatch_until.is_some_and(|until| t < until);
        let vertical_velocity_valid = drive.assembler().reader().vertical_velocity_valid();
        let observations: Vec<Observation> = drive.drain_observations().collect();
        for mut ob in observations {
            match ob {
                // A DVL's own velocities: what pinc dead reckons on while the autopilot's
                // position is not measured; beside a measured one they are in it already.
                Observation::Measured(Measurement::VelocityBody { t, u, v, .. }) => {
                    self.own_velocity_at = Some(t);
                    // Fused or in the autopilot's position and velocity, a DVL measures the
                    // velocity over the ground: the current is observed directly.
                    each!(&mut *estimator, tr => tr.ground_velocity_measured());
                    // The DVL's noise, measured on its own readings (the filter's default is a
                    // guess): taken by the estimator as it is measured.
                    if let Some(noise) = self.dvl_velocities.push(t, u, v) {
                        each!(&mut *estimator, tr => tr.set_velocity_body_std(noise.max(DVL_NOISE_FLOOR)));
                    }
                    if position_measured && !relatching && !own_fixes {
                        self.dvl_left_out += 1;
                        continue;
                    }
                    self.dvl_fused += 1;
                }
                Observation::Measured(Measurement::Fix { t, x, y, std }) => {
                    self.fixes.push(t, x, y);
                    self.fix_std_stated = std.is_finite().then_some(std);
                    // A sensor that states no accuracy: the noise measured on its fixes so far.
                    if let (false, Some(measured)) = (std.is_finite(), self.fixes.noise()) {
                        ob = Observation::Measured(Measurement::Fix { t, x, y, std: measured });
                    }
                }
                Observation::Measured(Measurement::Position { .. } | Measurement::VelocityNed { .. }) if own_fixes => {
                    self.autopilot_left_out += 1;
                    if let Observation::Measured(Measurement::VelocityNed { t, vd, .. }) = ob
                        && vertical_velocity_valid
                    {
                        self.vertical_velocities += 1;
                        ob = Observation::Measured(Measurement::VerticalVelocity { t, vd });
                    } else {
                        continue;
                    }
                }
                Observation::Measured(Measurement::Position { t, x, y, z }) if position_measured => {
                    if relatching {
                        let s = each!(&*estimator, tr => *tr.ekf().state());
                        self.autopilot_offset = [x - s[0], y - s[1]];
                        self.relatched += 1;
                        continue;
                    }
                    if std::mem::take(&mut self.relatched) > 0 {
                        self.notes.push(Note {
                            t,
                            level: Level::Info,
                            text: format!(
                                "the autopilot's position came back {:.2} m north and {:.2} m east of pinc's dead \
                                 reckoning (it goes on from where its own froze): fused less that from {t:.2} s",
                                self.autopilot_offset[0], self.autopilot_offset[1]
                            ),
                            from_autopilot: false,
                        });
                    }
                    let [dn, de] = self.autopilot_offset;
                    ob = Observation::Measured(Measurement::Position { t, x: x - dn, y: y - de, z });
                }
                // A dead-reckoned position's vertical velocity is still the EKF's estimate from
                // its accelerometers and depth: that part is kept.
                Observation::Measured(Measurement::VelocityNed { t, vd, .. })
                    if !position_measured && vertical_velocity_valid =>
                {
                    self.dead_reckoned += 1;
                    self.vertical_velocities += 1;
                    ob = Observation::Measured(Measurement::VerticalVelocity { t, vd });
                }
                Observation::Measured(Measurement::Position { .. } | Measurement::VelocityNed { .. })
                    if !position_measured =>
                {
                    self.dead_reckoned += 1;
                    continue;
                }
                Observation::Measured(Measurement::VerticalVelocity { .. }) => self.vertical_velocities += 1,
                Observation::Applied(t, applied) => self.applied(t, applied),
                _ => {}
            }
            each!(&mut *estimator, tr => match ob {
                Observation::Measured(m) => tr.measure(m),
                Observation::Applied(t, u) => tr.applied(t, u),
                Observation::Unfused(_) => {}
            });
        }
    }

    /// Whether pinc navigates on the positioning sensor's own fixes at `t`; taking them up and
    /// leaving them are said, and set the estimator for them.
    fn own_fixes_now<M: DiscreteModel>(&mut self, drive: &Drive, estimator: &mut AnyEstimator<M>, t: f64) -> bool {
        // With the positioning sensor's own fixes pinc navigates on its sensors: the fixes,
        // the DVL's velocities, the model. The autopilot's position (the same fixes through its
        // EKF, which cannot take a 0.5 s latency and jumps when it takes the fixes up) is the
        // fallback for when they stop.
        let own_fixes = self.fixes.newest().is_some_and(|f| t - f <= OWN_FIXES_FRESH_S);
        match (own_fixes, self.own_fixes_since) {
            (true, None) => {
                self.own_fixes_since = Some(t);
                // The fixes' frame need not be the estimate's (an origin set late or by hand, a
                // topside GPS's error): the filter estimates the offset between them, and the
                // estimate, and the point held, stay where they are (docs/MODEL.md section 15).
                self.position_process_std = each!(&*estimator, tr => tr.position_process_std());
                each!(&mut *estimator, tr => tr.set_position_process_std(OWN_FIXES_POSITION_PROCESS_STD));
                self.notes.push(Note {
                    t,
                    level: Level::Info,
                    text: format!(
                        "navigating on the positioning sensor's own fixes from {t:.2} s (their latency {:.2} s): the \
                         autopilot's position is left out while they come",
                        drive.assembler().reader().fix_latency()
                    ),
                    from_autopilot: false,
                });
            }
            (false, Some(_)) => {
                self.own_fixes_since = None;
                // The autopilot's position, in its own frame, is taken from pinc's estimate on:
                // the fixes' frame and the autopilot's need not agree (its origin set elsewhere).
                self.relatch_until = Some(t + RELATCH_S);
                each!(&mut *estimator, tr => tr.set_position_process_std(self.position_process_std));
                self.notes.push(Note {
                    t,
                    level: Level::Warning,
                    text: format!(
                        "the positioning sensor's fixes stopped ({OWN_FIXES_FRESH_S} s without one): the autopilot's \
                         position is fused again where it measures one"
                    ),
                    from_autopilot: false,
                });
            }
            _ => {}
        }
        own_fixes
    }

    /// The outputs the autopilot reports against what pinc asked for, once the command has
    /// had time to reach them (half a sample).
    fn applied(&mut self, t: f64, applied: Input) {
        self.last_applied = applied;
        if let Some((sent_t, asked)) = self.last_command
            && t > sent_t + 0.5 * self.dt
        {
            for j in 0..NU {
                if asked[j].abs() > 0.05 * (self.hi[j] - self.lo[j]).abs() {
                    self.delivered[j].0 += applied[j] * asked[j];
                    self.delivered[j].1 += asked[j] * asked[j];
                    self.delivered[j].2 += 1;
                }
            }
        }
    }

    /// The estimate at the fresh state's time, whether a position source is fused (said when
    /// that changes), and the state the controller runs on: the estimate, or without one the
    /// raw full state.
    fn estimate<M: DiscreteModel>(
        &mut self,
        estimator: &mut AnyEstimator<M>,
        fresh: &Fresh,
        o: &SessionOptions,
    ) -> Result<Estimated, Trigger> {
        let estimate = if o.estimator.no_estimator {
            None
        } else {
            each!(&mut *estimator, tr => tr.advance(fresh.state.t))
                .map_err(|e| Trigger::Error(format!("state estimator: {e}")))?
        };
        let observed = each!(&*estimator, tr => tr.horizontal_observed(fresh.state.t));
        let navigation = each!(&*estimator, tr => tr.navigation(fresh.state.t));
        if self.horizontal_before.is_some_and(|b| b != observed) || (observed && self.horizontal_before.is_none()) {
            let text = if observed {
                "position source present: position and velocity fused into the estimate"
            } else {
                "position source lost: running on the estimate (depth, heading, yaw rate and the model)"
            };
            let level = if observed { Level::Info } else { Level::Warning };
            self.notes.push(Note { t: fresh.state.t, level, text: text.into(), from_autopilot: false });
        }
        self.horizontal_before = Some(observed);
        // Steered on: measured, or dead reckoned within the bound (the estimate's, so not on
        // the raw state).
        let horizontal = navigation.usable() && !o.estimator.no_estimator || observed;
        let state = match (&estimate, o.estimator.no_estimator) {
            (Some(e), _) if horizontal || self.position_free => Some(e.sim),
            (None, true) if fresh.state.capability == Capability::Full => Some(SimState::from(fresh.state.sim)),
            _ => None,
        };
        Ok(Estimated { estimate, horizontal, navigation, state })
    }

    /// Before the first cycle: neutral while the autopilot's estimate is not usable, the state
    /// estimate has not started or (`--wait-position`) no position source came; a stop once
    /// that lasts too long. `Some(t0)` once control starts (the reasons said, the heading's
    /// reference said and logged), `None` to wait another sample.
    fn wait_to_start<M: DiscreteModel>(
        &mut self,
        drive: &mut Drive,
        estimator: &mut AnyEstimator<M>,
        fresh: &Fresh,
        now: &Estimated,
        o: &SessionOptions,
    ) -> Result<Option<f64>, Trigger> {
        // The autopilot's own estimate first: attitude and heading usable.
        let not_ready: Vec<String> = match drive.ekf_status() {
            Some(s) => s.not_ready(),
            None if self.waited.elapsed() < EKF_STATUS_WAIT => {
                vec!["no EKF_STATUS_REPORT from the autopilot yet".to_string()]
            }
            None => Vec::new(),
        };
        for why in &not_ready {
            if !self.not_ready_said.contains(why) {
                let text = format!("waiting for the autopilot: {why}");
                eprintln!("{text}");
                self.notes.push(Note { t: fresh.state.t, level: Level::Warning, text, from_autopilot: false });
                self.not_ready_said.push(why.clone());
            }
        }
        // With the sensor's own fixes, until they settled the estimate; with the autopilot's
        // hold, until the autopilot measures its own position (its controller steers by it).
        let unsettled = self.own_fixes_since.is_some_and(|since| fresh.state.t - since < FIXES_SETTLE_S);
        let autopilot_unplaced = self.hold.is_some() && !drive.position_ready_for_its_hold();
        let waiting_for_position =
            (!now.horizontal || unsettled || autopilot_unplaced) && self.waited.elapsed() < self.wait_position;
        if now.state.is_none() || waiting_for_position || !not_ready.is_empty() {
            if self.waited.elapsed() > self.give_up && (now.state.is_none() || !not_ready.is_empty()) {
                return Err(self.gave_up(&not_ready, fresh, o));
            }
            drive.send_neutral(fresh)?;
            each!(&mut *estimator, tr => tr.commanded(Input::zeros()));
            return Ok(None);
        }
        if self.not_ready_said.is_empty() && drive.ekf_status().is_none() {
            self.notes.push(Note {
                t: fresh.state.t,
                level: Level::Warning,
                text: "the autopilot sent no EKF_STATUS_REPORT: its estimate's health is unknown".into(),
                from_autopilot: false,
            });
        }
        let reference = HeadingReference::of(drive.params(), drive.ekf_status().is_some_and(|s| s.absolute_position()));
        let level = if reference == HeadingReference::Magnetic { Level::Warning } else { Level::Info };
        if level == Level::Warning {
            eprintln!("{}", reference.describe());
        }
        self.notes.push(Note { t: fresh.state.t, level, text: reference.describe(), from_autopilot: false });
        self.heading_reference = Some(reference);
        let text = format!(
            "control starts {:.1} s after arming, on the {}{}",
            self.waited.elapsed().as_secs_f64(),
            if now.estimate.is_some() { "state estimate" } else { "raw state" },
            if now.horizontal { " with a position source" } else { " without a position source (depth and heading)" }
        );
        self.say(fresh.state.t, Level::Info, text);
        self.control_after = Some(self.waited.elapsed().as_secs_f64());
        if let Some(s) = &now.state {
            self.hold_xy = (s[0], s[1]);
        }
        // The autopilot's hold steers by its own position: the point is where that puts the
        // vehicle (pinc's estimate, on the sensors' own fixes, may lie elsewhere).
        if self.hold.is_some() && fresh.state.capability == Capability::Full {
            self.hold_xy = (fresh.state.sim[0], fresh.state.sim[1]);
        }
        Ok(Some(*self.t0.insert(fresh.state.t)))
    }

    /// Why the wait for a state to control on ended the session.
    fn gave_up(&self, not_ready: &[String], fresh: &Fresh, o: &SessionOptions) -> Trigger {
        let waited = self.waited.elapsed().as_secs_f64();
        if !not_ready.is_empty() {
            return Trigger::NotReady(format!(
                "the autopilot's estimate was not usable after {waited:.0} s: {}",
                not_ready.join("; ")
            ));
        }
        let why = if o.estimator.no_estimator {
            format!(
                "no full state: {}; the estimator (on by default) needs only depth and heading",
                fresh.state.capability
            )
        } else if !self.position_free {
            "the model needs x, y (it is not position-free) and no position source came".to_string()
        } else {
            format!("the state estimate did not start: {}", fresh.state.capability)
        };
        Trigger::Error(format!("no state to control on after {waited:.0} s: {why}"))
    }

    /// pinc's MPC: one solve on the state, its input sent, what was asked told to the
    /// estimator.
    fn mpc_cycle<M: DiscreteModel + Clone>(
        &mut self,
        drive: &mut Drive,
        estimator: &mut AnyEstimator<M>,
        mpc: &mut crate::mpc::Mpc<M>,
        fresh: &Fresh,
        state: &SimState,
        refs: &[crate::mpc::Reference],
    ) -> Result<(CycleReport, Vec<crate::State>, Sent), Trigger> {
        let cycle = mpc.step(&to_network(state), refs);
        let sent = drive.send(fresh, &cycle.input)?;
        let asked = drive.commander().input_of(&sent.command);
        each!(&mut *estimator, tr => tr.commanded(asked));
        self.last_command = Some((sent.autopilot_t, asked));
        Ok((cycle, mpc.prediction().to_vec(), sent))
    }

    /// The autopilot's own hold: into its mode (asked again every half second until the
    /// heartbeat says so; a refusal after 3 s), the cycle's targets and neutral pilot axes (they
    /// keep the pilot-input failsafe quiet), or the pilot's `sticks` alone as its pilot axes,
    /// and the outputs it applied as the cycle's input.
    #[allow(clippy::too_many_arguments)]
    fn hold_cycle<M: DiscreteModel>(
        &mut self,
        drive: &mut Drive,
        estimator: &mut AnyEstimator<M>,
        hold: AutopilotHold,
        fresh: &Fresh,
        scenario: &Scenario,
        (t, offset): (f64, [f64; 2]),
        sticks: Option<crate::pilot::Sticks>,
    ) -> Result<(CycleReport, Vec<crate::State>, Sent), Trigger> {
        if drive.mode() == hold.mode() as u32 {
            self.mode_entered.get_or_insert(t);
        } else if self.mode_entered.is_some() {
            return Err(Trigger::Refused(format!(
                "the autopilot left {} for mode {} (the pilot or a failsafe)",
                hold.name(),
                SubMode::name_of(drive.mode())
            )));
        } else if t > 3.0 {
            return Err(Trigger::Refused(format!(
                "the autopilot did not enter {} within 3 s (still in {}){}",
                hold.name(),
                SubMode::name_of(drive.mode()),
                if hold == AutopilotHold::AltHold { "" } else { "; it needs a position source" }
            )));
        } else if self.mode_asked.is_none_or(|m| t - m >= 0.5) {
            drive.link().set_mode(hold.mode()).map_err(|e| Trigger::Link(e.to_string()))?;
            self.mode_asked = Some(t);
        }
        let (next, now) = (scenario.reference_from(t + self.dt, offset), scenario.reference(t));
        let rate = (next.depth - now.depth) / self.dt;
        let boot_ms = (fresh.state.t * 1e3).round() as u32;
        // The plan's point and velocity, or the start held.
        let horizontal =
            next.horizontal.unwrap_or_else(|| crate::mpc::Horizontal::hold(self.hold_xy.0, self.hold_xy.1));
        let sent = match sticks {
            Some(sticks) => drive.send_sticks(fresh, sticks)?,
            None => {
                send_targets(drive, hold, boot_ms, (next.depth, next.heading), rate, horizontal)?;
                drive.send_neutral(fresh)?
            }
        };
        let applied = self.last_applied;
        each!(&mut *estimator, tr => tr.commanded(applied));
        let cycle = CycleReport {
            input: applied,
            saturated: [false; NU],
            fallback: None,
            envelope: EnvelopeStatus::default(),
            status: clarabel::solver::SolverStatus::Unsolved,
            iterations: 0,
            objective: 0.0,
            linearise_us: 0.0,
            update_us: 0.0,
            solve_us: 0.0,
            cycle_us: 0.0,
            deadline_missed: false,
        };
        Ok((cycle, Vec::new(), sent))
    }

    /// The cycle into the log and the summary's counts: the state's age when its command went
    /// out and the arrival-to-send latency, the raw depth, the truth, the estimate, the sample.
    fn record<M: DiscreteModel>(
        &mut self,
        fresh: &Fresh,
        sent: &Sent,
        now: &Estimated,
        estimator: &AnyEstimator<M>,
        truths: &RefCell<super::truth::Feed>,
        mut sample: Sample,
    ) {
        let (t, start) = (sample.t, self.t0.expect("recorded after the start"));
        let u = sample.cycle.input;
        sample.bound_violation = (0..NU).any(|j| !(u[j] >= self.lo[j] - 1e-9 && u[j] <= self.hi[j] + 1e-9));
        let state_age = sent.autopilot_t - fresh.state.t;
        let latency = sent.at.saturating_duration_since(fresh.arrived).as_secs_f64();
        self.ages.push(state_age);
        self.latencies.push(latency);
        if fresh.state.sim[2].is_finite() {
            self.raw_depths.push((fresh.state.t, fresh.state.sim[2]));
        }
        let (n, e) = (fresh.state.sim[0], fresh.state.sim[1]);
        // The autopilot's position as pinc steered by it: while a horizontal source is measured.
        if now.navigation == Navigation::Measured && n.is_finite() && e.is_finite() {
            self.raw_positions.push((t, n, e));
        }
        if self.log_error.is_none() {
            self.log_error = self.log.link_cycle(t, state_age, latency, sent.autopilot_t).err();
        }
        for p in truths.borrow_mut().positions.drain(..) {
            // Metres from the first true position, for plots; the figures take their own origin.
            let first = *self.truth_positions.first().unwrap_or(&p);
            let (n, e) = p.north_east_from(&first);
            if self.log_error.is_none() {
                let m = json!({"t_autopilot_s": p.t, "north_m": n, "east_m": e, "lat_e7": p.lat_lon.0, "lon_e7": p.lat_lon.1});
                self.log_error =
                    self.log.live("/truth/position", "pinc.SimulatorPosition", (p.t - start).max(0.0), m).err();
            }
            self.truth_positions.push(p);
        }
        for tr in truths.borrow_mut().states.drain(..) {
            if self.log_error.is_none() {
                let m = json!({"t_autopilot_s": tr.t, "z": tr.z, "psi": tr.psi, "u": tr.uvw[0], "v": tr.uvw[1], "w": tr.uvw[2], "r": tr.r});
                self.log_error = self.log.live("/truth", "pinc.SimulatorTruth", (tr.t - start).max(0.0), m).err();
            }
            self.truths.push(tr);
        }
        if let Some(e) = &now.estimate {
            self.estimates.push(*e);
            let raw: Vec<Option<f64>> = fresh.state.named().map(|(_, v)| v).collect();
            let scale = each!(estimator, tr => tr.ekf().process_scale());
            let m = json!({
                "t_autopilot_s": e.t, "estimate": e.sim.as_slice(), "std": e.std,
                "disturbance": e.disturbance.as_slice(), "disturbance_std": e.disturbance_std, "raw": raw,
                "position_source": now.horizontal, "navigation": now.navigation, "process_noise_scale": scale, "heave_gain": e.heave_gain.0,
            });
            if self.log_error.is_none() {
                self.log_error = self.log.live("/estimate", "pinc.Estimate", t, m).err();
            }
        }
        if self.log_error.is_none() {
            self.log_error = self.log.record(&sample).err();
        }
        if self.stream_samples {
            stream_line(&sample, &self.navigation_line(now, estimator));
        }
        // The prediction is in the log; the figures never read it again (20 states a cycle).
        sample.prediction = Vec::new();
        self.samples.push(sample);
        self.forget_before(t - self.history_s);
    }

    /// Lets go of what came before scenario time `cut`, a tenth of the history at a time. The truth's
    /// positions up to the start stay: the figures measure from there.
    fn forget_before(&mut self, cut: f64) {
        if self.samples.first().is_none_or(|s| s.t >= cut - 0.1 * self.history_s) {
            return;
        }
        let start = self.t0.unwrap_or(0.0);
        let n = self.samples.partition_point(|s| s.t < cut);
        self.forgotten_cycles += n;
        self.forgotten_deadline_misses += self.samples[..n].iter().filter(|s| s.cycle.deadline_missed).count();
        self.samples.drain(..n);
        // One of each per recorded cycle, as the samples.
        self.ages.drain(..n.min(self.ages.len()));
        self.latencies.drain(..n.min(self.latencies.len()));
        let at = start + cut;
        fn drain_before<T>(v: &mut Vec<T>, before: impl Fn(&T) -> bool) {
            let n = v.partition_point(before);
            v.drain(..n);
        }
        drain_before(&mut self.estimates, |e| e.t < at);
        drain_before(&mut self.truths, |tr| tr.t < at);
        drain_before(&mut self.raw_depths, |d| d.0 < at);
        drain_before(&mut self.raw_positions, |p| p.0 < cut);
        let head = self.truth_positions.partition_point(|p| p.t <= start + 1.0);
        let upto = self.truth_positions.partition_point(|p| p.t < at);
        if upto > head {
            self.truth_positions.drain(head..upto);
        }
    }
}

impl Flight<'_> {
    /// The navigation this cycle, for the line each cycle streams (the page shows it): its
    /// standing, the position's uncertainty, and what each horizontal source gave so far, used
    /// or left out (the filter's gate counts apart from the sources' own).
    fn navigation_line<M: DiscreteModel>(&self, now: &Estimated, estimator: &AnyEstimator<M>) -> Value {
        use crate::estimation::Sensor;
        let std = each!(estimator, tr => tr.horizontal_std());
        let (position, velocity) = each!(estimator, tr => {
            let h = tr.ekf().health();
            (*h.sensor(Sensor::Position), *h.sensor(Sensor::Velocity))
        });
        let added = match now.navigation {
            Navigation::DeadReckoning { std, .. } => Some(std),
            _ => None,
        };
        let (e, counts, known) =
            each!(estimator, tr => (tr.ekf().estimate(), tr.counts(), tr.ekf().fix_offset_known()));
        json!({
            "mode": now.navigation.name(), "std_m": std.is_finite().then_some(std), "added_std_m": added,
            "gate": {"positions": position.count, "positions_rejected": position.rejected,
                     "velocities": velocity.count, "velocities_rejected": velocity.rejected},
            "dvl": {"fused": self.dvl_fused, "left_out": self.dvl_left_out, "noise_m_s": self.dvl_velocities.noise()},
            "fixes": {"received": self.fixes.count(), "noise_m": self.fixes.noise(), "own": self.own_fixes_since.is_some(),
                      "frame_offset_m": known.then_some(e.fix_offset.0), "frame_offset_std_m": known.then_some(e.fix_offset.1),
                      "outliers": counts.fixes_rejected, "frame_moves": counts.fix_frame_moves},
            "dvl_mounting": {"yaw_deg": e.dvl_yaw.0.to_degrees(), "yaw_std_deg": e.dvl_yaw.1.to_degrees(),
                             "scale": 1.0 + e.dvl_scale.0, "scale_std": e.dvl_scale.1},
            "autopilot": {"left_out": self.autopilot_left_out},
        })
    }
}

/// One cycle as a JSON line on stdout, flushed (a reader on a pipe sees it at once); missing
/// values are nulls.
fn stream_line(s: &Sample, navigation: &Value) {
    use std::io::Write;
    let r = &s.reference;
    let (north_ref, east_ref) = r.horizontal.as_ref().map_or((None, None), |h| (Some(h.north), Some(h.east)));
    let line = json!({
        "t": s.t,
        "depth_m": s.state[2], "depth_ref_m": r.depth,
        "heading_deg": s.state[3].to_degrees(), "heading_ref_deg": r.heading.to_degrees(),
        "north_m": s.state[0], "east_m": s.state[1], "north_ref_m": north_ref, "east_ref_m": east_ref,
        "input": s.cycle.input.as_slice(), "navigation": navigation,
    });
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}
