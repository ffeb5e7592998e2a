//! Identification of the vehicle's coefficients from trajectories (docs/MODEL.md section 10):
//! output-error least squares on the velocities one sample period ahead, the model integrated
//! over each period with the recorded input held, so the fit needs no derivative of noisy
//! data. `m`, `g`, `rho` and `izz` come from a base vehicle: the data cannot separate them
//! from the added masses (only `m - x_ud` and friends act on the motion).

use crate::dataset::TrajectorySet;
use crate::types::Input;
use crate::vehicle::{VehicleParams, body_accelerations, rk4};
use nalgebra::{DMatrix, DVector, SVector};
use serde::Serialize;

/// Coefficients taken from the base vehicle.
pub const FIXED: [&str; 4] = ["m", "g", "rho", "izz"];
/// Coefficients estimated from the data.
pub const ESTIMATED: [&str; 13] =
    ["volume", "x_ud", "y_vd", "z_wd", "n_rd", "x_u", "y_v", "z_w", "n_r", "x_uu", "y_vv", "z_ww", "n_rr"];
/// The degrees of freedom whose velocities are fitted.
pub const DOF: [&str; 4] = ["u", "v", "w", "r"];
/// A coefficient whose standard error exceeds this fraction of what it is judged against
/// ([`judged_against`]) is not identifiable from the data and keeps the base value.
pub const MAX_RELATIVE_STD_ERR: f64 = 0.2;

/// What a coefficient's standard error is judged against, given the data's RMS body
/// velocities `speeds` (`[u, v, w, r]`):
/// - an added mass or inertia by the effective mass or inertia it makes (`m - x_ud`,
///   `izz - n_rd`). The motion sees only the effective mass, and the added part is the
///   difference between the vehicle's and the base file's: where the base's `m` or `izz` is
///   already close, that difference is near zero and no recording would bring its standard
///   error under a fraction of it (ArduSub's simulator: `izz - n_rd` 0.268 against a base
///   `izz` of 0.245 leaves `n_rd` at -0.023), while the effective inertia is well determined.
/// - a damping term by the axis's whole damping at the data's RMS speed, per unit of speed
///   (`|n_r| + |n_rr| r_rms` for both yaw terms, in the term's own units). A vehicle with no
///   linear damping (the simulator's) has a linear term near zero, which no data determines
///   relative to itself; dropped, it took the base's value (-4.64 for the yaw), and the fit
///   bent the inertia and the quadratic term around it.
/// - the volume by itself.
pub fn judged_against(p: &VehicleParams, key: &str, speeds: [f64; 4]) -> f64 {
    let damping = |linear: f64, quadratic: f64, speed: f64, of_linear: bool| {
        let speed = speed.max(1e-6);
        let per_speed = linear.abs() + quadratic.abs() * speed;
        if of_linear { per_speed } else { per_speed / speed }
    };
    match key {
        "x_ud" | "y_vd" | "z_wd" => p.m - get(p, key),
        "n_rd" => p.izz - p.n_rd,
        "x_u" | "x_uu" => damping(p.x_u, p.x_uu, speeds[0], key == "x_u"),
        "y_v" | "y_vv" => damping(p.y_v, p.y_vv, speeds[1], key == "y_v"),
        "z_w" | "z_ww" => damping(p.z_w, p.z_ww, speeds[2], key == "z_w"),
        "n_r" | "n_rr" => damping(p.n_r, p.n_rr, speeds[3], key == "n_r"),
        _ => get(p, key),
    }
    .abs()
}
/// Sample periods integrated per residual: the effect of a coefficient grows with the
/// horizon while the noise of the start and end measurements does not, and a start's noise
/// enters the regressors that the one-period equation error would correlate with.
pub const HORIZON: usize = 4;
/// Longest RK4 sub-step (s): 0.02 s keeps the integration error of a period under 1e-8 of
/// the velocity change, far below any measurement.
const MAX_SUBSTEP: f64 = 0.02;
const P: usize = ESTIMATED.len();

type Velocities = SVector<f64, 4>;

/// [`HORIZON`] consecutive sample periods: the velocities at both ends and the inputs held
/// over each period.
#[derive(Debug, Clone, Copy)]
struct Interval {
    v0: Velocities,
    inputs: [Input; HORIZON],
    v1: Velocities,
    dt: f64,
}

/// Why identification could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    /// Fewer sample periods than coefficients to fit.
    #[error("{found} sample periods, identification needs at least {needed}")]
    TooFewSamples {
        /// Periods available.
        found: usize,
        /// Periods needed.
        needed: usize,
    },
    /// The base vehicle is not a valid model.
    #[error("base vehicle: {0}")]
    BadBase(#[from] crate::vehicle::ParamsError),
    /// Nothing in the data excites any coefficient.
    #[error("the data excite none of the coefficients (every one is not identifiable)")]
    NothingIdentifiable,
}

