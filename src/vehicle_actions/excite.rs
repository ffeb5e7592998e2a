//! `pinc vehicle excite`: an excitation file played open loop on the vehicle, recorded, and
//! watched (with the `train` feature) until the fit's coefficients are determined.
//!
//! The stages, in order: the plan (inputs, depth band, commander: everything checked before
//! the link opens), the recording (link, metadata, writer), the play loop (one input per
//! fresh state, the band's heave, the watch's looks), the end (neutral, the last outputs into
//! the file, the summary).

use super::writer::{Writer, recording_estimator};
use super::{ExciteArgs, SERVO_OUTPUT_RAW_ID, ctrl_c_flag, session_metadata};
use crate::closed_loop::Level;
use crate::link::cli::{non_negative, open, positive};
use crate::link::{Capability, DepthBand, Drive, Fresh, InputsFromOutputs, Received, Recorder, Stopped, Trigger};
use crate::types::Input;
use std::cell::RefCell;
use std::time::{Duration, Instant};

/// What an excitation plays, read and checked before anything is sent.
struct Plan {
    /// Sample period of the inputs (s).
    dt: f64,
    inputs: Vec<Input>,
    band: Option<DepthBand>,
}

fn plan(a: &ExciteArgs) -> Result<Plan, String> {
    let dt = positive("--dt", a.dt)?.as_secs_f64();
    let file = std::fs::File::open(&a.inputs).map_err(|e| format!("{}: {e}", a.inputs.display()))?;
    let inputs = crate::trajectory_csv::read_inputs(file).map_err(|e| format!("{}: {e}", a.inputs.display()))?;
    if inputs.is_empty() {
        return Err(format!("{}: no input rows", a.inputs.display()));
    }
    if !(a.watch_every.is_finite() && a.watch_every >= 0.0) {
        return Err(format!("--watch-every must be zero or a positive number of seconds, got {}", a.watch_every));
    }
    // The band's force limit: the largest heave the excitation itself asks for.
    let heave_limit = inputs.iter().map(|u| u[2].abs()).fold(0.0, f64::max).max(1.0);
    let band = match a.depth_band.as_deref() {
        Some(&[top, bottom]) => Some(DepthBand::new(top, bottom, a.band_kp, a.band_kd, heave_limit)?),
        Some(other) => return Err(format!("--depth-band: two depths TOP,BOTTOM (m), got {other:?}")),
        None => None,
    };
    Ok(Plan { dt, inputs, band })
}

/// The recording as the session writes it: the writer, the first error writing it (which
/// ends the session at the next cycle), and the watch.
struct Recording {
    w: RefCell<Writer>,
    write_error: RefCell<Option<String>>,
    watch: RefCell<Option<watch::Watch>>,
}

impl Recording {
    fn keep(&self, result: Result<(), String>) {
        if let Err(e) = result {
            self.write_error.borrow_mut().get_or_insert(e);
        }
    }

    /// Every message received, at autopilot time `t`: into the file and to the watch.
    fn seen(&self, r: &Received, t: f64) {
        self.keep(self.w.borrow_mut().message(r, t));
        if let Some(watch) = self.watch.borrow_mut().as_mut() {
            watch.message(r, t);
        }
    }

    fn log(&self, t: f64, level: Level, line: &str) {
        self.keep(self.w.borrow_mut().log(t, level, line));
    }
}

/// Why the play loop ended without a safety stop.
enum Ended {
    /// Every input was played.
    Played,
    /// The watch found every coefficient the fit needs determined (at this many seconds).
    Determined(f64),
}

