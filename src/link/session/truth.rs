//! The simulator's truth (`SIM_STATE`), read only to score a live run: the estimate's errors
//! and the tracking against what the vehicle really did.

use crate::estimation::Estimate;
use crate::estimation::mavlink::METRES_PER_E7_DEGREE;
use mavlink::dialects::ardupilotmega::{SIM_STATE_DATA, SIMSTATE_DATA};
use serde_json::{Value, json};

/// The simulator's truth at an autopilot time: depth, heading, body velocities, yaw rate.
#[derive(Debug, Clone, Copy)]
pub(super) struct Truth {
    pub(super) t: f64,
    pub(super) z: f64,
    pub(super) psi: f64,
    pub(super) uvw: [f64; 3],
    pub(super) r: f64,
}

/// What the simulator's truth sent since the last cycle: its states (`SIM_STATE`) and its
/// positions (`SIMSTATE`, whose latitude and longitude are integers of 1e-7 deg, about 1 cm;
/// `SIM_STATE`'s are `f32` degrees, 0.4 m here, and its integer ones are a MAVLink 2 extension).
#[derive(Debug, Default)]
pub(super) struct Feed {
    pub(super) states: Vec<Truth>,
    pub(super) positions: Vec<Position>,
}

/// The simulator's true position at an autopilot time (1e-7 deg).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Position {
    pub(super) t: f64,
    pub(super) lat_lon: (f64, f64),
}

pub(super) fn position_of(t: f64, s: &SIMSTATE_DATA) -> Position {
    Position { t, lat_lon: (f64::from(s.lat), f64::from(s.lng)) }
}

/// The two samples around `t` (by `time_of`), at most 0.2 s apart, and where `t` lies between
/// them (0 to 1): the simulator's messages have no stamp of their own, so each has its
/// arrival's autopilot time.
fn around<T>(samples: &[T], t: f64, time_of: impl Fn(&T) -> f64) -> Option<(&T, &T, f64)> {
    let k = samples.partition_point(|s| time_of(s) <= t);
    if k == 0 || k == samples.len() {
        return None;
    }
    let (a, b) = (&samples[k - 1], &samples[k]);
    let (ta, tb) = (time_of(a), time_of(b));
    (tb - ta <= 0.2 && tb > ta).then(|| (a, b, (t - ta) / (tb - ta)))
}

/// The position at `t`, interpolated between two at most 0.2 s apart.
pub(super) fn position_at(positions: &[Position], t: f64) -> Option<Position> {
    let (a, b, f) = around(positions, t, |p| p.t)?;
    let lerp = |x: f64, y: f64| x + f * (y - x);
    Some(Position { t, lat_lon: (lerp(a.lat_lon.0, b.lat_lon.0), lerp(a.lat_lon.1, b.lat_lon.1)) })
}

impl Position {
    /// Metres north and east of `other` (a flat earth: fine over a few hundred metres).
    pub(super) fn north_east_from(&self, other: &Position) -> (f64, f64) {
        let lat = other.lat_lon.0 * 1e-7;
        let dn = (self.lat_lon.0 - other.lat_lon.0) * METRES_PER_E7_DEGREE;
        let de = (self.lat_lon.1 - other.lat_lon.1) * METRES_PER_E7_DEGREE * lat.to_radians().cos();
        (dn, de)
    }
}

pub(super) fn truth_of(t: f64, s: &SIM_STATE_DATA) -> Truth {
    // NED velocity into the body frame by the whole attitude (Z-Y-X Euler angles).
    let (roll, pitch, yaw) = (f64::from(s.roll), f64::from(s.pitch), f64::from(s.yaw));
    let r = nalgebra::Rotation3::from_euler_angles(roll, pitch, yaw);
    let body = r.inverse() * nalgebra::Vector3::new(f64::from(s.vn), f64::from(s.ve), f64::from(s.vd));
    Truth { t, z: -f64::from(s.alt), psi: yaw, uvw: [body.x, body.y, body.z], r: f64::from(s.zgyro) }
}

/// The truth at `t`, interpolated between two truths at most 0.2 s apart.
pub(super) fn truth_at(truths: &[Truth], t: f64) -> Option<Truth> {
    let (a, b, f) = around(truths, t, |tr| tr.t)?;
    let lerp = |x: f64, y: f64| x + f * (y - x);
    Some(Truth {
        t,
        z: lerp(a.z, b.z),
        psi: a.psi + f * crate::vehicle::wrap_angle(b.psi - a.psi),
        uvw: std::array::from_fn(|i| lerp(a.uvw[i], b.uvw[i])),
        r: lerp(a.r, b.r),
    })
}

/// The estimate's errors `u v w r z` against the truth at each estimate's time. Heading is left
/// out: ATTITUDE's is magnetic where the autopilot knows no declination, the truth's true.
pub(super) fn errors_against_truth(estimates: &[Estimate], truths: &[Truth]) -> [Vec<f64>; 5] {
    let mut errors: [Vec<f64>; 5] = Default::default();
    for e in estimates {
        let Some(tr) = truth_at(truths, e.t) else { continue };
        let truth = [tr.uvw[0], tr.uvw[1], tr.uvw[2], tr.r, tr.z];
        for (i, idx) in [4, 5, 6, 7, 2].into_iter().enumerate() {
            errors[i].push(e.sim[idx] - truth[i]);
        }
    }
    errors
}

pub(super) fn rms(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt())
}

pub(super) fn percentiles_ms(v: &mut [f64]) -> Value {
    if v.is_empty() {
        return json!({"median": null, "p99": null, "max": null});
    }
    v.sort_by(f64::total_cmp);
    let at = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1] * 1e3;
    json!({"median": at(0.5), "p99": at(0.99), "max": v[v.len() - 1] * 1e3})
}
