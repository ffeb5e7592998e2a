//! Merging a log's streams onto one time base at the dataset's sample period (docs/MODEL.md
//! section 9): states interpolated linearly (yaw unwrapped first), inputs averaged over each
//! period as the zero-order-hold signals they are, gaps left out.

use super::streams::{Series, StreamSet};
use super::{ImportError, Recording, StreamInfo, StreamReport};
use crate::types::{Input, SimState};
use crate::vehicle::wrap_angle;
use std::f64::consts::PI;
use std::path::Path;

/// A grid time within this fraction of `dt` of a sample time is that sample: a log at the
/// dataset's period is taken row by row, unchanged.
const SNAP: f64 = 1e-6;

/// A stream with sorted, finite time stamps (a repeated stamp keeps the later sample).
struct Clean<const N: usize> {
    t: Vec<f64>,
    v: Vec<[f64; N]>,
    dropped: usize,
}

fn clean<const N: usize>(s: &Series<N>) -> Clean<N> {
    let mut c = Clean { t: Vec::with_capacity(s.len()), v: Vec::with_capacity(s.len()), dropped: 0 };
    for (&t, v) in s.t.iter().zip(&s.v) {
        match c.t.last() {
            _ if !t.is_finite() => c.dropped += 1,
            Some(&last) if t < last => c.dropped += 1,
            Some(&last) if t == last => *c.v.last_mut().expect("a time has a value") = *v,
            _ => {
                c.t.push(t);
                c.v.push(*v);
            }
        }
    }
    c
}

fn median_step(t: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.0).collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    Some(d[d.len() / 2])
}

/// The default gap tolerance of a stream: three of its median periods, at least `2 dt` (a
/// shorter hole hides at most one grid point, which interpolation bridges).
pub fn default_gap_tolerance(t: &[f64], dt: f64) -> f64 {
    median_step(t).map_or(2.0 * dt, |p| (3.0 * p).max(2.0 * dt))
}

/// The period chosen from the log when `--dt` is not given: the median time step of the
/// slowest state stream (position, depth, attitude, velocities, yaw rate), rounded to the
/// nearest millisecond (at least 1 ms). `None` when no state stream has two samples.
pub fn log_dt(set: &StreamSet) -> Option<f64> {
    let steps = [
        set.position.as_ref().map(|s| median_step(&clean(s).t)),
        set.depth.as_ref().map(|s| median_step(&clean(s).t)),
        set.attitude.as_ref().map(|s| median_step(&clean(s).t)),
        set.velocity_ned.as_ref().map(|s| median_step(&clean(s).t)),
        set.velocity_body.as_ref().map(|s| median_step(&clean(s).t)),
        set.yaw_rate.as_ref().map(|s| median_step(&clean(s).t)),
    ];
    let slowest =
        steps.into_iter().flatten().flatten().fold(None, |m: Option<f64>, p| Some(m.map_or(p, |m| m.max(p))))?;
    Some(((slowest * 1000.0).round() / 1000.0).max(0.001))
}

/// A row-aligned recording (today's CSV and MCAP logs) as streams on one time base, so it goes
/// through the same resampling as every other log.
pub fn stream_set_of(rec: &Recording) -> StreamSet {
    let mut set = StreamSet {
        position: Some(Series::new("x,y,z")),
        attitude: Some(Series::new("psi (roll and pitch 0)")),
        velocity_body: Some(Series::new("u,v,w")),
        yaw_rate: Some(Series::new("r")),
        input: Some(Series::new("X,Y,Z,Mz")),
        notes: std::iter::once("one row per sample: every quantity on the row's time stamp".to_string())
            .chain(rec.notes.iter().cloned())
            .collect(),
        ..StreamSet::default()
    };
    for ((&t, s), u) in rec.t.iter().zip(&rec.states).zip(&rec.inputs) {
        set.position.as_mut().expect("set above").push(t, [s[0], s[1], s[2]]);
        set.attitude.as_mut().expect("set above").push(t, [0.0, 0.0, s[3]]);
        set.velocity_body.as_mut().expect("set above").push(t, [s[4], s[5], s[6]]);
        set.yaw_rate.as_mut().expect("set above").push(t, [s[7]]);
        set.input.as_mut().expect("set above").push(t, [u[0], u[1], u[2], u[3]]);
    }
    set
}

/// Linear interpolation of a cleaned stream along increasing query times (a cursor, so a
/// whole grid costs one pass).
struct Interp<'a, const N: usize> {
    t: &'a [f64],
    v: &'a [[f64; N]],
    i: usize,
    snap: f64,
}

