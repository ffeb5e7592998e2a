//! One job at a time: an excitation or a flight runs as a child process (pinc's own
//! `vehicle excite` and `mpc_track --connect`, with every safety stop they have), a fit in a
//! thread. Children die with the server (Linux's parent-death signal): a server killed mid
//! flight leaves the vehicle to the autopilot's own failsafe (pilot input lost: neutral in 3 s)
//! and the recording as `.partial`. STOP interrupts the child (it sends neutral and disarms,
//! as on Ctrl-C) beside the server's own neutral and disarm; a child still running 5 s later is
//! killed. A flight on the page's gamepad takes the sticks on its standard input; the page gone
//! quiet for [`PAGE_GONE`] stops it the same way.

use serde_json::{Value, json};
use std::collections::VecDeque;
use std::ffi::OsString;
use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Lines of a job's output kept for the page.
const KEPT_LINES: usize = 400;
/// A flight's cycles kept for the page by default: as many as the flight keeps for its figures
/// (`--history`, 5 minutes at 12.5 Hz).
const KEPT_SAMPLES: usize = (crate::link::session::DEFAULT_HISTORY_S / 0.08) as usize;
/// A child still running this long after STOP is killed.
const KILL_AFTER: Duration = Duration::from_secs(5);
/// The most cycles one answer carries: a page that opens on a long flight takes the kept
/// history in pieces, a poll each. Whole (3750 cycles parsed at once, by several pages or
/// reloads at a time) they grew the server's memory to 57-87 MB at each such answer and its
/// resting memory from 13 to 18 MB in 3 minutes of a test load: memory the allocator keeps.
pub const SAMPLES_PER_ANSWER: usize = 250;

/// A flight on the page's sticks with none from the page for this long is stopped (neutral
/// and disarm): the page was closed or lost its link. The flight itself holds after 0.5 s, so
/// a page reloaded or reconnected within it flies on (a reload under load went 2.5-3.4 s
/// without sticks: at 3 s the dive's reload stopped the flight).
pub const PAGE_GONE: Duration = Duration::from_secs(10);

/// What a job does.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Kind {
    Excite,
    Fit,
    Fly,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Excite => "excite",
            Kind::Fit => "fit",
            Kind::Fly => "fly",
        }
    }
}

/// Where a job is.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum State {
    Running,
    Finished,
    Failed,
    Stopped,
}

impl State {
    fn name(self) -> &'static str {
        match self {
            State::Running => "running",
            State::Finished => "finished",
            State::Failed => "failed",
            State::Stopped => "stopped",
        }
    }
}

/// One job, as the page sees it.
pub struct Job {
    pub id: u64,
    pub kind: Kind,
    pub what: String,
    started: Instant,
    ended: Option<Instant>,
    pub state: State,
    lines: VecDeque<String>,
    /// The excitation's watch: its last word.
    pub verdict: Option<String>,
    /// The fit's stage, and its epochs done of all.
    pub stage: Option<String>,
    pub epochs: Option<(usize, usize)>,
    /// A flight's newest cycles as its process streams them (at most `kept_samples`).
    samples: SampleRing,
    kept_samples: usize,
    /// What it made (kind, name) and its figures.
    pub result: Option<Value>,
    pub error: Option<String>,
    pub exit_code: Option<i32>,
    child: Option<u32>,
    /// The child's standard input, where it takes the pilot's sticks.
    sticks_in: Option<ChildStdin>,
    /// When the page last sent sticks (a flight on them: from its start).
    sticks_at: Option<Instant>,
    stop_asked: Option<Instant>,
    interrupt: Arc<AtomicBool>,
}

/// A flight's newest cycles, the JSON lines its process streamed, in slots that are written
/// over in place and handed from one job to the next. Cycles allocated afresh each on the job's
/// own thread grew the server by the kept history's size at every new flight (each thread
/// allocates from its own arena, and the last flight's freed memory was not reused: +3 MB at the
/// second flight of a dive, measured); written over, an hour's dive, a reboot and another
/// flight keep it flat.
#[derive(Default)]
struct SampleRing {
    slots: Vec<String>,
    /// The oldest kept, once the ring is full; how many are kept; how many were let go.
    start: usize,
    len: usize,
    dropped: usize,
}

