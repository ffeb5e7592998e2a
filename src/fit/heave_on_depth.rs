//! Stage 4b, the heave identified on the depth readings: the heave coefficients (added mass,
//! linear and quadratic drag, net buoyancy) fitted to the depth sensor's own readings by
//! rolling the vehicle out from the recorded thrust over whole segments, each segment's start
//! depth and heave rate fitted with them (docs/MODEL.md section 10.1).
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
    /// Those the readings pushed to a bound (a drag that would push, an added mass that would
    /// leave no mass): they keep the starting file's value.
    pub held_at_bound: Vec<&'static str>,
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

/// The bound of unknown `i` (a drag cannot push, an added mass cannot leave no mass).
fn bound(p: &VehicleParams, i: usize) -> f64 {
    match i {
        0 => 0.999 * p.m,
        1 | 2 => 0.0,
        _ => f64::INFINITY,
    }
}

fn set(p: &mut VehicleParams, i: usize, v: f64) {
    let v = v.min(bound(p, i));
    match i {
        0 => p.z_wd = v,
        1 => p.z_w = v,
        2 => p.z_ww = v,
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

    /// Each active coefficient's standard error in its own units (the volume's from the net
    /// buoyancy's), from `J^T J` and the residuals `r` at `fitted`.
    fn std_errors(&self, fitted: &VehicleParams, jtj: DMatrix<f64>, r: &DVector<f64>) -> Vec<f64> {
        let dof = (r.len() as f64 - self.len() as f64).max(1.0);
        let sigma2 = r.norm_squared() / dof;
        let diagonal = jtj.diagonal();
        let covariance = jtj.cholesky().map(|c| c.inverse());
        self.active
            .iter()
            .enumerate()
            .map(|(j, &i)| {
                // Without the inverse (J'J singular) the diagonal alone, as the identification
                // does: nothing in the readings moves a coefficient whose column is zero.
                let variance = match &covariance {
                    Some(c) => c[(j, j)].max(0.0),
                    None if diagonal[j] > 0.0 => 1.0 / diagonal[j],
                    None => f64::INFINITY,
                };
                let se = (sigma2 * variance).sqrt() * SCALE[i];
                if i == 3 { se / (fitted.rho * fitted.g) } else { se }
            })
            .collect()
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
/// with too few segments, with nothing determined, or where the fit explains the readings no
/// better than the identification's heave does.
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
    // What the identification's heave leaves unexplained, each segment's start fitted alone:
    // the fit on the depth is taken only where it explains the readings better.
    let (_, _, r) = Problem { segments, dt, active: Vec::new() }.solve(&id.vehicle);
    let identification_rss = r.norm_squared();
    // A coefficient the identification left at its bound starts from the starting file's
    // value: at the bound a step outward moves nothing, so nothing would pull it inward.
    let mut p = id.vehicle;
    for i in 0..3 {
        if get(&p, i) >= bound(&p, i) {
            set(&mut p, i, get(base, i));
        }
    }
    let mut problem = Problem { segments, dt, active: (0..4).collect() };
    let mut held_at_bound = Vec::new();
    loop {
        if problem.active.is_empty() {
            return None;
        }
        let (x, jtj, r) = problem.solve(&p);
        let (fitted, _) = problem.at(&p, &x);
        // A coefficient held at its bound (a drag that would push, an added mass that would
        // leave no mass) is what the data do not want of it: it takes the starting file's
        // value and the rest are fitted again (ArduSub's simulator, no linear heave drag: its
        // `z_w` comes out at 0).
        let held = problem.active.iter().position(|&i| get(&fitted, i) >= bound(&fitted, i));
        if let Some(j) = held {
            let i = problem.active.remove(j);
            set(&mut p, i, get(base, i));
            held_at_bound.push(HEAVE_KEYS[i]);
            continue;
        }
        let std_err = problem.std_errors(&fitted, jtj, &r);
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
            _ if r.norm_squared() >= identification_rss => return None,
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
                    held_at_bound,
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

    /// The report's notes: the coefficients held at a bound, said so.
    pub fn notes(&self) -> Vec<String> {
        self.held_at_bound
            .iter()
            .map(|k| {
                format!(
                    "heave: on the depth readings {k} went past its bound (a drag that would push, or an added mass \
                     that would leave no mass): the data want none of it, and it keeps the starting file's value"
                )
            })
            .collect()
    }
}

/// `p`'s heave coefficients in [`HEAVE_KEYS`] order.
fn heave_of(p: &VehicleParams) -> [f64; 4] {
    [p.z_wd, p.z_w, p.z_ww, p.volume]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::identified::{fixture, identified_on_fixture};
    use crate::fit::open_loop_depth::SEGMENT_S;
    use crate::types::Input;

    /// `id` as the identification would hand it over: `vehicle`, every heave coefficient
    /// with a standard error, the recording's RMS heave speed.
    fn identification(vehicle: VehicleParams, w_rms: f64) -> Identification {
        Identification {
            vehicle,
            std_err: HEAVE_KEYS.iter().map(|k| (*k, Some(1.0))).collect(),
            not_identifiable: Vec::new(),
            rms_residual: [0.0; 4],
            samples: 0,
            speeds: [0.0, 0.0, w_rms, 0.0],
        }
    }

    /// Segments of `truth` driven by trains of heave-force reversals (the designed
    /// excitation's shape), read every step with uniform noise of +-`noise` m, each started
    /// from the truth less a smoothed estimate's error.
    fn noisy_segments(truth: &VehicleParams, dt: f64, noise: f64) -> Vec<DepthSegment> {
        let physics = Rk4Vehicle { params: *truth, ..Rk4Vehicle::with_dt(dt) };
        let steps = (SEGMENT_S / dt).round() as usize;
        // A seeded linear congruential generator: uniform in [-1, 1).
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut uniform = move || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        };
        // Forces (N) and half-periods (steps) of the trains; the truth floats up 1 N.
        let levels = [8.0, 20.0, 40.0, 14.0, 30.0, 5.0, 50.0, 25.0];
        let halves = [12, 25, 18, 35, 10, 30, 20, 15];
        (0..levels.len())
            .map(|s| {
                let mut start = SimState::zeros();
                start[2] = 1.5;
                let inputs: Vec<Input> = (0..steps)
                    .map(|k| {
                        let sign = if (k / halves[s]) % 2 == 0 { 1.0 } else { -1.0 };
                        Input::new(0.0, 0.0, sign * levels[s], 0.0)
                    })
                    .collect();
                let times: Vec<f64> = (0..=steps).map(|k| 100.0 * s as f64 + k as f64 * dt).collect();
                let mut x = start;
                let mut readings = vec![(times[0], x[2] + noise * uniform())];
                for (k, u) in inputs.iter().enumerate() {
                    x = physics.step_sim(&x, u);
                    readings.push((times[k + 1], x[2] + noise * uniform()));
                }
                // The smoothed start is off by a few centimetres and centimetres a second.
                start[2] += 0.03 * uniform();
                start[6] += 0.03 * uniform();
                DepthSegment { start, times, inputs, readings }
            })
            .collect()
    }

    /// A vehicle with quadratic heave drag only, read by a depth sensor with +-0.2 m of
    /// uniform noise (ArduSub's simulator's), handed over with the biased heave the velocity
    /// fit found on the firmware (`z_w` -6.7, `z_ww` -47, 1 N of buoyancy off), or with its
    /// linear drag at the bound (a killed recording's fit: `z_w` 0, where a step outward moves
    /// nothing): the fit on the readings finds the truth's heave, and its residual is the
    /// sensor's noise.
    #[test]
    fn the_heave_on_noisy_depth_readings_is_the_truths() {
        let truth = VehicleParams::load(fixture("sitl_truth.toml")).unwrap();
        let dt = 0.08;
        let segments = noisy_segments(&truth, dt, 0.2);
        let mut biased = VehicleParams { z_w: -6.7, z_ww: -47.0, z_wd: 0.7, ..truth };
        biased.volume -= 1.0 / (truth.rho * truth.g);
        let at_bound = VehicleParams { z_w: 0.0, z_ww: -65.6, z_wd: 0.85, ..truth };
        for handed in [biased, at_bound] {
            the_truths_heave_from(&truth, handed, &segments, dt);
        }
    }

    fn the_truths_heave_from(truth: &VehicleParams, handed: VehicleParams, segments: &[DepthSegment], dt: f64) {
        let truth = *truth;
        let base = VehicleParams { z_w: -0.19, z_ww: -74.2, ..truth };
        let h = heave_on_depth(&identification(handed, 0.25), &base, segments, dt).unwrap();
        let mut fitted = truth;
        [fitted.z_wd, fitted.z_w, fitted.z_ww, fitted.volume] = h.fitted;
        eprintln!("{h:?}");
        assert_eq!((h.segments, h.readings), (8, 8 * 126));
        let mass = |p: &VehicleParams| p.m - p.z_wd;
        assert!((mass(&fitted) / mass(&truth) - 1.0).abs() < 0.05, "{h:?}");
        assert!((fitted.z_ww / truth.z_ww - 1.0).abs() < 0.05, "{h:?}");
        assert!((fitted.net_buoyancy() - truth.net_buoyancy()).abs() < 0.2, "{h:?}");
        // No linear drag: none found beyond its standard error, or held at zero (the base's).
        match h.std_err[1] {
            Some(se) => assert!(fitted.z_w.abs() < 2.0 * se.max(0.5), "{h:?}"),
            None => assert_eq!(fitted.z_w, base.z_w),
        }
        // Uniform noise of +-0.2 m: 0.115 m RMS.
        assert!((h.rms_m / (0.2 / 3f64.sqrt()) - 1.0).abs() < 0.1, "{h:?}");
    }

    /// Segments touching the surface are left out; too few left is no fit.
    #[test]
    fn segments_at_the_surface_are_left_out() {
        let truth = VehicleParams::load(fixture("sitl_truth.toml")).unwrap();
        let mut segments = noisy_segments(&truth, 0.08, 0.2);
        for s in segments.iter_mut().skip(2) {
            s.readings[10].1 = 0.1;
        }
        assert!(heave_on_depth(&identification(truth, 0.25), &truth, &segments, 0.08).is_none());
    }

    /// On the firmware's two recordings (stock, and the GPS's four axes; stock joystick gain),
    /// as `pinc fit` runs it: the heave the vehicle takes has the simulator's drag (69 N/(m/s)^2
    /// in true metres, 65.9 in pinc's depth, which converts the simulator's 1023.6 kg/m^3 water
    /// with 1000) within 10 % at 0.5 m/s, and its fit explains the readings down to their noise.
    #[test]
    fn the_firmwares_heave_on_its_depth_readings() {
        let simulator_z_ww = -69.0 / 1.0236f64.powi(2);
        for rec in ["stock_designed_60s.mcap", "gps_designed_90s.mcap"] {
            let found = identified_on_fixture(rec);
            let h = found.heave_on_depth.clone().unwrap();
            let v = &found.identification.vehicle;
            eprintln!("{rec}: {h:?}; the vehicle: z_wd {:.3}, z_w {:.3}, z_ww {:.2}", v.z_wd, v.z_w, v.z_ww);
            let drag = |w: f64| -(v.z_w * w + v.z_ww * w * w);
            assert!((drag(0.5) / (-simulator_z_ww * 0.25) - 1.0).abs() < 0.1, "{rec}: {h:?}");
            assert!(h.rms_m < 1.1 * found.sensors.depth_std, "{rec}: {h:?} against {}", found.sensors.depth_std);
        }
    }
}