/// The identified vehicle with its uncertainty.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Identification {
    /// The base vehicle with every identifiable coefficient replaced by its estimate.
    pub vehicle: VehicleParams,
    /// Standard error of each estimated coefficient (`None` for fixed and not identifiable
    /// ones), in [`ESTIMATED`] order.
    pub std_err: Vec<(&'static str, Option<f64>)>,
    /// Coefficients the data do not excite (they keep the base value).
    pub not_identifiable: Vec<&'static str>,
    /// RMS of the velocity residuals [`HORIZON`] periods ahead, `[u, v, w, r]` (m/s, rad/s).
    pub rms_residual: [f64; 4],
    /// Sample periods used.
    pub samples: usize,
    /// RMS of each body velocity `[u, v, w, r]` over the data: the speeds the damping terms
    /// are judged at ([`judged_against`]).
    pub speeds: [f64; 4],
}

impl Identification {
    /// The standard error of `key`, if it was estimated.
    pub fn std_err_of(&self, key: &str) -> Option<f64> {
        self.std_err.iter().find(|(k, _)| *k == key).and_then(|(_, s)| *s)
    }
}

/// Whether any coefficient of [`ESTIMATED`] differs between `a` and `b` by more than
/// `tolerance` of the larger (an identification that feeds its own estimate has converged
/// when none does).
pub fn any_moved(a: &VehicleParams, b: &VehicleParams, tolerance: f64) -> bool {
    ESTIMATED.iter().any(|k| {
        let (x, y) = (get(a, k), get(b, k));
        (x - y).abs() > tolerance * x.abs().max(y.abs()).max(1e-9)
    })
}

fn get(p: &VehicleParams, key: &str) -> f64 {
    p.named().into_iter().find(|(k, _)| *k == key).map(|(_, v)| v).expect("ESTIMATED names are fields")
}

fn set(p: &mut VehicleParams, key: &str, value: f64) {
    *p.get_mut(key).expect("ESTIMATED names are fields") = value;
}

/// Keeps a trial vehicle meaningful: damping at most zero, effective masses and inertia
/// positive, a positive volume.
fn project(p: &mut VehicleParams) {
    for d in [&mut p.x_u, &mut p.y_v, &mut p.z_w, &mut p.n_r, &mut p.x_uu, &mut p.y_vv, &mut p.z_ww, &mut p.n_rr] {
        *d = d.min(0.0);
    }
    let m = p.m;
    for a in [&mut p.x_ud, &mut p.y_vd, &mut p.z_wd] {
        *a = a.min(0.999 * m);
    }
    p.n_rd = p.n_rd.min(0.999 * p.izz);
    p.volume = p.volume.max(1e-9);
}

/// The velocities [`HORIZON`] periods ahead under `p`.
fn predict(p: &VehicleParams, s: &Interval) -> Velocities {
    let n = (s.dt / MAX_SUBSTEP).ceil().max(1.0) as usize;
    let mut v = s.v0;
    for u in &s.inputs {
        let f = |v: &Velocities| Velocities::from(body_accelerations(p, [v[0], v[1], v[2], v[3]], u));
        v = rk4(f, v, s.dt / n as f64, n);
    }
    v
}

/// `f` of each 256-interval chunk, in parallel, returned in the chunks' order: callers add
/// the parts in that order, so a fit is the same bits however rayon splits the work (its own
/// `sum`/`reduce` group by where threads steal, which changes the last digits with load).
fn in_order<T: Send>(intervals: &[Interval], f: impl Fn(&[Interval]) -> T + Sync + Send) -> Vec<T> {
    use rayon::prelude::*;
    intervals.par_chunks(256).map(f).collect()
}

/// Weighted least-squares problem over the `active` coefficients, each scaled by `scale`
/// (the unknowns are relative changes, so coefficients of very different size condition alike).
struct Problem<'a> {
    intervals: &'a [Interval],
    scale: [f64; P],
    /// Residual standard deviation per degree of freedom (the weights are its inverse).
    sigma: [f64; 4],
}