/// The play loop: one input per fresh state (neutral while waiting for a position source),
/// the band's heave over the excitation's, the watch's looks said and acted on.
fn play(
    drive: &mut Drive,
    s: &Recording,
    plan: &mut Plan,
    a: &ExciteArgs,
    played: &mut usize,
) -> Result<Ended, Trigger> {
    let wait_position = non_negative("--wait-position", a.drive.wait_position).map_err(Trigger::Error)?;
    let mut t0: Option<f64> = None;
    let waited = Instant::now();
    let seen = |r: &Received, t: f64| s.seen(r, t);
    loop {
        let fresh: Fresh = drive.next_state(seen)?;
        s.w.borrow_mut().observed(fresh.state.t, drive.drain_observations()).map_err(Trigger::Error)?;
        // The autopilot's own texts are in the recording already (the writer logs them).
        for n in drive.take_notes().into_iter().filter(|n| !n.from_autopilot) {
            s.log(n.t, n.level, &n.text);
        }
        if let Some(e) = s.write_error.borrow().as_ref() {
            return Err(Trigger::Error(e.clone()));
        }
        let estimate = s.w.borrow_mut().state(&fresh.state).map_err(Trigger::Error)?;
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
                s.log(fresh.state.t, Level::Warning, &line);
            }
            t0 = Some(fresh.state.t);
        }
        if let Some(at) = watch::look(s, fresh.state.t, a.keep_going) {
            return Ok(Ended::Determined(at));
        }
        let k = ((fresh.state.t - t0.expect("set")) / plan.dt).round() as usize;
        let Some(u) = plan.inputs.get(k) else { return Ok(Ended::Played) };
        let mut u = *u;
        if let Some(b) = &mut plan.band {
            // The estimate's depth and heave rate; the raw depth at rest before it starts.
            let (z, w_rate) = estimate.map_or((fresh.state.sim[2], 0.0), |e| (e.sim[2], e.sim[6]));
            let h = b.heave(z, w_rate, u[2]);
            if h.switched {
                let line = if h.feedback {
                    format!("depth {z:.2} m: the band's feedback takes the heave")
                } else {
                    format!("depth {z:.2} m: back in the band's middle, the excitation takes the heave again")
                };
                s.log(fresh.state.t, Level::Info, &line);
            }
            s.keep(s.w.borrow_mut().rec.excite_heave(fresh.state.t, u[2], h.z, h.feedback).map_err(|e| e.to_string()));
            u[2] = h.z;
        }
        drive.send(&fresh, &u)?;
        *played = k + 1;
    }
}

pub(super) fn run_excite(a: ExciteArgs) -> Result<(), String> {
    let mut plan = plan(&a)?;
    let commander = a.drive.commander(&a.vehicle)?;
    let settings = a.drive.settings()?;
    let limits = settings.limits.clone();
    let stop = ctrl_c_flag()?;
    let recorded = Some(InputsFromOutputs::new(1.0 / a.link.rate, a.link.max_age));
    let mut pending: Vec<Received> = Vec::new();
    let (link, autopilot, estimator) = open(&a.link.connect, &a.link, |r| pending.push(r.clone()))?;
    link.set_message_rate(SERVO_OUTPUT_RAW_ID, a.drive.outputs_rate).map_err(|e| e.to_string())?;
    let mut metadata = session_metadata(&a.link, &autopilot);
    metadata.insert("vehicle_file".to_string(), a.vehicle.display().to_string());
    metadata.insert("inputs_file".to_string(), a.inputs.display().to_string());
    metadata.insert("command".to_string(), a.drive.command_way.clone());
    metadata.insert("limits".to_string(), limits.describe());
    let rec = Recorder::create(&a.out, metadata).map_err(|e| e.to_string())?;
    let mut writer = Writer::new(rec, autopilot.clone(), recorded, pending.clone());
    writer.estimation = Some(recording_estimator(&a.vehicle, plan.dt)?);
    let s = Recording {
        w: RefCell::new(writer),
        write_error: RefCell::new(None),
        watch: RefCell::new(watch::start(&a, plan.dt, &autopilot, &pending)),
    };
    let started =
        Drive::start(link, autopilot, estimator, commander, settings, stop, |r: &Received, t: f64| s.seen(r, t));
    let mut drive = match started {
        Ok(d) => d,
        Err(mut stopped) => {
            for n in std::mem::take(&mut stopped.notes).into_iter().filter(|n| !n.from_autopilot) {
                s.log(n.t, n.level, &n.text);
            }
            return end_excite(s, &stopped, None, 0, plan.inputs.len());
        }
    };
    let line = format!(
        "excitation: {} inputs at {} s from {} by {}",
        plan.inputs.len(),
        plan.dt,
        a.inputs.display(),
        a.drive.command_way
    );
    s.log(drive.now_t(), Level::Info, &line);
    let mut played = 0usize;
    let outcome = play(&mut drive, &s, &mut plan, &a, &mut played);
    let (stopped, ended) = match outcome {
        Ok(ended) => (drive.finish(), Some(ended)),
        Err(trigger) => (drive.abort(trigger), None),
    };
    // The last outputs (the neutral ones among them) into the recording.
    drive.drain(Duration::from_millis(300), |r: &Received, t: f64| s.seen(r, t));
    let now = drive.now_t();
    s.keep(s.w.borrow_mut().observed(now, drive.drain_observations()));
    if drive.out_of_order() > 0 {
        let line = format!("{} messages arrived out of order and were dropped", drive.out_of_order());
        s.log(stopped.t, Level::Warning, &line);
    }
    drop(drive);
    end_excite(s, &stopped, ended, played, plan.inputs.len())
}

