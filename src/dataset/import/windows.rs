//! Resampling a recorded run to the sample period, cutting it into windows where it is
//! whole, and assigning windows to splits.

use super::{ImportError, Recording, SkipCounts};
use crate::types::{Input, SimState};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

/// Relative tolerance on a time step: a step within 10 % of the log's period continues the run.
const STEP_TOLERANCE: f64 = 0.1;
/// How close `dt / period` must be to an integer for decimation.
const RATIO_TOLERANCE: f64 = 1e-3;

impl std::fmt::Display for SkipCounts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "skipped: {} rows with NaN or infinity, {} gaps, {} non-monotonic time stamps, {} rows too few for another window",
            self.non_finite_rows, self.gaps, self.non_monotonic, self.tail_rows
        )
    }
}

/// One window at the dataset's period: `points` states and `points - 1` held inputs.
#[derive(Debug, Clone, PartialEq)]
pub struct Window {
    /// Simulator-form states.
    pub states: Vec<SimState>,
    /// Inputs held over each interval (averaged when decimated).
    pub inputs: Vec<Input>,
}

/// The run's sample period: the median of its positive time steps.
fn log_period(t: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).filter(|d| d.is_finite() && *d > 0.0).collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    Some(d[d.len() / 2])
}

/// Cuts `rec` into windows of `points` samples at period `dt`: rows are used as they are when
/// the log's period is `dt`, decimated by `n` (inputs averaged over each period) when it is
/// `dt / n`. A NaN row, a gap or a time stamp that does not advance ends a stretch; each
/// stretch gives back-to-back windows (sharing their end points), and what is left over is
/// counted, never dropped silently.
///
/// # Errors
/// A log period that is neither `dt` nor an integer fraction of it.
pub fn cut_windows(rec: &Recording, dt: f64, points: usize) -> Result<(Vec<Window>, SkipCounts), ImportError> {
    let mut skips = SkipCounts::default();
    let Some(period) = log_period(&rec.t) else {
        skips.tail_rows = rec.t.len();
        return Ok((Vec::new(), skips));
    };
    let ratio = dt / period;
    let n = ratio.round();
    if n < 1.0 || (ratio - n).abs() > RATIO_TOLERANCE * ratio {
        return Err(ImportError::Malformed {
            path: rec.path.clone(),
            message: format!(
                "the log's sample period is {period} s (median time step), which is neither --dt {dt} s nor an integer fraction of it"
            ),
        });
    }
    let n = n as usize;
    let finite = |i: usize| {
        rec.t[i].is_finite()
            && rec.states[i].iter().all(|v| v.is_finite())
            && rec.inputs[i].iter().all(|v| v.is_finite())
    };
    let mut windows = Vec::new();
    let mut start = 0;
    let rows = rec.t.len();
    while start < rows {
        if !finite(start) {
            skips.non_finite_rows += 1;
            start += 1;
            continue;
        }
        // The stretch [start, end): finite rows, each step within tolerance of the period.
        let mut end = start + 1;
        while end < rows && finite(end) {
            let step = rec.t[end] - rec.t[end - 1];
            if step <= 0.0 {
                skips.non_monotonic += 1;
                break;
            }
            if (step - period).abs() > STEP_TOLERANCE * period {
                skips.gaps += 1;
                break;
            }
            end += 1;
        }
        let used = stretch_windows(rec, start, end, n, points, &mut windows);
        skips.tail_rows += end - start - used;
        start = end;
    }
    Ok((windows, skips))
}

/// Back-to-back windows from rows `[start, end)` decimated by `n`; returns the rows used.
fn stretch_windows(rec: &Recording, start: usize, end: usize, n: usize, points: usize, out: &mut Vec<Window>) -> usize {
    let rows_per_window = (points - 1) * n;
    let len = end - start;
    if len == 0 || len - 1 < rows_per_window {
        return 0;
    }
    let count = (len - 1) / rows_per_window;
    for w in 0..count {
        let first = start + w * rows_per_window;
        let states = (0..points).map(|k| rec.states[first + k * n]).collect();
        let inputs = (0..points - 1)
            .map(|k| {
                let rows = &rec.inputs[first + k * n..first + (k + 1) * n];
                let mut mean = Input::zeros();
                for u in rows {
                    mean += u;
                }
                mean / n as f64
            })
            .collect();
        out.push(Window { states, inputs });
    }
    // The windows share end points: the last row used is the last window's end.
    count * rows_per_window + 1
}

/// Windows of each split and the split of each run.
pub(super) struct Assignment {
    /// Windows of train, dev and test.
    pub windows: [Vec<Window>; 3],
    /// `train`, `dev`, `test` per run, or `time` when runs were split by time.
    pub run_split: Vec<&'static str>,
    /// Whether whole runs went to splits.
    pub by_run: bool,
}

const SPLIT_NAMES: [&str; 3] = ["train", "dev", "test"];

/// Whole runs per split when there are at least as many runs with windows as non-empty
/// fractions (so no run's windows land in two splits); otherwise each run is split by time,
/// leaving one window out between consecutive splits so they share no samples.
pub(super) fn split(per_run: &[Vec<Window>], fractions: [f64; 3], seed: u64) -> Assignment {
    let wanted: Vec<usize> = (0..3).filter(|&i| fractions[i] > 0.0).collect();
    let runs: Vec<usize> = (0..per_run.len()).filter(|&r| !per_run[r].is_empty()).collect();
    let mut windows: [Vec<Window>; 3] = Default::default();
    let mut run_split = vec!["none"; per_run.len()];
    if runs.len() >= wanted.len() {
        let mut order = runs.clone();
        order.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
        let total: usize = runs.iter().map(|&r| per_run[r].len()).sum();
        let mut have = [0usize; 3];
        // One run to each wanted split first (test, then dev, then train), then each run to the
        // split furthest below its share.
        for (k, &r) in order.iter().enumerate() {
            let s = if k < wanted.len() {
                wanted[wanted.len() - 1 - k]
            } else {
                *wanted
                    .iter()
                    .max_by(|&&a, &&b| {
                        let deficit = |i: usize| fractions[i] * total as f64 - have[i] as f64;
                        deficit(a).total_cmp(&deficit(b))
                    })
                    .expect("the fractions sum to 1, so one is wanted")
            };
            have[s] += per_run[r].len();
            windows[s].extend(per_run[r].iter().cloned());
            run_split[r] = SPLIT_NAMES[s];
        }
        return Assignment { windows, run_split, by_run: true };
    }
    for &r in &runs {
        let w = &per_run[r];
        let usable = w.len().saturating_sub(wanted.len() - 1);
        let mut counts: Vec<usize> = wanted.iter().map(|&i| (fractions[i] * usable as f64).floor() as usize).collect();
        // Hand the rounding remainder to the splits in order, at least one window each.
        let mut left = usable - counts.iter().sum::<usize>();
        for c in counts.iter_mut() {
            if *c == 0 && left > 0 {
                *c = 1;
                left -= 1;
            }
        }
        counts[0] += left;
        let mut at = 0;
        for (j, &i) in wanted.iter().enumerate() {
            let (from, to) = (at.min(w.len()), (at + counts[j]).min(w.len()));
            windows[i].extend(w[from..to].iter().cloned());
            at += counts[j] + 1;
        }
        run_split[r] = "time";
    }
    Assignment { windows, run_split, by_run: false }
}
