//! Stage 4b, the heave identified on the depth readings: the heave coefficients (added mass,
//! linear and quadratic drag, net buoyancy) fitted to the depth sensor's own readings by
//! rolling the vehicle out from the recorded thrust over whole segments, each segment's start
//! depth and heave rate fitted with them (docs/MODEL.md section 10).
//!
//! Apart from the identification because the two see the depth sensor's noise differently.
//! The identification fits velocities a few periods ahead from the smoothed estimate's, so the
//! noise of the estimate's heave rate is in its starting points: a model that damps the rate
//! faster than the vehicle does explains part of that noise, and the fit finds a linear drag
//! the vehicle does not have (ArduSub's simulator, quadratic drag only, +-0.2 m of depth
//! noise: `z_w` -6.7 and `z_ww` -47 where the simulator has 0 and -69; the same excitation
//! with the noise off: -0.2 and -66.5). Here the noise is only in what is compared, each
//! segment's start is free, and the estimate is not biased by it.

use super::open_loop_depth::DepthSegment;
use crate::identify::{Identification, MAX_RELATIVE_STD_ERR, judged_against};
use crate::types::SimState;
use crate::vehicle::{Rk4Vehicle, VehicleParams};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// The heave coefficients fitted, as the identification names them.
pub const HEAVE_KEYS: [&str; 4] = ["z_wd", "z_w", "z_ww", "volume"];
/// The scale of each unknown: the added mass (kg), the linear drag (N s/m), the quadratic drag
/// (N s^2/m^2), the net buoyancy (N), then each segment's start depth (m) and heave rate (m/s).
const SCALE: [f64; 6] = [1.0, 1.0, 10.0, 1.0, 0.1, 0.1];
/// Fewest segments for a fit: each brings two unknowns of its own.
const MIN_SEGMENTS: usize = 3;
/// A segment whose estimate comes this close to the surface (m) is left out: there the hull
/// meets the surface, its buoyancy is no longer the submerged one and the depth stops where
/// the heave equation would carry it on (ArduSub's simulator floats its vehicle at 0.13 m; a
/// recording waits there for its position source, or starts there).
pub const SURFACE_MARGIN_M: f64 = 0.3;
/// Levenberg-Marquardt iterations at most.
const MAX_ITERATIONS: usize = 60;

/// What the heave fit on the depth found.
#[derive(Debug, Clone, Serialize)]
pub struct HeaveOnDepth {
    /// The heave coefficients before (the identification's, from the velocities).
    pub from_velocities: [f64; 4],
    /// The heave coefficients fitted on the depth, in [`HEAVE_KEYS`] order (a coefficient
    /// not determined keeps the starting file's value).
    pub fitted: [f64; 4],
    /// Their standard errors (`None`: not determined).
    pub std_err: [Option<f64>; 4],
    /// Segments rolled out and readings compared.
    pub segments: usize,
    /// Depth readings compared.
    pub readings: usize,
    /// RMS of the fitted rollouts against the readings (m): the sensor's noise, if the fit
    /// explains the rest.
    pub rms_m: f64,
}

/// The value of unknown `i` of `p` (the net buoyancy for the volume).
fn get(p: &VehicleParams, i: usize) -> f64 {
    match i {
        0 => p.z_wd,
        1 => p.z_w,
        2 => p.z_ww,
        _ => p.net_buoyancy(),
    }
}

fn set(p: &mut VehicleParams, i: usize, v: f64) {
    match i {
        0 => p.z_wd = v.min(0.999 * p.m),
        1 => p.z_w = v.min(0.0),
        2 => p.z_ww = v.min(0.0),
        _ => p.volume = ((p.m * p.g - v) / (p.rho * p.g)).max(1e-9),
    }
}

/// The unknowns: the active heave coefficients, then each segment's start depth and rate.
struct Problem<'a> {
    segments: &'a [DepthSegment],
    dt: f64,
    active: Vec<usize>,
}

