//! The sensor model of a vehicle from its own recordings: the noise of each reading from the
//! reading alone, the depth sensor's lag against the autopilot's vertical velocity or the
//! heave equation (docs/FIT.md).

use crate::estimation::Measurement;
pub use crate::estimation::white_noise_std;
use crate::model::SensorModel;

/// Smallest standard deviations a fit gives (m, rad, rad/s): below them the filter would
/// trust a reading more than its resolution and the autopilot's own filtering justify. The
/// heading's is the live default's, 0.02 rad: the autopilot's heading is its EKF's, smooth
/// sample to sample (0.002 rad of white noise on ArduSub's simulator) but wandering with its
/// compass corrections, which no comparison of a reading with its neighbours sees. Told 0.002,
/// the filter followed that wander: on the firmware a fitted model held its heading 0.220-0.223
/// deg off the truth (the simulator's file 0.182-0.214), told 0.02 0.177-0.207.
pub const NOISE_FLOOR: [f64; 3] = [0.005, 0.02, 0.001];

/// Smallest standard deviations a fit gives the horizontal position (m) and NED velocity
/// (m/s), as [`NOISE_FLOOR`] does the others.
pub const HORIZONTAL_NOISE_FLOOR: [f64; 2] = [0.01, 0.01];

/// The noise of the horizontal readings a position source gives (what the estimator is told
/// for them in a fit's replays).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HorizontalNoise {
    /// Position, north and east (m).
    pub position_std: f64,
    /// NED velocity, north and east (m/s).
    pub velocity_std: f64,
}

/// The white noise of the position's and the NED velocity's north and east readings (the
/// larger of the two axes), at least [`HORIZONTAL_NOISE_FLOOR`]; `None` for a kind with too
/// few readings (no position source, or too short a recording).
pub fn horizontal_noise(measurements: &[Measurement]) -> [Option<f64>; 2] {
    let mut series: [Vec<(f64, f64)>; 4] = Default::default();
    for m in measurements {
        match *m {
            Measurement::Position { t, x, y, .. } => {
                series[0].push((t, x));
                series[1].push((t, y));
            }
            Measurement::VelocityNed { t, vn, ve, .. } => {
                series[2].push((t, vn));
                series[3].push((t, ve));
            }
            _ => {}
        }
    }
    for s in &mut series {
        // A repeated reading is the source read faster than it updates, as in `readings`.
        s.dedup_by(|b, a| b.1 == a.1);
    }
    let noise = |a: &[(f64, f64)], b: &[(f64, f64)], floor: f64| {
        let (a, b) = (white_noise_std(a, false)?, white_noise_std(b, false)?);
        Some(a.max(b).max(floor))
    };
    [noise(&series[0], &series[1], HORIZONTAL_NOISE_FLOOR[0]), noise(&series[2], &series[3], HORIZONTAL_NOISE_FLOOR[1])]
}

/// Depth lags the fit tries (s): 0 to 0.3 in steps of 0.02.
pub fn lag_candidates() -> Vec<f64> {
    (0..=15).map(|i| f64::from(i) * 0.02).collect()
}

/// Half-width (s) of the local quadratic that differentiates the depth reading.
const DERIVATIVE_HALF_WIDTH: f64 = 0.5;
/// Spacing (s) of the times the heave equation is checked at.
const LAG_GRID: f64 = 0.04;