impl<'a, const N: usize> Interp<'a, N> {
    fn new(t: &'a [f64], v: &'a [[f64; N]], dt: f64) -> Self {
        Self { t, v, i: 0, snap: SNAP * dt }
    }

    /// The samples around `g` and the weight of the second: `(i, i, 0)` when `g` is sample
    /// `i` (up to the snap tolerance) or past the last one.
    fn locate(&mut self, g: f64) -> (usize, usize, f64) {
        let t = self.t;
        while self.i + 1 < t.len() && t[self.i + 1] <= g {
            self.i += 1;
        }
        let i = self.i;
        if (g - t[i]).abs() <= self.snap || i + 1 == t.len() {
            return (i, i, 0.0);
        }
        if (t[i + 1] - g).abs() <= self.snap {
            return (i + 1, i + 1, 0.0);
        }
        (i, i + 1, (g - t[i]) / (t[i + 1] - t[i]))
    }

    /// The value at `g` (inside the stream's span, up to the snap tolerance).
    fn at(&mut self, g: f64) -> [f64; N] {
        let (i, j, w) = self.locate(g);
        if i == j {
            return self.v[i];
        }
        let v = self.v;
        std::array::from_fn(|k| v[i][k] + w * (v[j][k] - v[i][k]))
    }
}

/// The time-weighted mean over `[a, b]` of a signal holding each sample until the next (the
/// last held on); overlaps shorter than the snap tolerance are left out, so a period inside
/// one hold is exactly that hold's value.
fn held_mean<const N: usize>(t: &[f64], v: &[[f64; N]], a: f64, b: f64, snap: f64) -> [f64; N] {
    let first = t.partition_point(|&x| x <= a + snap).saturating_sub(1);
    let mut sum = [0.0; N];
    let mut weight = 0.0;
    let mut only: Option<usize> = None;
    let mut parts = 0;
    for j in first..t.len() {
        if t[j] >= b - snap {
            break;
        }
        let end = t.get(j + 1).copied().unwrap_or(f64::INFINITY).min(b);
        let overlap = end - t[j].max(a);
        if overlap <= snap {
            continue;
        }
        parts += 1;
        only = Some(j);
        weight += overlap;
        for k in 0..N {
            sum[k] += overlap * v[j][k];
        }
    }
    match (parts, only) {
        (1, Some(j)) => v[j],
        (0, _) => v[first],
        _ => sum.map(|s| s / weight),
    }
}

/// Yaw made continuous: each sample shifted by whole turns to lie within pi of the previous
/// finite one (NaN stays NaN).
fn unwrap(yaw: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(yaw.len());
    let mut prev: Option<f64> = None;
    for &y in yaw {
        if !y.is_finite() {
            out.push(f64::NAN);
            continue;
        }
        let u = match prev {
            Some(p) => y + 2.0 * PI * ((p - y) / (2.0 * PI)).round(),
            None => y,
        };
        prev = Some(u);
        out.push(u);
    }
    out
}

/// Body-frame velocity from NED: `R^T v` with `R = Rz(yaw) Ry(pitch) Rx(roll)`.
pub fn ned_to_body(v: [f64; 3], roll: f64, pitch: f64, yaw: f64) -> [f64; 3] {
    let (sr, cr) = roll.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let (sy, cy) = yaw.sin_cos();
    // Columns of R are the body axes in NED; R^T v is v projected onto each.
    let forward = [cy * cp, sy * cp, -sp];
    let right = [cy * sp * sr - sy * cr, sy * sp * sr + cy * cr, cp * sr];
    let down = [cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr];
    let dot = |a: [f64; 3]| a[0] * v[0] + a[1] * v[1] + a[2] * v[2];
    [dot(forward), dot(right), dot(down)]
}

fn info<const N: usize>(name: &str, s: &Series<N>, c: &Clean<N>, tol: f64) -> StreamInfo {
    let steps = c.t.windows(2).map(|w| w[1] - w[0]);
    StreamInfo {
        name: name.into(),
        source: s.source.clone(),
        samples: c.t.len(),
        rate_hz: median_step(&c.t).map(|p| 1.0 / p),
        span_s: c.t.first().map(|&a| (a, *c.t.last().expect("non-empty"))),
        gaps: steps.clone().filter(|&d| d > tol).count(),
        longest_step_s: steps.fold(0.0, f64::max),
        gap_tolerance_s: tol,
        dropped: c.dropped,
    }
}