impl Problem<'_> {
    /// Weighted cost `sum ((pred - v1) / sigma)^2`.
    fn cost(&self, p: &VehicleParams) -> f64 {
        in_order(self.intervals, |chunk| {
            chunk
                .iter()
                .map(|s| {
                    let r = predict(p, s) - s.v1;
                    (0..4).map(|d| (r[d] / self.sigma[d]).powi(2)).sum::<f64>()
                })
                .sum::<f64>()
        })
        .into_iter()
        .sum()
    }

    /// Unweighted RMS residual per degree of freedom, without a Jacobian.
    fn rms(&self, p: &VehicleParams) -> [f64; 4] {
        let sq = in_order(self.intervals, |chunk| {
            chunk.iter().fold([0.0; 4], |acc, s| {
                let r = predict(p, s) - s.v1;
                [0, 1, 2, 3].map(|d| acc[d] + r[d] * r[d])
            })
        })
        .into_iter()
        .fold([0.0; 4], |a, b| [0, 1, 2, 3].map(|d| a[d] + b[d]));
        let n = self.intervals.len().max(1) as f64;
        sq.map(|s| (s / n).sqrt())
    }

    /// `J^T J`, `J^T r` (weighted, J by forward differences in the scaled unknowns), the cost
    /// and the unweighted RMS residual per degree of freedom; the residuals in parallel.
    fn normal_equations(&self, p: &VehicleParams, active: &[usize]) -> (DMatrix<f64>, DVector<f64>, f64, [f64; 4]) {
        let k = active.len();
        let shifted: Vec<(VehicleParams, f64)> = active
            .iter()
            .map(|&i| {
                let h = 1e-6 * self.scale[i];
                let mut plus = *p;
                set(&mut plus, ESTIMATED[i], get(p, ESTIMATED[i]) + h);
                (plus, self.scale[i] / h)
            })
            .collect();
        let empty = || (DMatrix::<f64>::zeros(k, k), DVector::<f64>::zeros(k), 0.0, [0.0; 4]);
        let (mut jtj, jtr, cost, sq) = in_order(self.intervals, |chunk| {
            let (mut jtj, mut jtr, mut cost, mut sq) = empty();
            let mut row = vec![Velocities::zeros(); k];
            for s in chunk {
                let at = predict(p, s);
                let r = at - s.v1;
                for (j, (plus, f)) in shifted.iter().enumerate() {
                    row[j] = (predict(plus, s) - at) * *f;
                }
                for d in 0..4 {
                    let w = 1.0 / (self.sigma[d] * self.sigma[d]);
                    sq[d] += r[d] * r[d];
                    cost += r[d] * r[d] * w;
                    for a in 0..k {
                        jtr[a] += row[a][d] * r[d] * w;
                        for b in 0..=a {
                            jtj[(a, b)] += row[a][d] * row[b][d] * w;
                        }
                    }
                }
            }
            (jtj, jtr, cost, sq)
        })
        .into_iter()
        .fold(empty(), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2, [0, 1, 2, 3].map(|d| a.3[d] + b.3[d])));
        for a in 0..k {
            for b in 0..a {
                jtj[(b, a)] = jtj[(a, b)];
            }
        }
        let n = self.intervals.len().max(1) as f64;
        (jtj, jtr, cost, sq.map(|s| (s / n).sqrt()))
    }

    /// Levenberg-Marquardt from `p` over the `active` coefficients.
    fn fit(&self, mut p: VehicleParams, active: &[usize]) -> VehicleParams {
        let mut lambda = 1e-3;
        for _ in 0..100 {
            let (jtj, jtr, cost, _) = self.normal_equations(&p, active);
            let mut improved = false;
            while lambda < 1e12 {
                let mut a = jtj.clone();
                for i in 0..active.len() {
                    a[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
                }
                let Some(step) = a.cholesky().map(|c| c.solve(&(-&jtr))) else {
                    lambda *= 4.0;
                    continue;
                };
                let mut trial = p;
                for (j, &i) in active.iter().enumerate() {
                    set(&mut trial, ESTIMATED[i], get(&p, ESTIMATED[i]) + step[j] * self.scale[i]);
                }
                project(&mut trial);
                let c = self.cost(&trial);
                if c < cost {
                    let relative = (cost - c) / cost.max(f64::MIN_POSITIVE);
                    p = trial;
                    lambda = (lambda / 3.0).max(1e-12);
                    improved = relative > 1e-9 && step.amax() > 1e-8;
                    break;
                }
                lambda *= 4.0;
            }
            if !improved {
                break;
            }
        }
        p
    }
}

/// Back-to-back stretches of [`HORIZON`] periods of `sets` (network-form states: the
/// velocities are components 5..9), each from its [`TrajectorySet::start`] (the recorded
/// state unless the set carries estimated ones) to the state `HORIZON` periods on; stretches
/// do not overlap, so their residuals are independent.
fn intervals(sets: &[&TrajectorySet]) -> Vec<Interval> {
    let v = |x: &crate::State| Velocities::new(x[5], x[6], x[7], x[8]);
    let mut out = Vec::new();
    for set in sets {
        for i in 0..set.count {
            let (states, inputs) = set.trajectory(i);
            for k in (0..inputs.len() / HORIZON).map(|c| c * HORIZON) {
                let inputs = std::array::from_fn(|j| inputs[k + j]);
                // From where a prediction starts (the estimator's state where the set has
                // one) to the state it is scored against, as training does.
                let (v0, v1) = (v(&set.start(i, k)), v(&states[k + HORIZON]));
                out.push(Interval { v0, inputs, v1, dt: set.dt });
            }
        }
    }
    out
}