impl SampleRing {
    /// Empty again, the slots kept for the next flight.
    fn reset(&mut self) {
        (self.start, self.len, self.dropped) = (0, 0, 0);
    }

    fn push(&mut self, line: &str, kept: usize) {
        let index = if self.len < kept {
            if self.slots.len() == self.len {
                // Room to grow: the next line of a flight is seldom much longer.
                self.slots.push(String::with_capacity(line.len() + 256));
            }
            self.len += 1;
            self.len - 1
        } else {
            let oldest = self.start;
            self.start = (self.start + 1) % kept;
            self.dropped += 1;
            oldest
        };
        let slot = &mut self.slots[index];
        slot.clear();
        slot.push_str(line);
    }

    /// The kept cycles from the `from`-th of the flight (counting those let go) on.
    fn from(&self, from: usize) -> impl Iterator<Item = &str> {
        let first = from.saturating_sub(self.dropped);
        (first..self.len).map(move |i| self.slots[(self.start + i) % self.len.max(1)].as_str())
    }
}

impl Job {
    /// `since`: the first sample to send (the page asks only for the new ones), at most
    /// [`SAMPLES_PER_ANSWER`] of them. A page that fell behind the kept cycles gets them from the
    /// oldest kept (`samples_from`).
    pub fn to_json(&self, since: usize) -> Value {
        let total = self.samples.dropped + self.samples.len;
        let from = since.clamp(self.samples.dropped, total);
        // Each line was checked as JSON when it came.
        let samples: Vec<Value> = self
            .samples
            .from(from)
            .take(SAMPLES_PER_ANSWER)
            .filter_map(|line| serde_json::from_str(line).ok())
            .collect();
        json!({
            "id": self.id,
            "kind": self.kind.name(),
            "what": self.what,
            "state": self.state.name(),
            "elapsed_s": self.ended.unwrap_or_else(Instant::now).duration_since(self.started).as_secs_f64(),
            "lines": self.lines,
            "verdict": self.verdict,
            "stage": self.stage,
            "epochs": self.epochs,
            "samples_total": total,
            "samples_from": from,
            "samples": samples,
            "result": self.result,
            "error": self.error,
            "exit_code": self.exit_code,
            "stop_asked_s_ago": self.stop_asked.map(|t| t.elapsed().as_secs_f64()),
            "takes_sticks": self.state == State::Running && self.sticks_in.is_some(),
        })
    }

    fn add_sample(&mut self, line: &str) {
        self.samples.push(line, self.kept_samples);
    }

    fn say(&mut self, line: String) {
        if self.lines.len() == KEPT_LINES {
            self.lines.pop_front();
        }
        self.lines.push_back(line);
    }
}

/// The current (or last) job, shared by the routes and the job's threads.
#[derive(Clone)]
pub struct Jobs {
    current: Arc<Mutex<Option<Job>>>,
    next_id: Arc<Mutex<u64>>,
    /// A flight's newest cycles kept for the page.
    kept_samples: usize,
}

impl Default for Jobs {
    fn default() -> Self {
        Self::keeping(KEPT_SAMPLES)
    }
}

/// A process to run: the program and its arguments, for the page's log too.
pub struct Step {
    pub program: PathBuf,
    pub args: Vec<OsString>,
    /// The child takes the page's sticks on its standard input.
    pub sticks: bool,
}

impl Step {
    fn shown(&self) -> String {
        let mut s = self.program.display().to_string();
        for a in &self.args {
            s.push(' ');
            s.push_str(&a.to_string_lossy());
        }
        s
    }
}

/// What a child's run gave: its exit code (`None`: killed by a signal), and its standard
/// output that was not a stream sample.
pub struct Ran {
    pub code: Option<i32>,
    pub stdout: String,
}

impl Jobs {
    /// Jobs whose flights keep their newest `kept_samples` cycles for the page.
    pub fn keeping(kept_samples: usize) -> Self {
        Self { current: Arc::default(), next_id: Arc::default(), kept_samples: kept_samples.max(1) }
    }