/// One stream's cleaned times and gap tolerance, for the common span and the gaps.
struct Span {
    name: String,
    t: Vec<f64>,
    tol: f64,
}

/// A log's streams cleaned ([`clean`]), the attitude and the input always there.
struct Cleaned {
    position: Option<Clean<3>>,
    depth: Option<Clean<1>>,
    att: Clean<3>,
    vel_ned: Option<Clean<3>>,
    vel_body: Option<Clean<3>>,
    yaw_rate: Option<Clean<1>>,
    inp: Clean<4>,
    /// Every stream's span, in the order above (the input last).
    spans: Vec<Span>,
}

impl Cleaned {
    /// Cleans every stream of `set` (which has an attitude and an input), reporting each in
    /// `report` with its gap tolerance `tol_of(its times)`.
    fn new(set: &StreamSet, tol_of: &dyn Fn(&[f64]) -> f64, report: &mut StreamReport) -> Self {
        let mut spans = Vec::new();
        macro_rules! take {
            ($field:ident, $name:literal) => {
                set.$field.as_ref().map(|s| {
                    let c = clean(s);
                    let tol = tol_of(&c.t);
                    report.streams.push(info($name, s, &c, tol));
                    spans.push(Span { name: $name.to_string(), t: c.t.clone(), tol });
                    c
                })
            };
        }
        let position = take!(position, "position");
        let depth = take!(depth, "depth");
        let att = take!(attitude, "attitude").expect("checked by check_parts");
        let vel_ned = take!(velocity_ned, "velocity_ned");
        let vel_body = take!(velocity_body, "velocity_body");
        let yaw_rate = take!(yaw_rate, "yaw_rate");
        let inp = take!(input, "input").expect("checked by check_parts");
        Self { position, depth, att, vel_ned, vel_body, yaw_rate, inp, spans }
    }

    /// The time span every stream covers.
    ///
    /// # Errors
    /// A stream without a sample, or streams that share no time.
    fn common_span(&self) -> Result<(f64, f64), String> {
        let spans = &self.spans;
        for s in spans {
            if s.t.is_empty() {
                return Err(format!("the {} stream has no sample with a finite time stamp", s.name));
            }
        }
        let start = spans.iter().map(|s| s.t[0]).fold(f64::NEG_INFINITY, f64::max);
        let end = spans.iter().map(|s| *s.t.last().expect("non-empty")).fold(f64::INFINITY, f64::min);
        if end < start {
            let each: Vec<String> = spans
                .iter()
                .map(|s| format!("{} {:.3}..{:.3} s", s.name, s.t[0], s.t.last().unwrap_or(&0.0)))
                .collect();
            return Err(format!("the streams share no time span: {}", each.join(", ")));
        }
        Ok((start, end))
    }

    /// What the resampling derives for want of a stream, one note each.
    fn derivation_notes(&self) -> Vec<String> {
        let mut notes = Vec::new();
        if self.yaw_rate.is_none() {
            notes.push("yaw rate: central difference of the unwrapped yaw at the attitude samples".into());
        }
        if self.vel_body.is_none() {
            notes.push("body velocity: the NED velocity rotated by roll, pitch and yaw (R^T v)".into());
        }
        if self.depth.is_some() {
            notes.push("z: from the depth stream".into());
        }
        if self.position.is_none() {
            notes.push(
                "x, y: no position in the log; dead-reckoned from u, v and yaw (trapezoid on the grid, from 0 at each stretch)"
                    .into(),
            );
        }
        notes
    }
}

/// The parts a state is assembled from.
///
/// # Errors
/// No attitude, no input, neither position nor depth, or no velocity.
fn check_parts(set: &StreamSet) -> Result<(), String> {
    let missing = |what: &str| Err(format!("no {what} in the log: the state cannot be assembled"));
    if set.attitude.is_none() {
        return missing("attitude (yaw)");
    }
    if set.input.is_none() {
        return missing("input (body forces)");
    }
    if set.position.is_none() && set.depth.is_none() {
        return missing("position or depth");
    }
    if set.velocity_body.is_none() && set.velocity_ned.is_none() {
        return missing("velocity (body or NED)");
    }
    Ok(())
}

/// The grid times, and where each stretch between gaps starts in them.
#[derive(Default)]
struct Grid {
    t: Vec<f64>,
    stretch_starts: Vec<usize>,
}

