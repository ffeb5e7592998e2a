//! The frame rules of ROS 2 logs, in one place: which convention a `frame_id` names and the
//! rotations that take it to pinc's NED world and forward-right-down body.
//!
//! REP 103 and REP 105: world frames (`map`, `odom`, `world`, `earth`) are east-north-up and
//! body frames (`base_link` and any other name) forward-left-up. mavros and PX4 mark the
//! other conventions with a suffix: `_ned` for a world frame, `_frd` for a body frame.

pub use crate::dataset::import::streams::{BodyFrame, WorldFrame};
use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};

/// The name without a leading `/`, in lower case.
fn bare(frame_id: &str) -> String {
    frame_id.trim_start_matches('/').to_ascii_lowercase()
}

/// True when `frame_id` names a world frame: `map`, `odom`, `world`, `earth`, alone or with a
/// `_ned` / `_enu` suffix.
pub fn is_world(frame_id: &str) -> bool {
    let name = bare(frame_id);
    let base = name.strip_suffix("_ned").or_else(|| name.strip_suffix("_enu")).unwrap_or(&name);
    matches!(base, "map" | "odom" | "world" | "earth")
}

/// The convention of a world frame: `over` when given, else NED for a `_ned` name, else ENU.
pub fn world_of(frame_id: &str, over: Option<WorldFrame>) -> WorldFrame {
    over.unwrap_or(if bare(frame_id).ends_with("_ned") { WorldFrame::Ned } else { WorldFrame::Enu })
}

/// The convention of a body frame: `over` when given, else FRD for a `_frd` name, FLU for a
/// `_flu` name, the partner of `world` (ENU: FLU, NED: FRD) for an empty name, else FLU.
pub fn body_of(frame_id: &str, world: WorldFrame, over: Option<BodyFrame>) -> BodyFrame {
    if let Some(b) = over {
        return b;
    }
    let name = bare(frame_id);
    if name.ends_with("_frd") {
        BodyFrame::Frd
    } else if name.ends_with("_flu") || !name.is_empty() {
        BodyFrame::Flu
    } else {
        partner(world)
    }
}

/// The body convention that goes with a world convention (mavros: ENU / FLU, PX4: NED / FRD).
pub fn partner(world: WorldFrame) -> BodyFrame {
    match world {
        WorldFrame::Ned => BodyFrame::Frd,
        WorldFrame::Enu => BodyFrame::Flu,
    }
}

/// The rotation taking world-frame coordinates to NED: ENU `(x, y, z)` is NED `(y, x, -z)`.
pub fn to_ned(world: WorldFrame) -> Matrix3<f64> {
    match world {
        WorldFrame::Ned => Matrix3::identity(),
        WorldFrame::Enu => Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0),
    }
}

/// The rotation taking body-frame coordinates to FRD: FLU `(x, y, z)` is FRD `(x, -y, -z)`.
pub fn to_frd(body: BodyFrame) -> Matrix3<f64> {
    match body {
        BodyFrame::Frd => Matrix3::identity(),
        BodyFrame::Flu => Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)),
    }
}

/// A 3-vector rotated by `m`.
pub fn rotate(m: &Matrix3<f64>, v: [f64; 3]) -> [f64; 3] {
    let r = m * Vector3::from(v);
    [r.x, r.y, r.z]
}

/// Roll, pitch, yaw (Z-Y-X, rad) of the FRD body in NED, from the unit quaternion
/// `(x, y, z, w)` of the body in the world: `R_ned_frd = W R B^T` (both maps are their own
/// inverses). For an FLU body in ENU this is roll, -pitch, pi/2 - yaw.
pub fn attitude(q_xyzw: [f64; 4], world: WorldFrame, body: BodyFrame) -> [f64; 3] {
    let [x, y, z, w] = q_xyzw;
    let r = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)).to_rotation_matrix();
    let m = to_ned(world) * r.matrix() * to_frd(body);
    let (roll, pitch, yaw) = Rotation3::from_matrix_unchecked(m).euler_angles();
    [roll, pitch, yaw]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_rep_105_and_the_ned_frd_suffixes() {
        assert!(is_world("odom") && is_world("/map") && is_world("odom_ned") && !is_world("base_link"));
        assert_eq!(world_of("map", None), WorldFrame::Enu);
        assert_eq!(world_of("odom_ned", None), WorldFrame::Ned);
        assert_eq!(world_of("odom_ned", Some(WorldFrame::Enu)), WorldFrame::Enu);
        assert_eq!(body_of("base_link", WorldFrame::Ned, None), BodyFrame::Flu);
        assert_eq!(body_of("base_link_frd", WorldFrame::Enu, None), BodyFrame::Frd);
        assert_eq!(body_of("", WorldFrame::Ned, None), BodyFrame::Frd);
    }

    #[test]
    fn a_flu_body_heading_north_in_enu_has_zero_yaw_in_ned() {
        // ENU yaw pi/2 (facing north), rotation about z by pi/2.
        let h = std::f64::consts::FRAC_PI_4;
        let a = attitude([0.0, 0.0, h.sin(), h.cos()], WorldFrame::Enu, BodyFrame::Flu);
        assert!(a.iter().all(|v| v.abs() < 1e-12), "{a:?}");
    }
}