    /// Starts a job unless one runs (the refusal says which); `work` runs on its own thread
    /// with a handle to report through, and returns what the job made or why it failed.
    pub fn start(
        &self,
        kind: Kind,
        what: String,
        work: impl FnOnce(&Handle) -> Result<Value, String> + Send + 'static,
    ) -> Result<u64, String> {
        let mut current = self.current.lock().expect("jobs");
        if let Some(j) = current.as_ref().filter(|j| j.state == State::Running) {
            return Err(format!(
                "refused: {} {} is running (job {}); one at a time: stop it or wait for its end",
                j.kind.name(),
                j.what,
                j.id
            ));
        }
        let id = {
            let mut n = self.next_id.lock().expect("ids");
            *n += 1;
            *n
        };
        let interrupt = Arc::new(AtomicBool::new(false));
        // The last job's cycle slots serve this one (see `SampleRing`).
        let mut samples = current.take().map(|j| j.samples).unwrap_or_default();
        samples.reset();
        *current = Some(Job {
            id,
            kind,
            what,
            started: Instant::now(),
            ended: None,
            state: State::Running,
            lines: VecDeque::new(),
            verdict: None,
            stage: None,
            epochs: None,
            samples,
            kept_samples: self.kept_samples,
            result: None,
            error: None,
            exit_code: None,
            child: None,
            sticks_in: None,
            sticks_at: None,
            stop_asked: None,
            interrupt: interrupt.clone(),
        });
        drop(current);
        let handle = Handle { jobs: self.clone(), id, interrupt };
        std::thread::spawn(move || {
            let outcome = work(&handle);
            handle.update(|j| {
                j.ended = Some(Instant::now());
                (j.child, j.sticks_in) = (None, None);
                match outcome {
                    Ok(result) => {
                        j.result = Some(result);
                        j.state = if j.stop_asked.is_some() { State::Stopped } else { State::Finished };
                    }
                    Err(e) => {
                        j.say(format!("error: {e}"));
                        j.error = Some(e);
                        j.state = if j.stop_asked.is_some() { State::Stopped } else { State::Failed };
                    }
                }
            });
        });
        Ok(id)
    }

    /// The running job told to stop: its child interrupted, or its fit's flag set. Whether a
    /// job was running.
    pub fn stop(&self) -> bool {
        let mut current = self.current.lock().expect("jobs");
        let Some(j) = current.as_mut().filter(|j| j.state == State::Running) else { return false };
        j.stop_asked.get_or_insert_with(Instant::now);
        j.interrupt.store(true, Ordering::Relaxed);
        if let Some(pid) = j.child {
            signal(pid, libc::SIGINT);
        }
        j.say("STOP asked".into());
        true
    }

    /// The running flight told to end by handing the vehicle back as the pilot had it (its
    /// child's SIGUSR1; a flight that does not end is left to STOP). Whether a flight was
    /// running.
    pub fn hand_back(&self) -> bool {
        let mut current = self.current.lock().expect("jobs");
        let Some(j) = current.as_mut().filter(|j| j.state == State::Running && j.kind == Kind::Fly) else {
            return false;
        };
        if let Some(pid) = j.child {
            signal(pid, libc::SIGUSR1);
        }
        j.say("asked to hand the vehicle back to the pilot".into());
        true
    }

    /// One line of sticks to the running flight that takes them.
    ///
    /// # Errors
    /// No such flight runs, or its input is closed.
    pub fn send_sticks(&self, line: &str) -> Result<(), String> {
        let mut current = self.current.lock().expect("jobs");
        let j = current
            .as_mut()
            .filter(|j| j.state == State::Running && j.sticks_in.is_some())
            .ok_or("no flight on the gamepad is running: start one first")?;
        let input = j.sticks_in.as_mut().expect("checked");
        input
            .write_all(line.as_bytes())
            .and_then(|()| input.write_all(b"\n"))
            .and_then(|()| input.flush())
            .map_err(|e| format!("the flight no longer takes sticks: {e}"))?;
        j.sticks_at = Some(Instant::now());
        Ok(())
    }

    /// Whether a job runs.
    pub fn running(&self) -> bool {
        self.current.lock().expect("jobs").as_ref().is_some_and(|j| j.state == State::Running)
    }

    pub fn to_json(&self, since: usize) -> Value {
        self.current.lock().expect("jobs").as_ref().map_or(Value::Null, |j| j.to_json(since))
    }
}

fn signal(pid: u32, sig: libc::c_int) {
    if let Ok(pid) = libc::pid_t::try_from(pid) {
        // SAFETY: kill(2) takes any pid and signal number; the pid is our own child's.
        unsafe { libc::kill(pid, sig) };
    }
}