impl Grid {
    /// Points every `dt` over `[start, end]`, none strictly inside a gap of any span; each
    /// stretch starts at a gap's end (at least 1.5 `dt` after the last point).
    fn new(spans: &[Span], start: f64, end: f64, dt: f64) -> Self {
        // Gap interiors of every stream, merged.
        let mut gaps: Vec<(f64, f64)> = spans
            .iter()
            .flat_map(|s| s.t.windows(2).filter(|w| w[1] - w[0] > s.tol).map(|w| (w[0], w[1])).collect::<Vec<_>>())
            .collect();
        gaps.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut grid = Self::default();
        let mut cur = start;
        for &(a, b) in &gaps {
            if b <= cur || a >= end {
                if a >= end {
                    break;
                }
                continue;
            }
            if a >= cur {
                grid.push_stretch(cur, a, dt);
            }
            cur = b;
        }
        if cur <= end {
            grid.push_stretch(cur, end, dt);
        }
        grid
    }

    /// One stretch of points from `from` (or 1.5 `dt` after the last point) up to `to`.
    fn push_stretch(&mut self, from: f64, to: f64, dt: f64) {
        let from = self.t.last().map_or(from, |&l| from.max(l + 1.5 * dt));
        if to < from - SNAP * dt {
            return;
        }
        self.stretch_starts.push(self.t.len());
        let n = ((to - from) / dt + SNAP).floor() as usize;
        self.t.extend((0..=n).map(|k| from + k as f64 * dt));
    }
}

/// The attitude with its yaw unwrapped, and the yaw rate derived from it for a log without one.
struct Unwrapped {
    yaw: Vec<f64>,
    /// Roll and pitch as logged, the unwrapped yaw.
    att: Vec<[f64; 3]>,
    /// The central difference of the unwrapped yaw at the attitude samples (one-sided at the
    /// ends and next to gaps), when the log has no yaw rate.
    derived_r: Option<Vec<[f64; 1]>>,
}

impl Unwrapped {
    /// `rate_tol`: the gap tolerance of the attitude when the rate is derived, `None` when the
    /// log has a yaw rate.
    fn new(att: &Clean<3>, rate_tol: Option<f64>) -> Self {
        let yaw = unwrap(&att.v.iter().map(|v| v[2]).collect::<Vec<_>>());
        let unwrapped = att.v.iter().zip(&yaw).map(|(v, &y)| [v[0], v[1], y]).collect();
        let derived_r = rate_tol.map(|tol| {
            let t = &att.t;
            (0..t.len())
                .map(|i| {
                    let lo = if i > 0 && t[i] - t[i - 1] <= tol { i - 1 } else { i };
                    let hi = if i + 1 < t.len() && t[i + 1] - t[i] <= tol { i + 1 } else { i };
                    [if hi > lo { (yaw[hi] - yaw[lo]) / (t[hi] - t[lo]) } else { f64::NAN }]
                })
                .collect()
        });
        Self { yaw, att: unwrapped, derived_r }
    }
}

/// The state at each grid time: position (z from the depth where there is one, x and y NaN
/// without a position), the yaw wrapped back, body velocities given or rotated from NED, the
/// yaw rate given or derived.
fn states_on(grid: &[f64], c: &Cleaned, unwrapped: &Unwrapped, dt: f64) -> Vec<SimState> {
    let att = &c.att;
    let mut att_i = Interp::new(&att.t, &unwrapped.att, dt);
    let mut pos_i = c.position.as_ref().map(|c| Interp::new(&c.t, &c.v, dt));
    let mut depth_i = c.depth.as_ref().map(|c| Interp::new(&c.t, &c.v, dt));
    let mut ned_i = c.vel_ned.as_ref().map(|c| Interp::new(&c.t, &c.v, dt));
    let mut body_i = c.vel_body.as_ref().map(|c| Interp::new(&c.t, &c.v, dt));
    let mut r_i = match (&c.yaw_rate, &unwrapped.derived_r) {
        (Some(c), _) => Interp::new(&c.t, &c.v, dt),
        (None, Some(r)) => Interp::new(&att.t, r, dt),
        (None, None) => unreachable!("derived when not given"),
    };
    let mut states = Vec::with_capacity(grid.len());
    for &g in grid {
        let (i, j, wy) = att_i.locate(g);
        let [roll, pitch, yaw] = att_i.at(g);
        // Snapped to a sample, the logged yaw comes back exactly (no turn added and removed).
        let psi = if i == j && att.v[i][2] > -PI && att.v[i][2] <= PI {
            att.v[i][2]
        } else if i == j {
            wrap_angle(att.v[i][2])
        } else {
            wrap_angle(unwrapped.yaw[i] + wy * (unwrapped.yaw[j] - unwrapped.yaw[i]))
        };
        let p = pos_i.as_mut().map_or([f64::NAN; 3], |i| i.at(g));
        let z = depth_i.as_mut().map_or(p[2], |i| i.at(g)[0]);
        let [u, v, w] = match (&mut body_i, &mut ned_i) {
            (Some(b), _) => b.at(g),
            (None, Some(n)) => ned_to_body(n.at(g), roll, pitch, yaw),
            (None, None) => unreachable!("checked above"),
        };
        let r = r_i.at(g)[0];
        states.push(SimState::from([p[0], p[1], z, psi, u, v, w, r]));
    }
    states
}

