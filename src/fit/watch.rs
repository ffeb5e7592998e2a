//! A recording watched as it is made (`pinc vehicle excite`): at intervals the fit's own
//! stages 1-5 ([`super::determinacy`]) run on a worker thread over the messages so far, and
//! the watch says which coefficients and axes are determined yet, since when, and whether
//! the fit's report would pass. The session stops exciting once it would.

use super::report::Findings;
use super::{FitSettings, determinacy};
use mavlink::dialects::ardupilotmega::MavMessage;
use std::collections::BTreeMap;
use std::sync::mpsc;
use std::thread::JoinHandle;

/// What one look at the recording found.
#[derive(Debug, Clone)]
pub struct Verdict {
    /// Seconds of recording it looked at.
    pub at: f64,
    /// The fit's findings on them (its warnings empty: the report would pass).
    pub findings: Findings,
}

impl Verdict {
    /// Whether the fit's report on the recording so far passes.
    pub fn passes(&self) -> bool {
        self.findings.warnings.is_empty()
    }

    /// One line: the axes determined, those not yet and what each still lacks.
    pub fn line(&self) -> String {
        let axes: Vec<String> = self
            .findings
            .axes
            .iter()
            .map(|a| if a.determined { format!("{} determined", a.axis) } else { format!("{} not yet", a.axis) })
            .collect();
        let verdict = if self.passes() {
            "the fit's report would pass".to_string()
        } else {
            format!("the fit would warn: {}", self.findings.warnings.join("; "))
        };
        format!("watch at {:.0} s of recording: {}; {verdict}", self.at, axes.join(", "))
    }
}

/// Messages to look at, and the seconds of recording they hold.
type Job = (f64, Vec<(u64, u8, MavMessage)>);

/// The watch: the messages so far, and a worker that looks at a copy of them.
pub struct Watch {
    messages: Vec<(u64, u8, MavMessage)>,
    start: Option<f64>,
    every: f64,
    next: f64,
    busy: bool,
    jobs: Option<mpsc::Sender<Job>>,
    verdicts: mpsc::Receiver<(f64, Result<Findings, String>)>,
    worker: Option<JoinHandle<()>>,
    progress: Progress,
}

/// What the looks so far found.
#[derive(Debug, Clone, Default)]
pub struct Progress {
    /// Since when (s of recording) each coefficient and axis has been determined, without a
    /// break up to the last look.
    pub since: BTreeMap<String, f64>,
    /// The last look.
    pub last: Option<Verdict>,
}

impl Progress {
    fn note(&mut self, v: &Verdict) {
        let determined = v
            .findings
            .coefficients
            .iter()
            .map(|c| (c.name.to_string(), c.status == "identified"))
            .chain(v.findings.axes.iter().map(|a| (format!("{} axis", a.axis), a.determined)));
        for (name, now) in determined {
            if now {
                self.since.entry(name).or_insert(v.at);
            } else {
                self.since.remove(&name);
            }
        }
        self.last = Some(v.clone());
    }

    /// One line: the last look's verdict and since when each thing has been determined.
    pub fn summary(&self) -> Option<String> {
        let last = self.last.as_ref()?;
        let mut parts: Vec<(&String, &f64)> = self.since.iter().collect();
        // The axes first, then the coefficients, each by the time they took.
        parts.sort_by(|a, b| b.0.ends_with(" axis").cmp(&a.0.ends_with(" axis")).then(a.1.total_cmp(b.1)));
        let parts: Vec<String> = parts.iter().map(|(k, at)| format!("{k} {at:.0} s")).collect();
        Some(format!(
            "watch: at its last look ({:.0} s of recording) the fit's report {}; determined since: {}",
            last.at,
            if last.passes() { "passes" } else { "would warn" },
            if parts.is_empty() { "nothing".to_string() } else { parts.join(", ") }
        ))
    }
}

/// The watch replayed over a recording's messages (time stamps in µs): a look at every
/// `every` seconds of it, the first at twice that, as `pinc vehicle excite` makes them live;
/// `on_look` hears of each.
pub fn replay(
    settings: &FitSettings,
    messages: &[(u64, u8, MavMessage)],
    every: f64,
    mut on_look: impl FnMut(&Result<Verdict, String>),
) -> Progress {
    let mut progress = Progress::default();
    let Some(start) = messages.first().map(|m| m.0) else { return progress };
    let end = messages.last().map_or(start, |m| m.0);
    let mut at = 2.0 * every;
    loop {
        let cut = start + (at.min((end - start) as f64 * 1e-6) * 1e6) as u64;
        let upto = messages.partition_point(|m| m.0 <= cut);
        let look = determinacy(settings, messages[..upto].to_vec())
            .map(|(findings, _)| Verdict { at: (cut - start) as f64 * 1e-6, findings })
            .map_err(|e| e.to_string());
        if let Ok(v) = &look {
            progress.note(v);
        }
        on_look(&look);
        if cut >= end {
            break;
        }
        at += every;
    }
    progress
}

impl Watch {
    /// A watch that looks every `every` seconds of recording, first at `first`, with the fit's
    /// `settings` (their recordings are ignored: the watch has its own messages).
    pub fn new(settings: FitSettings, first: f64, every: f64) -> Self {
        let (jobs, inbox) = mpsc::channel::<Job>();
        let (outbox, verdicts) = mpsc::channel();
        let worker = std::thread::Builder::new()
            .name("pinc-watch".into())
            .spawn(move || {
                for (at, messages) in inbox {
                    let found = determinacy(&settings, messages).map(|(f, _)| f).map_err(|e| e.to_string());
                    if outbox.send((at, found)).is_err() {
                        break;
                    }
                }
            })
            .ok();
        Self {
            messages: Vec::new(),
            start: None,
            every,
            next: first,
            busy: false,
            jobs: worker.as_ref().map(|_| jobs),
            verdicts,
            worker,
            progress: Progress::default(),
        }
    }

    /// A message from the autopilot (system `sys`) at autopilot time `t` (s). Before the
    /// autopilot's clock is known the link gives time 0: those messages (parameters,
    /// heartbeats) are none of what the fit reads, and a vehicle that booted long before the
    /// session would otherwise start the watch's clock at its boot.
    pub fn message(&mut self, t: f64, sys: u8, message: &MavMessage) {
        if self.start.is_none() && t <= 0.0 {
            return;
        }
        let start = *self.start.get_or_insert(t);
        self.messages.push((((t - start).max(0.0) * 1e6) as u64, sys, message.clone()));
    }

    /// Seconds of recording so far at autopilot time `t`.
    fn recorded(&self, t: f64) -> f64 {
        self.start.map_or(0.0, |s| t - s)
    }

    /// At autopilot time `t`: hands the worker the messages so far when a look is due and it
    /// is idle, and returns a finished look (or why it could not look), if one came.
    pub fn poll(&mut self, t: f64) -> Option<Result<Verdict, String>> {
        let at = self.recorded(t);
        if !self.busy
            && at >= self.next
            && let Some(jobs) = &self.jobs
        {
            if jobs.send((at, self.messages.clone())).is_ok() {
                self.busy = true;
            }
            self.next = at + self.every;
        }
        let (at, found) = self.verdicts.try_recv().ok()?;
        self.busy = false;
        Some(found.map(|findings| {
            let verdict = Verdict { at, findings };
            self.progress.note(&verdict);
            verdict
        }))
    }

    /// What the looks so far found.
    pub fn progress(&self) -> &Progress {
        &self.progress
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        // Closing the channel ends the worker after its current look.
        self.jobs = None;
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}