/// A running job's view of itself.
#[derive(Clone)]
pub struct Handle {
    jobs: Jobs,
    id: u64,
    interrupt: Arc<AtomicBool>,
}

impl Handle {
    /// Changes this job (not a later one).
    pub fn update(&self, f: impl FnOnce(&mut Job)) {
        if let Some(j) = self.jobs.current.lock().expect("jobs").as_mut().filter(|j| j.id == self.id) {
            f(j);
        }
    }

    pub fn say(&self, line: impl Into<String>) {
        let line = line.into();
        self.update(|j| j.say(line));
    }

    /// Set when STOP was asked (the fit watches it; builds without the trainer have no fit).
    #[cfg_attr(not(feature = "train"), allow(dead_code))]
    pub fn interrupt(&self) -> &AtomicBool {
        &self.interrupt
    }

    /// Runs `step` to its end: its standard error line by line into the job's log (the
    /// watch's lines also as the verdict), its standard output's JSON lines with a `t` as
    /// samples; STOP interrupts it and kills it 5 s later.
    pub fn run(&self, step: &Step) -> Result<Ran, String> {
        if self.interrupt.load(Ordering::Relaxed) {
            return Err("stopped before it started".into());
        }
        self.say(format!("$ {}", step.shown()));
        let mut child = spawn(step).map_err(|e| format!("cannot start {}: {e}", step.program.display()))?;
        let sticks_in = child.stdin.take();
        self.update(|j| {
            j.child = Some(child.id());
            if step.sticks {
                (j.sticks_in, j.sticks_at) = (sticks_in, Some(Instant::now()));
            }
        });
        // A STOP that came while the child was starting found none to interrupt.
        if self.interrupt.load(Ordering::Relaxed) {
            signal(child.id(), libc::SIGINT);
        }
        let stderr = child.stderr.take().expect("piped");
        let stdout = child.stdout.take().expect("piped");
        let errors = {
            let me = self.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                    me.update(|j| {
                        if line.starts_with("watch") {
                            j.verdict = Some(line.clone());
                        }
                        j.say(line);
                    });
                }
            })
        };
        // Read on a thread too: the wait below must see a STOP while the child still writes.
        let output = {
            let me = self.clone();
            std::thread::spawn(move || {
                let mut rest = String::new();
                for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                    match serde_json::from_str::<Value>(&line) {
                        Ok(v) if v.get("t").is_some_and(Value::is_number) => me.update(|j| j.add_sample(&line)),
                        _ => {
                            rest.push_str(&line);
                            rest.push('\n');
                        }
                    }
                }
                rest
            })
        };
        let status = wait(&mut child, self)?;
        let _ = errors.join();
        let rest = output.join().unwrap_or_default();
        self.update(|j| j.exit_code = status.code());
        Ok(Ran { code: status.code(), stdout: rest })
    }
}