/// x and y dead-reckoned from u, v and yaw: the trapezoid rule on the grid, from 0 at the start
/// of each stretch.
fn dead_reckon(states: &mut [SimState], stretch_starts: &[usize], dt: f64) {
    for (s, &from) in stretch_starts.iter().enumerate() {
        let to = stretch_starts.get(s + 1).copied().unwrap_or(states.len());
        let (mut x, mut y) = (0.0, 0.0);
        for k in from..to {
            if k > from {
                let vel = |st: &SimState| {
                    let (sn, cs) = st[3].sin_cos();
                    (cs * st[4] - sn * st[5], sn * st[4] + cs * st[5])
                };
                let (a, b) = (vel(&states[k - 1]), vel(&states[k]));
                x += 0.5 * dt * (a.0 + b.0);
                y += 0.5 * dt * (a.1 + b.1);
            }
            states[k][0] = x;
            states[k][1] = y;
        }
    }
}

/// Resamples a log's streams onto a grid of period `dt` over their common span.
///
/// - States: position (z from `depth` where there is one) linearly interpolated; yaw unwrapped,
///   interpolated, wrapped to `(-pi, pi]`; body velocities given, or `R^T v_ned` with
///   `R = Rz(yaw) Ry(pitch) Rx(roll)` at each grid time; yaw rate given, or the central
///   difference of the unwrapped yaw at the attitude samples (one-sided at the ends and next
///   to gaps), interpolated. Without position, x and y are dead-reckoned from u, v and yaw
///   (trapezoid on the grid, from 0 at each stretch; a note says so).
/// - Inputs: the time-weighted mean over each period of the held values (the held value
///   itself when the period lies inside one hold).
/// - Gaps: a step longer than the tolerance (`gap_tolerance` for every stream, or per stream
///   [`default_gap_tolerance`] when it is `None`) in any stream removes the grid points
///   strictly inside it; the grid starts again at the gap's end (at least 1.5 `dt` after the
///   last point, so the windowing sees the break and counts it). A NaN sample gives NaN at
///   the grid points that use it, which the windowing skips and counts.
///
/// The stages: the parts checked, every stream cleaned and reported (`Cleaned`), the common span,
/// the grid between the gaps (`Grid`), the yaw unwrapped (`Unwrapped`), the notes,
/// the states on the grid, x and y dead-reckoned without a position, the inputs averaged.
///
/// # Errors
/// No attitude, no input, neither position nor depth, no velocity, a stream without samples,
/// or streams that do not overlap in time.
pub fn resample(
    set: &StreamSet,
    dt: f64,
    gap_tolerance: Option<f64>,
    path: &Path,
) -> Result<(Recording, StreamReport), ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    check_parts(set).map_err(malformed)?;
    let tol_of = |t: &[f64]| gap_tolerance.unwrap_or_else(|| default_gap_tolerance(t, dt));
    let mut report = StreamReport { streams: Vec::new(), notes: set.notes.clone() };
    let cleaned = Cleaned::new(set, &tol_of, &mut report);
    let (start, end) = cleaned.common_span().map_err(malformed)?;
    let grid = Grid::new(&cleaned.spans, start, end, dt);
    let unwrapped = Unwrapped::new(&cleaned.att, cleaned.yaw_rate.is_none().then(|| tol_of(&cleaned.att.t)));
    report.notes.extend(cleaned.derivation_notes());
    let mut states = states_on(&grid.t, &cleaned, &unwrapped, dt);
    if cleaned.position.is_none() {
        dead_reckon(&mut states, &grid.stretch_starts, dt);
    }
    let snap = SNAP * dt;
    let inp = &cleaned.inp;
    let inputs = grid.t.iter().map(|&g| Input::from(held_mean(&inp.t, &inp.v, g, g + dt, snap))).collect();
    Ok((Recording { path: path.to_path_buf(), t: grid.t, states, inputs, notes: Vec::new() }, report))
}