/// The depth reading's lag from the heave equation alone: a sensor that reads `z(t - tau)`
/// has `z_m''(t) = (Z(t - tau) - D(z_m'(t)) + B) / m`, so the lag is the shift of the applied
/// heave force that best explains the reading's acceleration by a force, a linear and a
/// quadratic drag of the reading's own rate and a constant. The rate and acceleration come
/// from a local quadratic over +-0.5 s of readings (symmetric: it shifts nothing); no
/// coefficient of the vehicle enters. Returns each candidate lag with its residual sum of
/// squares, or `None` with too few readings (under 100 usable times).
///
/// `heave` is the applied heave force as a step function: `(t, Z)` from `t` on.
pub fn depth_lag_scan(depth: &[(f64, f64)], heave: &[(f64, f64)], lags: &[f64]) -> Option<Vec<(f64, f64)>> {
    let (Some(first), Some(last)) = (depth.first(), depth.last()) else { return None };
    let h = DERIVATIVE_HALF_WIDTH;
    // Rate and acceleration of the reading at grid times with readings all around.
    let mut points = Vec::new();
    let mut lo = 0;
    let mut t = first.0 + h;
    while t <= last.0 - h {
        while lo < depth.len() && depth[lo].0 < t - h {
            lo += 1;
        }
        let hi = depth[lo..].iter().position(|&(s, _)| s > t + h).map_or(depth.len(), |k| lo + k);
        let window = &depth[lo..hi];
        // At least 8 readings, and no gap of more than a third of the window.
        let gapless = window.windows(2).all(|w| w[1].0 - w[0].0 < 2.0 * h / 3.0);
        if let Some((rate, accel)) = (window.len() >= 8 && gapless).then(|| local_quadratic(window, t)).flatten() {
            points.push((t, rate, accel));
        }
        t += LAG_GRID;
    }
    if points.len() < 100 {
        return None;
    }
    let force_at = |t: f64| -> Option<f64> {
        let k = heave.partition_point(|&(s, _)| s <= t);
        (k > 0).then(|| heave[k - 1].1)
    };
    let scan = lags
        .iter()
        .map(|&lag| {
            let rows: Vec<([f64; 4], f64)> = points
                .iter()
                .filter_map(|&(t, rate, accel)| {
                    force_at(t - lag).map(|force| ([force, rate, rate.abs() * rate, 1.0], accel))
                })
                .collect();
            (lag, least_squares_residual(&rows))
        })
        .collect();
    Some(scan)
}

/// Length (s) of the blocks over which the integrated vertical velocity may drift from the
/// depth by a constant (its bias, the unknown start).
const DRIFT_BLOCK: f64 = 10.0;
/// A gap between vertical velocities longer than this (s) ends an integration.
const VELOCITY_GAP: f64 = 1.0;

/// The depth reading's lag against the autopilot's vertical velocity: its integral is the
/// depth's shape with no lag of its own (the velocity is fused from accelerometers), so a
/// sensor that reads `z(t - tau)` matches the integral shifted by `tau` best. The integral
/// (trapezoid, restarted at a gap of over 1 s) may drift from the depth by a constant per
/// 10 s block; each candidate's residual sum of squares is taken after those constants.
/// Returns each candidate lag with its residual, or `None` with under 100 usable readings.
pub fn depth_lag_from_vertical_velocity(
    depth: &[(f64, f64)],
    vertical_velocity: &[(f64, f64)],
    lags: &[f64],
) -> Option<Vec<(f64, f64)>> {
    // (t, integral, segment) at every velocity sample.
    let mut integral: Vec<(f64, f64, usize)> = Vec::with_capacity(vertical_velocity.len());
    let mut segment = 0;
    for (k, &(t, vd)) in vertical_velocity.iter().enumerate() {
        let z = match k.checked_sub(1).map(|j| vertical_velocity[j]) {
            Some((t0, v0)) if t - t0 <= VELOCITY_GAP && t > t0 => integral[k - 1].1 + 0.5 * (vd + v0) * (t - t0),
            Some(_) => {
                segment += 1;
                0.0
            }
            None => 0.0,
        };
        integral.push((t, z, segment));
    }
    let integral_at = |t: f64| -> Option<(f64, usize)> {
        let k = integral.partition_point(|&(s, _, _)| s <= t);
        let (a, b) = (integral.get(k.checked_sub(1)?)?, integral.get(k)?);
        (a.2 == b.2).then(|| (a.1 + (b.1 - a.1) * (t - a.0) / (b.0 - a.0), a.2))
    };
    // The readings every candidate can compare, each in one integration segment: its group
    // (segment, block) and the depth minus the integral shifted by each lag.
    let usable: Vec<((usize, i64), Vec<f64>)> = depth
        .iter()
        .filter_map(|&(t, z)| {
            let shifted: Option<Vec<(f64, usize)>> = lags.iter().map(|&lag| integral_at(t - lag)).collect();
            let shifted = shifted?;
            let seg = shifted.first()?.1;
            shifted
                .iter()
                .all(|&(_, s)| s == seg)
                .then(|| ((seg, (t / DRIFT_BLOCK).floor() as i64), shifted.iter().map(|&(zi, _)| z - zi).collect()))
        })
        .collect();
    if usable.len() < 100 {
        return None;
    }
    let scan = lags
        .iter()
        .enumerate()
        .map(|(k, &lag)| {
            // The sum of squares about each group's own mean.
            let mut groups: std::collections::BTreeMap<(usize, i64), (f64, f64, f64)> = Default::default();
            for (group, d) in &usable {
                let g = groups.entry(*group).or_insert((0.0, 0.0, 0.0));
                *g = (g.0 + d[k], g.1 + d[k] * d[k], g.2 + 1.0);
            }
            (lag, groups.values().map(|&(s, s2, n)| s2 - s * s / n).sum())
        })
        .collect();
    Some(scan)
}