/// Estimates every coefficient of [`ESTIMATED`] from `sets`, starting from and keeping
/// [`FIXED`] of `base`. Coefficients the data do not excite (relative standard error above
/// [`MAX_RELATIVE_STD_ERR`]) keep the base value and are listed, worst first.
///
/// # Errors
/// Too few sample periods, an invalid base, or no coefficient identifiable.
pub fn identify(sets: &[&TrajectorySet], base: &VehicleParams) -> Result<Identification, IdentifyError> {
    base.validate()?;
    let data = intervals(sets);
    let needed = 4 * P;
    if data.len() < needed {
        // Counted in sample periods, which is what a user has.
        return Err(IdentifyError::TooFewSamples { found: data.len() * HORIZON, needed: needed * HORIZON });
    }
    let mut scale = [1.0; P];
    for (i, key) in ESTIMATED.iter().enumerate() {
        let v = get(base, key).abs();
        scale[i] = if v > 0.0 { v } else { 1.0 };
    }
    // First weights: the spread of the velocity changes, so no degree of freedom dominates.
    let mut sigma = [0.0; 4];
    for s in &data {
        for d in 0..4 {
            sigma[d] += (s.v1[d] - s.v0[d]).powi(2);
        }
    }
    let floor = |x: f64| x.max(1e-12);
    sigma = sigma.map(|s| floor((s / data.len() as f64).sqrt()));
    let mut speeds = [0.0; 4];
    for s in &data {
        for d in 0..4 {
            speeds[d] += s.v0[d] * s.v0[d];
        }
    }
    let speeds = speeds.map(|s| (s / data.len() as f64).sqrt());
    let mut problem = Problem { intervals: &data, scale, sigma };
    let mut active: Vec<usize> = (0..P).collect();
    let mut not_identifiable = Vec::new();
    let mut p = *base;
    loop {
        if active.is_empty() {
            return Err(IdentifyError::NothingIdentifiable);
        }
        p = problem.fit(p, &active);
        // Reweight by the residuals and refine once: the weights then are the noise levels,
        // which makes (J^T W J)^-1 the covariance of the estimates.
        problem.sigma = problem.rms(&p).map(floor);
        p = problem.fit(p, &active);
        let (jtj, _, _, rms) = problem.normal_equations(&p, &active);
        let covariance = jtj.clone().cholesky().map(|c| c.inverse());
        // The worst-determined coefficient: infinite when J^T W J is singular (nothing in the
        // data moves it), else its relative standard error.
        let relative = |j: usize| -> f64 {
            let i = active[j];
            match &covariance {
                Some(c) if jtj[(j, j)] > 0.0 => {
                    c[(j, j)].max(0.0).sqrt() * scale[i] / judged_against(&p, ESTIMATED[i], speeds).max(1e-300)
                }
                _ => {
                    if jtj[(j, j)] > 0.0 {
                        1.0 / (jtj[(j, j)].sqrt()) * scale[i] / judged_against(&p, ESTIMATED[i], speeds).max(1e-300)
                    } else {
                        f64::INFINITY
                    }
                }
            }
        };
        let worst = (0..active.len()).map(|j| (j, relative(j))).max_by(|a, b| a.1.total_cmp(&b.1));
        match (worst, &covariance) {
            (Some((j, rel)), cov) if rel > MAX_RELATIVE_STD_ERR || cov.is_none() => {
                let i = active.remove(j);
                not_identifiable.push(ESTIMATED[i]);
                // The others go on from their current estimates.
                set(&mut p, ESTIMATED[i], get(base, ESTIMATED[i]));
            }
            _ => {
                let c = covariance.expect("checked above");
                let std_err = ESTIMATED
                    .iter()
                    .enumerate()
                    .map(|(i, key)| {
                        let se = active.iter().position(|&a| a == i).map(|j| c[(j, j)].max(0.0).sqrt() * scale[i]);
                        (*key, se)
                    })
                    .collect();
                return Ok(Identification {
                    vehicle: p,
                    std_err,
                    not_identifiable,
                    rms_residual: rms,
                    samples: data.len() * HORIZON,
                    speeds,
                });
            }
        }
    }
}