/// Waits for `child`, killing it 5 s after a STOP it did not obey.
fn wait(child: &mut Child, handle: &Handle) -> Result<std::process::ExitStatus, String> {
    loop {
        if let Some(status) = child.try_wait().map_err(|e| e.to_string())? {
            return Ok(status);
        }
        let mut overdue = false;
        let mut page_gone = false;
        handle.update(|j| {
            overdue = j.stop_asked.is_some_and(|t| t.elapsed() > KILL_AFTER);
            page_gone = j.stop_asked.is_none() && j.sticks_at.is_some_and(|t| t.elapsed() > PAGE_GONE);
        });
        if page_gone {
            handle.say(format!(
                "no sticks from the page for {} s (closed, or its link lost): stopped (neutral and disarm)",
                PAGE_GONE.as_secs()
            ));
            handle.jobs.stop();
        }
        if overdue {
            handle.say(format!("still running {} s after STOP: killed", KILL_AFTER.as_secs()));
            let _ = child.kill();
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The child, its output piped, killed by the kernel if the server dies.
fn spawn(step: &Step) -> std::io::Result<Child> {
    let mut command = Command::new(&step.program);
    let stdin = if step.sticks { Stdio::piped() } else { Stdio::null() };
    command.args(&step.args).stdin(stdin).stdout(Stdio::piped()).stderr(Stdio::piped());
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        // SAFETY: between fork and exec only prctl(2) and sigaction(2), which are
        // async-signal-safe, run; the struct is plain data, zeroed on the stack.
        unsafe {
            command.pre_exec(|| {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                // SIGINT back to its default: a server started in the background by a shell
                // without job control ignores it, its children would inherit that, and a
                // shell script cannot trap a signal ignored on entry (STOP's interrupt lost).
                let mut default: libc::sigaction = std::mem::zeroed();
                default.sa_sigaction = libc::SIG_DFL;
                if libc::sigaction(libc::SIGINT, &default, std::ptr::null_mut()) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    command.spawn()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wait_for_end(jobs: &Jobs) -> Value {
        for _ in 0..800 {
            let j = jobs.to_json(0);
            if j["state"] != "running" {
                return j;
            }
            std::thread::sleep(Duration::from_millis(25));
        }
        panic!("the job did not end: {}", jobs.to_json(0));
    }

    #[test]
    fn one_job_at_a_time_and_samples_apart_from_the_rest() {
        let jobs = Jobs::default();
        let script = "echo '{\"t\": 0.08, \"depth_m\": 1}'; echo 'said' >&2; sleep 0.3; echo '{\"summary\": 1}'";
        let step = Step { program: "sh".into(), args: vec!["-c".into(), script.into()], sticks: false };
        jobs.start(Kind::Fly, "test".into(), move |h| {
            let ran = h.run(&step)?;
            Ok(json!({"rest": ran.stdout, "code": ran.code}))
        })
        .unwrap();
        let refused = jobs.start(Kind::Fit, "second".into(), |_| Ok(Value::Null)).expect_err("one at a time");
        assert!(refused.contains("fly test is running"), "{refused}");
        let j = wait_for_end(&jobs);
        assert_eq!(j["state"], "finished");
        assert_eq!(j["samples"], json!([{"t": 0.08, "depth_m": 1}]));
        assert_eq!(j["result"], json!({"rest": "{\"summary\": 1}\n", "code": 0}));
        assert!(j["lines"].as_array().unwrap().iter().any(|l| l == "said"));
        assert_eq!(jobs.to_json(1)["samples"], json!([]));
    }

    #[test]
    fn a_long_flight_keeps_its_last_cycles_and_a_page_behind_starts_from_the_oldest() {
        let jobs = Jobs::keeping(50);
        let n = 55;
        let script = format!("i=0; while [ $i -lt {n} ]; do echo \"{{\\\"t\\\": $i}}\"; i=$((i+1)); done");
        let step = Step { program: "sh".into(), args: vec!["-c".into(), script.into()], sticks: false };
        jobs.start(Kind::Fly, "long".into(), move |h| h.run(&step).map(|r| json!(r.code))).unwrap();
        let j = wait_for_end(&jobs);
        assert_eq!(j["samples_total"], json!(n));
        assert_eq!(j["samples_from"], json!(5));
        assert_eq!(j["samples"].as_array().unwrap().len(), 50);
        assert_eq!(j["samples"][0], json!({"t": 5}));
        let newest = jobs.to_json(n - 2);
        assert_eq!(
            (newest["samples_from"].clone(), newest["samples"].clone()),
            (json!(n - 2), json!([{"t": n - 2}, {"t": n - 1}]))
        );
        assert_eq!(jobs.to_json(n + 10)["samples"], json!([]));
        // The next flight writes over the same slots: its own cycles only, from its first.
        let step = Step {
            program: "sh".into(),
            args: vec!["-c".into(), "echo '{\"t\": 100}'; echo '{\"t\": 101}'".into()],
            sticks: false,
        };
        jobs.start(Kind::Fly, "next".into(), move |h| h.run(&step).map(|r| json!(r.code))).unwrap();
        let j = wait_for_end(&jobs);
        assert_eq!((j["samples_total"].clone(), j["samples_from"].clone()), (json!(2), json!(0)));
        assert_eq!(j["samples"], json!([{"t": 100}, {"t": 101}]));
        assert_eq!(jobs.to_json(1)["samples"], json!([{"t": 101}]));
    }

    #[test]
    fn a_page_behind_takes_the_kept_cycles_in_pieces() {
        let jobs = Jobs::keeping(600);
        let script = "i=0; while [ $i -lt 600 ]; do echo \"{\\\"t\\\": $i}\"; i=$((i+1)); done";
        let step = Step { program: "sh".into(), args: vec!["-c".into(), script.into()], sticks: false };
        jobs.start(Kind::Fly, "long".into(), move |h| h.run(&step).map(|r| json!(r.code))).unwrap();
        wait_for_end(&jobs);
        let mut since = 0;
        let mut seen = Vec::new();
        while since < 600 {
            let j = jobs.to_json(since);
            let samples = j["samples"].as_array().unwrap();
            assert!(!samples.is_empty() && samples.len() <= SAMPLES_PER_ANSWER, "{}", samples.len());
            assert_eq!(j["samples_from"], json!(since));
            seen.extend(samples.iter().map(|s| s["t"].as_u64().unwrap()));
            since += samples.len();
        }
        assert_eq!(seen, (0..600).collect::<Vec<u64>>());
    }

    #[test]
    fn stop_interrupts_the_child_and_kills_one_that_ignores_it() {
        let jobs = Jobs::default();
        // Traps SIGINT (says so and goes on): only the kill after 5 s ends it.
        let script = "trap 'echo interrupted >&2' INT; echo trapped >&2; for i in $(seq 100); do sleep 0.1; done";
        let step = Step { program: "sh".into(), args: vec!["-c".into(), script.into()], sticks: false };
        jobs.start(Kind::Excite, "stubborn".into(), move |h| h.run(&step).map(|r| json!(r.code))).unwrap();
        // STOP once the trap is set (a loaded machine may take longer than any fixed wait).
        let said = |what: &str| jobs.to_json(0)["lines"].as_array().is_some_and(|l| l.iter().any(|l| l == what));
        for _ in 0..400 {
            if said("trapped") {
                break;
            }
            std::thread::sleep(Duration::from_millis(25));
        }
        assert!(said("trapped"), "{}", jobs.to_json(0));
        let asked = Instant::now();
        assert!(jobs.stop());
        let j = wait_for_end(&jobs);
        let took = asked.elapsed();
        assert_eq!(j["state"], "stopped");
        assert_eq!(j["result"], Value::Null, "killed by a signal: no exit code");
        assert!(took >= KILL_AFTER && took < KILL_AFTER + Duration::from_secs(2), "{took:?}");
        let lines = j["lines"].as_array().unwrap();
        assert!(lines.iter().any(|l| l == "interrupted"), "{lines:?}");
        assert!(!jobs.stop(), "nothing runs any more");
    }

    #[test]
    fn sticks_reach_the_flight_and_a_quiet_page_stops_it() {
        let jobs = Jobs::default();
        assert!(jobs.send_sticks("{}").unwrap_err().contains("no flight on the gamepad"));
        // Says each line it takes; SIGINT ends it as a flight's Ctrl-C does.
        let script = "trap 'echo interrupted >&2; exit 3' INT; while read line; do echo \"got $line\" >&2; done";
        let step = Step { program: "sh".into(), args: vec!["-c".into(), script.into()], sticks: true };
        let started = Instant::now();
        jobs.start(Kind::Fly, "sticks".into(), move |h| h.run(&step).map(|r| json!(r.code))).unwrap();
        let said = |what: &str| jobs.to_json(0)["lines"].as_array().is_some_and(|l| l.iter().any(|l| l == what));
        for _ in 0..400 {
            if jobs.send_sticks(r#"{"surge": 0.5}"#).is_ok() && said(r#"got {"surge": 0.5}"#) {
                break;
            }
            std::thread::sleep(Duration::from_millis(25));
        }
        assert!(said(r#"got {"surge": 0.5}"#), "{}", jobs.to_json(0));
        // Then nothing from the page: stopped PAGE_GONE later, the child interrupted.
        let last = Instant::now();
        let j = wait_for_end(&jobs);
        assert_eq!(j["state"], "stopped", "{j}");
        let took = last.elapsed();
        assert!(
            took >= PAGE_GONE && took < PAGE_GONE + Duration::from_secs(2),
            "{took:?} ({:?} in all)",
            started.elapsed()
        );
        let lines = j["lines"].as_array().unwrap();
        assert!(
            lines.iter().any(|l| l.as_str().is_some_and(|l| l.starts_with("no sticks from the page for 10 s"))),
            "{lines:?}"
        );
        assert!(lines.iter().any(|l| l == "interrupted"), "{lines:?}");
        assert!(jobs.send_sticks("{}").is_err(), "nothing takes sticks any more");
    }
}
