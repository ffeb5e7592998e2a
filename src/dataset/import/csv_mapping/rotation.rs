//! The quaternion's part of the conversion: the rotation of a unit quaternion, its Z-Y-X
//! angles, and the ENU/FLU axis changes. Apart because it is the only matrix algebra in the
//! reader, and its sign conventions are what the tests below pin down.

use nalgebra::Matrix3;

/// The rotation (body to world) of a unit quaternion `w, x, y, z`.
pub(super) fn rotation(w: f64, x: f64, y: f64, z: f64) -> Matrix3<f64> {
    Matrix3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )
}

/// Roll, pitch, yaw (Z-Y-X) of a body-to-world rotation.
pub(super) fn euler_zyx(r: &Matrix3<f64>) -> [f64; 3] {
    [r[(2, 1)].atan2(r[(2, 2)]), -r[(2, 0)].clamp(-1.0, 1.0).asin(), r[(1, 0)].atan2(r[(0, 0)])]
}

/// ENU world axes to NED: swap east and north, flip up.
pub(super) const ENU_TO_NED: Matrix3<f64> = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
/// FRD body axes to FLU (its own inverse): flip y and z.
pub(super) const FRD_TO_FLU: Matrix3<f64> = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn a_quaternion_of_a_pure_enu_yaw_gives_the_ned_yaw_pi_over_2_minus_it() {
        let a: f64 = 0.4;
        let r = rotation((a / 2.0).cos(), 0.0, 0.0, (a / 2.0).sin());
        let [roll, pitch, yaw] = euler_zyx(&(ENU_TO_NED * r * FRD_TO_FLU));
        assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12);
        assert!((yaw - (FRAC_PI_2 - a)).abs() < 1e-12);
    }

    #[test]
    fn nose_up_in_flu_is_nose_up_in_frd() {
        // Pitch about FLU's y (left) by -b lifts the nose; in FRD that is a positive pitch.
        let b: f64 = 0.2;
        let r = rotation((-b / 2.0).cos(), 0.0, (-b / 2.0).sin(), 0.0);
        let [roll, pitch, _] = euler_zyx(&(ENU_TO_NED * r * FRD_TO_FLU));
        assert!(roll.abs() < 1e-12);
        assert!((pitch - b).abs() < 1e-12, "{pitch}");
    }

    #[test]
    fn starboard_down_in_flu_is_a_positive_roll_in_frd() {
        // About FLU's x (forward) by +a the left side rises: starboard down, positive in FRD too.
        let a: f64 = 0.15;
        let r = rotation((a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0);
        let [roll, pitch, _] = euler_zyx(&(ENU_TO_NED * r * FRD_TO_FLU));
        assert!(pitch.abs() < 1e-12);
        assert!((roll - a).abs() < 1e-12, "{roll}");
    }
}