impl Problem<'_> {
    fn len(&self) -> usize {
        self.active.len() + 2 * self.segments.len()
    }

    /// The vehicle and the segments' starts at the unknowns `x` (each a multiple of its scale,
    /// added to `p` and the smoothed starts).
    fn at(&self, p: &VehicleParams, x: &DVector<f64>) -> (VehicleParams, Vec<SimState>) {
        let mut q = *p;
        for (j, &i) in self.active.iter().enumerate() {
            set(&mut q, i, get(p, i) + x[j] * SCALE[i]);
        }
        let k = self.active.len();
        let starts = self
            .segments
            .iter()
            .enumerate()
            .map(|(s, seg)| {
                let mut start = seg.start;
                start[2] += x[k + 2 * s] * SCALE[4];
                start[6] += x[k + 2 * s + 1] * SCALE[5];
                start
            })
            .collect();
        (q, starts)
    }

    /// Each segment's rollout less its readings.
    fn residuals_of(&self, q: &VehicleParams, starts: &[SimState], only: Option<usize>) -> Vec<Vec<f64>> {
        let physics = Rk4Vehicle { params: *q, ..Rk4Vehicle::with_dt(self.dt) };
        self.segments
            .iter()
            .zip(starts)
            .enumerate()
            .map(|(s, (seg, start))| {
                if only.is_some_and(|o| o != s) {
                    return Vec::new();
                }
                seg.rollout(&physics, start).iter().zip(&seg.readings).map(|(p, (_, z))| p - z).collect()
            })
            .collect()
    }

    fn residuals(&self, p: &VehicleParams, x: &DVector<f64>) -> DVector<f64> {
        let (q, starts) = self.at(p, x);
        DVector::from_iterator(self.readings(), self.residuals_of(&q, &starts, None).into_iter().flatten())
    }

    fn readings(&self) -> usize {
        self.segments.iter().map(|s| s.readings.len()).sum()
    }

    /// The Jacobian of the residuals in the unknowns, by forward differences: a heave
    /// coefficient moves every segment, a segment's start only its own.
    fn jacobian(&self, p: &VehicleParams, x: &DVector<f64>, r: &DVector<f64>) -> DMatrix<f64> {
        const H: f64 = 1e-6;
        let mut j = DMatrix::zeros(r.len(), self.len());
        let offsets: Vec<usize> = self
            .segments
            .iter()
            .scan(0, |o, s| {
                let at = *o;
                *o += s.readings.len();
                Some(at)
            })
            .collect();
        for c in 0..self.len() {
            let mut shifted = x.clone();
            shifted[c] += H;
            let (q, starts) = self.at(p, &shifted);
            let only = (c >= self.active.len()).then(|| (c - self.active.len()) / 2);
            for (s, res) in self.residuals_of(&q, &starts, only).into_iter().enumerate() {
                for (n, v) in res.into_iter().enumerate() {
                    let row = offsets[s] + n;
                    j[(row, c)] = (v - r[row]) / H;
                }
            }
        }
        j
    }

    /// Levenberg-Marquardt from zero; the unknowns found, `J^T J` there and the residuals.
    fn solve(&self, p: &VehicleParams) -> (DVector<f64>, DMatrix<f64>, DVector<f64>) {
        let mut x = DVector::zeros(self.len());
        let mut r = self.residuals(p, &x);
        let mut lambda = 1e-3;
        for _ in 0..MAX_ITERATIONS {
            let j = self.jacobian(p, &x, &r);
            let (jtj, jtr) = (j.transpose() * &j, j.transpose() * &r);
            let cost = r.norm_squared();
            let mut improved = false;
            while lambda < 1e12 {
                let mut a = jtj.clone();
                for i in 0..a.nrows() {
                    a[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
                }
                let Some(step) = a.cholesky().map(|c| c.solve(&(-&jtr))) else {
                    lambda *= 4.0;
                    continue;
                };
                let trial = &x + &step;
                let rt = self.residuals(p, &trial);
                let c = rt.norm_squared();
                if c < cost {
                    improved = (cost - c) / cost.max(f64::MIN_POSITIVE) > 1e-10;
                    (x, r) = (trial, rt);
                    lambda = (lambda / 3.0).max(1e-12);
                    break;
                }
                lambda *= 4.0;
            }
            if !improved {
                break;
            }
        }
        let j = self.jacobian(p, &x, &r);
        (x, j.transpose() * &j, r)
    }
}