/// Rate and acceleration at `t` of the least-squares quadratic through `samples`.
fn local_quadratic(samples: &[(f64, f64)], t: f64) -> Option<(f64, f64)> {
    let rows: Vec<([f64; 3], f64)> = samples.iter().map(|&(s, y)| ([1.0, s - t, (s - t) * (s - t)], y)).collect();
    let c = least_squares(&rows)?;
    Some((c[1], 2.0 * c[2]))
}

/// The least-squares coefficients of `y` on the rows, by the normal equations (`None` for a
/// singular system).
fn least_squares<const N: usize>(rows: &[([f64; N], f64)]) -> Option<nalgebra::SVector<f64, N>> {
    let mut ata = nalgebra::SMatrix::<f64, N, N>::zeros();
    let mut atb = nalgebra::SVector::<f64, N>::zeros();
    for (x, y) in rows {
        let x = nalgebra::SVector::<f64, N>::from(*x);
        ata += x * x.transpose();
        atb += x * *y;
    }
    Some(ata.cholesky()?.solve(&atb))
}

/// Residual sum of squares of the least-squares fit of `y` on the rows (NaN without rows or
/// with a singular system).
fn least_squares_residual(rows: &[([f64; 4], f64)]) -> f64 {
    let Some(c) = least_squares(rows) else { return f64::NAN };
    rows.iter().map(|(x, y)| (y - nalgebra::Vector4::from(*x).dot(&c)).powi(2)).sum()
}

/// The readings of each kind, in order: depth `(t, z)`, heading `(t, psi)`, yaw rate `(t, r)`.
/// A reading exactly equal to the one before is left out: a sensor read faster than it
/// updates repeats its last value (ArduSub's simulator sends its 10 Hz depth at 12.5 Hz,
/// every fifth a repeat), and the repeat's stamp is not when the value was measured.
pub fn readings(measurements: &[Measurement]) -> [Vec<(f64, f64)>; 3] {
    let mut out: [Vec<(f64, f64)>; 3] = Default::default();
    for m in measurements {
        let (k, t, v) = match *m {
            Measurement::Depth { t, z } => (0, t, z),
            Measurement::Heading { t, psi } => (1, t, psi),
            Measurement::YawRate { t, r } => (2, t, r),
            _ => continue,
        };
        if out[k].last().is_none_or(|&(_, last)| last != v) {
            out[k].push((t, v));
        }
    }
    out
}