/// Writes the stop and what the watch found into the recording and on the terminal, and
/// finishes the file; an error (exit 1) for any safety stop.
fn end_excite(
    s: Recording,
    stopped: &Stopped,
    ended: Option<Ended>,
    played: usize,
    total: usize,
) -> Result<(), String> {
    let (level, line) = match (&stopped.trigger, ended) {
        (None, Some(Ended::Determined(at))) => (
            Level::Info,
            format!(
                "excitation stopped: every coefficient the fit needs was determined after {at:.0} s of recording; \
                 {played} of {total} inputs played"
            ),
        ),
        (None, _) => (Level::Info, format!("excitation finished: {played} of {total} inputs played")),
        (Some(t), _) => (
            Level::Error,
            format!(
                "{t}; neutral command sent{}{}; {played} of {total} inputs played",
                stopped.neutral_t.map_or(" (failed)".to_string(), |n| format!(" at {n:.3} s")),
                if stopped.disarm_sent { ", disarm sent" } else { "" }
            ),
        ),
    };
    if let Some(summary) = s.watch.borrow_mut().take().and_then(|w| watch::summary(&w)) {
        s.log(stopped.t, Level::Info, &summary);
        eprintln!("{summary}");
    }
    let Recording { w, write_error, .. } = s;
    let stats = w.into_inner().finish(stopped.t, level, &line);
    if stopped.trigger.is_some() {
        eprintln!("{line}");
    }
    let stats = stats?;
    if let Some(e) = write_error.into_inner() {
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

/// The watch: the fit's identification on the recording so far, at intervals, on a worker
/// thread (it needs the fit, so the `train` feature).
#[cfg(feature = "train")]
mod watch {
    use super::{ExciteArgs, Recording};
    use crate::closed_loop::Level;
    use crate::fit::FitSettings;
    use crate::link::{Autopilot, Received};

    /// The watch and the autopilot whose messages it takes.
    pub(super) struct Watch {
        inner: crate::fit::watch::Watch,
        autopilot: Autopilot,
    }

    impl Watch {
        pub(super) fn message(&mut self, r: &Received, t: f64) {
            if self.autopilot.sent(r) {
                self.inner.message(t, self.autopilot.system_id, &r.message);
            }
        }
    }

    /// A watch over the recording, unless `--watch-every 0`. The messages that came before
    /// the autopilot's clock was known are offered at time 0, which the watch leaves out.
    pub(super) fn start(a: &ExciteArgs, dt: f64, autopilot: &Autopilot, pending: &[Received]) -> Option<Watch> {
        if a.watch_every == 0.0 {
            return None;
        }
        let mut settings = FitSettings::new(Vec::new(), a.vehicle.clone());
        settings.dt = dt;
        let inner = crate::fit::watch::Watch::new(settings, 2.0 * a.watch_every, a.watch_every);
        let mut w = Watch { inner, autopilot: autopilot.clone() };
        for r in pending {
            w.message(r, 0.0);
        }
        Some(w)
    }

    /// A look, if one finished: said on the terminal and in the recording; the recording
    /// time at which the fit's report passes, unless `keep_going`.
    pub(super) fn look(s: &Recording, t: f64, keep_going: bool) -> Option<f64> {
        let found = s.watch.borrow_mut().as_mut()?.inner.poll(t)?;
        match found {
            Ok(v) => {
                let line = v.line();
                eprintln!("{line}");
                s.log(t, Level::Info, &line);
                (v.passes() && !keep_going).then_some(v.at)
            }
            Err(e) => {
                let line = format!("watch: the fit cannot look at the recording yet: {e}");
                eprintln!("{line}");
                s.log(t, Level::Info, &line);
                None
            }
        }
    }

    /// Since when each coefficient and axis has been determined, in one line.
    pub(super) fn summary(w: &Watch) -> Option<String> {
        w.inner.progress().summary()
    }
}

/// Without the `train` feature there is no fit to watch with: the whole file plays.
#[cfg(not(feature = "train"))]
mod watch {
    use super::{ExciteArgs, Recording};
    use crate::link::{Autopilot, Received};

    pub(super) struct Watch;

    impl Watch {
        pub(super) fn message(&mut self, _: &Received, _: f64) {}
    }

    pub(super) fn start(a: &ExciteArgs, _: f64, _: &Autopilot, _: &[Received]) -> Option<Watch> {
        if a.watch_every > 0.0 {
            eprintln!("note: this build has no `train` feature: the recording is not watched and the whole file plays");
        }
        None
    }

    pub(super) fn look(_: &Recording, _: f64, _: bool) -> Option<f64> {
        None
    }

    pub(super) fn summary(_: &Watch) -> Option<String> {
        None
    }
}