/// The heave of `id`'s vehicle fitted on the depth readings of `segments` (the replays' whole
/// segments, their steps `dt` apart), from the identification's values; a coefficient whose
/// standard error is over [`MAX_RELATIVE_STD_ERR`] of what it is judged against (as the
/// identification judges it) takes `base`'s value and the others are fitted again. `None`
/// with too few segments, or with nothing determined.
pub(super) fn heave_on_depth(
    id: &Identification,
    base: &VehicleParams,
    segments: &[DepthSegment],
    dt: f64,
) -> Option<HeaveOnDepth> {
    let submerged: Vec<DepthSegment> =
        segments.iter().filter(|s| s.shallowest() >= SURFACE_MARGIN_M).cloned().collect();
    let segments = &submerged[..];
    if segments.len() < MIN_SEGMENTS {
        return None;
    }
    let from_velocities = heave_of(&id.vehicle);
    let mut p = id.vehicle;
    let mut problem = Problem { segments, dt, active: (0..4).collect() };
    loop {
        if problem.active.is_empty() {
            return None;
        }
        let (x, jtj, r) = problem.solve(&p);
        let dof = (r.len() as f64 - problem.len() as f64).max(1.0);
        let sigma2 = r.norm_squared() / dof;
        let covariance = jtj.cholesky().map(|c| c.inverse());
        let (fitted, _) = problem.at(&p, &x);
        // A coefficient held at its bound (a drag that would push, an added mass that would
        // leave no mass) is what the data do not want of it: it takes the starting file's
        // value and the rest are fitted again (ArduSub's simulator, no linear heave drag: its
        // `z_w` comes out at 0).
        let held = problem.active.iter().enumerate().position(|(j, &i)| {
            // The same sum `set` was given: unequal only where it clamped.
            i != 3 && get(&fitted, i) != get(&p, i) + x[j] * SCALE[i]
        });
        if let Some(j) = held {
            let i = problem.active.remove(j);
            set(&mut p, i, get(base, i));
            continue;
        }
        // Each coefficient's standard error in its own units (the volume's from the net
        // buoyancy's), relative to what the identification judges it against.
        let std_err: Vec<f64> = problem
            .active
            .iter()
            .enumerate()
            .map(|(j, &i)| {
                let se = covariance.as_ref().map_or(f64::INFINITY, |c| (sigma2 * c[(j, j)].max(0.0)).sqrt() * SCALE[i]);
                if i == 3 { se / (fitted.rho * fitted.g) } else { se }
            })
            .collect();
        let relative = |j: usize| {
            let key = HEAVE_KEYS[problem.active[j]];
            std_err[j] / judged_against(&fitted, key, id.speeds).max(1e-300)
        };
        let worst = (0..problem.active.len()).map(|j| (j, relative(j))).max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((j, rel)) if rel > MAX_RELATIVE_STD_ERR || !rel.is_finite() => {
                let i = problem.active.remove(j);
                set(&mut p, i, get(base, i));
            }
            _ => {
                let mut se = [None; 4];
                for (j, &i) in problem.active.iter().enumerate() {
                    se[i] = Some(std_err[j]);
                }
                let readings = r.len();
                return Some(HeaveOnDepth {
                    from_velocities,
                    fitted: heave_of(&fitted),
                    std_err: se,
                    segments: segments.len(),
                    readings,
                    rms_m: (r.norm_squared() / readings.max(1) as f64).sqrt(),
                });
            }
        }
    }
}

impl HeaveOnDepth {
    /// `id` with its heave coefficients, their standard errors and the list of those not
    /// determined replaced by this fit's.
    pub(super) fn apply_to(&self, id: &mut Identification) {
        [id.vehicle.z_wd, id.vehicle.z_w, id.vehicle.z_ww, id.vehicle.volume] = self.fitted;
        for (key, se) in HEAVE_KEYS.iter().zip(self.std_err) {
            if let Some(slot) = id.std_err.iter_mut().find(|(k, _)| k == key) {
                slot.1 = se;
            }
            id.not_identifiable.retain(|k| k != key);
            if se.is_none() {
                id.not_identifiable.push(key);
            }
        }
    }
}

/// `p`'s heave coefficients in [`HEAVE_KEYS`] order.
fn heave_of(p: &VehicleParams) -> [f64; 4] {
    [p.z_wd, p.z_w, p.z_ww, p.volume]
}