/// The autopilot's vertical velocities `(t, vd)`, in order.
pub fn vertical_velocities(measurements: &[Measurement]) -> Vec<(f64, f64)> {
    measurements
        .iter()
        .filter_map(|m| match *m {
            Measurement::VerticalVelocity { t, vd } => Some((t, vd)),
            _ => None,
        })
        .collect()
}

/// The noise part of the sensor model (the lag is found by the filter): each reading's white
/// noise, at least [`NOISE_FLOOR`], and which readings were too few to tell (their default is
/// kept).
pub fn noise_model(measurements: &[Measurement], default: &SensorModel) -> (SensorModel, Vec<&'static str>) {
    let [depth, heading, yaw_rate] = readings(measurements);
    let mut missing = Vec::new();
    let mut pick = |name: &'static str, s: Option<f64>, floor: f64, fallback: f64| match s {
        Some(s) => s.max(floor),
        None => {
            missing.push(name);
            fallback
        }
    };
    let model = SensorModel {
        depth_std: pick("depth", white_noise_std(&depth, false), NOISE_FLOOR[0], default.depth_std),
        heading_std: pick("heading", white_noise_std(&heading, true), NOISE_FLOOR[1], default.heading_std),
        yaw_rate_std: pick("yaw rate", white_noise_std(&yaw_rate, false), NOISE_FLOOR[2], default.yaw_rate_std),
        depth_delay: default.depth_delay,
    };
    (model, missing)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A position source's readings: a turning track with 4 cm of noise on the position (each
    /// reading sent twice, as a source read faster than it updates does) and 3 cm/s on the
    /// velocity comes back within 10 %; a quieter one at the floor; none without readings.
    #[test]
    fn the_position_sources_noise_is_measured_from_its_readings() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let track = |t: f64| (2.0 * (0.1 * t).sin(), 0.3 * t + (0.05 * t).cos());
        let readings = |position: f64, velocity: f64, rng: &mut rand_chacha::ChaCha8Rng| {
            let (p, v) = (Normal::new(0.0, position).unwrap(), Normal::new(0.0, velocity).unwrap());
            let mut out = Vec::new();
            for i in 0..3000 {
                let t = f64::from(i) * 0.2;
                let (x, y) = track(t);
                let reading = Measurement::Position { t, x: x + p.sample(rng), y: y + p.sample(rng), z: f64::NAN };
                out.extend([reading, reading]);
                let (vn, ve) = (0.2 * (0.1 * t).cos(), 0.3 - 0.05 * (0.05 * t).sin());
                out.push(Measurement::VelocityNed { t, vn: vn + v.sample(rng), ve: ve + v.sample(rng), vd: 0.0 });
            }
            out
        };
        let [position, velocity] = horizontal_noise(&readings(0.04, 0.03, &mut rng));
        let (position, velocity) = (position.unwrap(), velocity.unwrap());
        assert!((position / 0.04 - 1.0).abs() < 0.1, "{position}");
        assert!((velocity / 0.03 - 1.0).abs() < 0.1, "{velocity}");
        assert_eq!(horizontal_noise(&readings(1e-4, 1e-4, &mut rng)), [Some(0.01), Some(0.01)]);
        let depth_only = [Measurement::Depth { t: 0.0, z: 1.0 }, Measurement::Depth { t: 0.1, z: 1.1 }];
        assert_eq!(horizontal_noise(&depth_only), [None, None]);
    }

    /// A smooth manoeuvre plus white noise of a known spread, at uneven stamps: the estimate
    /// comes back within 5 %.
    #[test]
    fn white_noise_of_a_manoeuvre_is_recovered() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 0.12).expect("finite");
        let samples: Vec<(f64, f64)> = (0..6000)
            .map(|i| {
                let t = f64::from(i) * 0.1 + 0.01 * f64::from(i % 3);
                (t, 1.5 + (0.3 * t).sin() + 0.5 * (0.05 * t).cos() + noise.sample(&mut rng))
            })
            .collect();
        let s = white_noise_std(&samples, false).expect("enough samples");
        assert!((s / 0.12 - 1.0).abs() < 0.05, "{s}");
    }

    /// A simulated heave under a random force, read through a sensor that lags 0.12 s with
    /// 0.1 m of noise: the scan's best lag is within one step of it.
    #[test]
    fn depth_lag_of_a_simulated_heave() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let noise = Normal::new(0.0, 0.1).expect("finite");
        let (dt, lag) = (0.001, 0.12);
        let (mut z, mut w, mut force) = (1.0f64, 0.0f64, 0.0);
        let (mut truth, mut heave, mut depth) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..600_000u32 {
            let t = f64::from(k) * dt;
            if k % 80 == 0 {
                // A new force every 0.08 s, held: steps of random size, pulled back to 1.5 m.
                force = 40.0 * (rand::Rng::random::<f64>(&mut rng) - 0.5) - 30.0 * (z - 1.5);
                heave.push((t, force));
            }
            w += dt * (force - 60.0 * w.abs() * w - 5.0 * w + 1.0) / 12.0;
            z += dt * w;
            truth.push(z);
            if k % 80 == 40 && t > lag {
                let delayed = truth[k as usize - (lag / dt) as usize];
                depth.push((t, delayed + noise.sample(&mut rng)));
            }
        }
        let scan = depth_lag_scan(&depth, &heave, &lag_candidates()).expect("enough readings");
        let best = scan.iter().min_by(|a, b| a.1.total_cmp(&b.1)).expect("candidates").0;
        assert!((best - lag).abs() <= 0.021, "best lag {best}, scan {scan:?}");
    }

    /// A heave read through a sensor that lags 0.12 s with 0.12 m of noise at 10 Hz, beside
    /// the autopilot's vertical velocity at 3 Hz with 0.02 m/s of noise and a bias: the scan
    /// against the velocity's integral finds the lag within one step.
    #[test]
    fn depth_lag_against_the_vertical_velocity() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(6);
        let depth_noise = Normal::new(0.0, 0.12).expect("finite");
        let velocity_noise = Normal::new(0.0, 0.02).expect("finite");
        let lag = 0.12;
        let z = |t: f64| 1.5 + 0.6 * (0.9 * t).sin() + 0.3 * (2.3 * t + 1.0).sin();
        let w = |t: f64| 0.54 * (0.9 * t).cos() + 0.69 * (2.3 * t + 1.0).cos();
        let depth: Vec<(f64, f64)> =
            (0..6000).map(|i| f64::from(i) * 0.1).map(|t| (t, z(t - lag) + depth_noise.sample(&mut rng))).collect();
        let velocity: Vec<(f64, f64)> =
            (0..1800).map(|i| f64::from(i) / 3.0).map(|t| (t, w(t) + 0.01 + velocity_noise.sample(&mut rng))).collect();
        let scan = depth_lag_from_vertical_velocity(&depth, &velocity, &lag_candidates()).expect("enough readings");
        let best = scan.iter().min_by(|a, b| a.1.total_cmp(&b.1)).expect("candidates").0;
        assert!((best - lag).abs() <= 0.021, "best lag {best}, scan {scan:?}");
        assert_eq!(depth_lag_from_vertical_velocity(&depth[..50], &velocity, &lag_candidates()), None);
    }

    /// Angles across the wrap: a steady turn through +-pi with 0.01 rad of noise.
    #[test]
    fn heading_noise_across_the_wrap() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let noise = Normal::new(0.0, 0.01).expect("finite");
        let samples: Vec<(f64, f64)> = (0..4000)
            .map(|i| {
                let t = f64::from(i) * 0.08;
                (t, crate::vehicle::wrap_angle(0.7 * t + noise.sample(&mut rng)))
            })
            .collect();
        let s = white_noise_std(&samples, true).expect("enough samples");
        assert!((s / 0.01 - 1.0).abs() < 0.06, "{s}");
        assert_eq!(white_noise_std(&samples[..5], true), None);
    }
}
