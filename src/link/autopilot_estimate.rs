//! What the autopilot says of its own estimate (`EKF_STATUS_REPORT`) and which heading it
//! reports: whether its attitude and heading can be controlled on yet, whether its position is
//! measured or only dead-reckoned, and whether its heading is true or magnetic.
//!
//! ArduSub's heading is magnetic plus the declination in force: looked up from the position
//! where `COMPASS_AUTODEC` is on and the autopilot has a position (GPS), else `COMPASS_DEC` as
//! set. Most BlueROV2s dive without a position source, so their heading is magnetic unless an
//! owner set `COMPASS_DEC` (measured on ArduSub's simulator near Los Angeles: 10.9 deg off the
//! truth with `COMPASS_DEC` 0, 0.4 deg with it set to the local 11.5 deg).

use super::params::Params;
use mavlink::dialects::ardupilotmega::EKF_STATUS_REPORT_DATA;

/// `EKF_STATUS_FLAGS` bits (ArduPilot's dialect).
pub mod flags {
    /// The attitude estimate is good.
    pub const ATTITUDE: u16 = 1;
    /// The horizontal velocity estimate is good.
    pub const VELOCITY_HORIZ: u16 = 2;
    /// The vertical velocity estimate is good.
    pub const VELOCITY_VERT: u16 = 4;
    /// The horizontal position (relative) estimate is good.
    pub const POS_HORIZ_REL: u16 = 8;
    /// The horizontal position (absolute) estimate is good.
    pub const POS_HORIZ_ABS: u16 = 16;
    /// The vertical position (absolute) estimate is good.
    pub const POS_VERT_ABS: u16 = 32;
    /// In constant position mode: no position source, the position held where it was.
    pub const CONST_POS_MODE: u16 = 128;
    /// The EKF has never been healthy.
    pub const UNINITIALIZED: u16 = 1024;
    /// GPS glitching.
    pub const GPS_GLITCHING: u16 = 32768;
}

/// ArduPilot's own threshold on its variances (below 0.5 good, 0.8 or more bad).
pub const BAD_VARIANCE: f32 = 0.8;

/// The newest `EKF_STATUS_REPORT`, as pinc reads it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EkfStatus {
    /// Autopilot time (s) it arrived.
    pub t: f64,
    /// Its flags.
    pub flags: u16,
    /// Its compass (heading) variance, as a fraction of the EKF's gate.
    pub compass_variance: f32,
    /// Its horizontal position variance, likewise.
    pub pos_horiz_variance: f32,
}

impl EkfStatus {
    /// From the message, received at autopilot time `t`.
    pub fn new(t: f64, m: &EKF_STATUS_REPORT_DATA) -> Self {
        Self {
            t,
            flags: m.flags.bits(),
            compass_variance: m.compass_variance,
            pos_horiz_variance: m.pos_horiz_variance,
        }
    }

    fn has(&self, bit: u16) -> bool {
        self.flags & bit != 0
    }

    /// Why attitude or heading cannot be controlled on yet (empty: they can).
    pub fn not_ready(&self) -> Vec<String> {
        let mut why = Vec::new();
        if self.has(flags::UNINITIALIZED) {
            why.push("the autopilot's EKF has not initialised (EKF_UNINITIALIZED)".to_string());
        }
        if !self.has(flags::ATTITUDE) {
            why.push("the autopilot's attitude estimate is not good yet (EKF_ATTITUDE unset)".to_string());
        }
        if !self.compass_variance.is_finite() || self.compass_variance >= BAD_VARIANCE {
            why.push(format!(
                "the autopilot's heading is not usable: compass variance {:.2} (bad from {BAD_VARIANCE})",
                self.compass_variance
            ));
        }
        why
    }

    /// Whether the autopilot's horizontal position is measured (a position source is fused),
    /// not dead-reckoned or held: only then is `LOCAL_POSITION_NED`'s position a measurement.
    pub fn position_measured(&self) -> bool {
        self.has(flags::POS_HORIZ_ABS | flags::POS_HORIZ_REL)
            && !self.has(flags::CONST_POS_MODE)
            && !self.has(flags::GPS_GLITCHING)
            && self.pos_horiz_variance < BAD_VARIANCE
    }

    /// Whether the autopilot has an absolute position (from which it can look up the
    /// declination).
    pub fn absolute_position(&self) -> bool {
        self.has(flags::POS_HORIZ_ABS) && !self.has(flags::CONST_POS_MODE)
    }
}

/// `EK3_SRC1_POSXY` of GPS.
const SOURCE_GPS: f64 = 3.0;
/// `EK3_SRC1_POSXY` / `EK3_SRC1_VELXY` of external navigation: a DVL's `VISION_POSITION_DELTA`
/// (Water Linked's integration) or an acoustic system's `VISION_POSITION_ESTIMATE`.
const SOURCE_EXTERNAL_NAV: f64 = 6.0;
/// `GPS_RAW_INT.fix_type` of a 3D fix.
const FIX_3D: u8 = 3;
/// `MAV_SYS_STATUS_SENSOR_VISION_POSITION`: visual odometry, what ArduPilot reports a DVL as.
const SENSOR_VISION_POSITION: u32 = 128;

/// A DVL's health from `SYS_STATUS`'s sensor bits: `None` where none is present. ArduPilot
/// clears the health 0.3 s after the last message (measured on ArduSub's simulator: 0.24 s
/// after the stand-in's last `VISION_POSITION_DELTA`).
pub fn vision_health(present: u32, health: u32) -> Option<bool> {
    (present & SENSOR_VISION_POSITION != 0).then_some(health & SENSOR_VISION_POSITION != 0)
}

/// Whether the autopilot's position (`LOCAL_POSITION_NED`) is a measurement now: its EKF says
/// it fuses a position source ([`EkfStatus::position_measured`]; no report at all counts as
/// yes, for firmware without it), where that source is GPS (`EK3_SRC1_POSXY` 3) the GPS still
/// has a 3D fix, and where it is external navigation (`EK3_SRC1_POSXY` or `EK3_SRC1_VELXY` 6:
/// a DVL) the DVL is healthy. The source checks come first because ArduSub's EKF goes on
/// reporting a good position for seconds after its source is lost, dead-reckoning meanwhile
/// (measured on its simulator: after the GPS, the fix is gone within 1 s and the flags change
/// 7.2 s later, `LOCAL_POSITION_NED` keeping on for 15 s with its velocity drifting to 0.6 m/s
/// on a still vehicle; after a DVL's last message, the health clears in 0.24 s and the EKF
/// stops aiding 5 s later, its position frozen while a current carries the vehicle 0.35 m).
pub fn position_measured(
    status: Option<&EkfStatus>,
    params: &Params,
    gps_fix: Option<u8>,
    vision_healthy: Option<bool>,
) -> bool {
    let ekf = status.is_none_or(EkfStatus::position_measured);
    let gps_source = params.get("EK3_SRC1_POSXY").is_some_and(|s| s == SOURCE_GPS);
    let gps_lost = gps_source && gps_fix.is_some_and(|f| f < FIX_3D);
    let dvl_source = ["EK3_SRC1_POSXY", "EK3_SRC1_VELXY"]
        .iter()
        .any(|name| params.get(name).is_some_and(|s| s == SOURCE_EXTERNAL_NAV));
    let dvl_lost = dvl_source && vision_healthy == Some(false);
    ekf && !gps_lost && !dvl_lost
}

/// Which heading the autopilot reports, and so which heading pinc steers by.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HeadingReference {
    /// True north: the declination looked up from the autopilot's position.
    TrueLookedUp,
    /// True north by the declination set by hand (`COMPASS_DEC`, degrees east).
    TrueBySetting {
        /// `COMPASS_DEC` in degrees.
        declination_deg: f64,
    },
    /// Magnetic north: `COMPASS_DEC` is 0 and no position to look it up.
    Magnetic,
    /// The autopilot did not answer the declination parameters.
    Unknown,
}

impl HeadingReference {
    /// From the declination parameters and whether the autopilot has an absolute position.
    pub fn of(params: &Params, absolute_position: bool) -> Self {
        let (Some(dec), auto) = (params.get("COMPASS_DEC"), params.get("COMPASS_AUTODEC")) else {
            return HeadingReference::Unknown;
        };
        if auto.is_some_and(|a| a >= 0.5) && absolute_position {
            HeadingReference::TrueLookedUp
        } else if dec != 0.0 {
            HeadingReference::TrueBySetting { declination_deg: dec.to_degrees() }
        } else {
            HeadingReference::Magnetic
        }
    }

    /// `true`, `magnetic` or `unknown`.
    pub fn key(&self) -> &'static str {
        match self {
            HeadingReference::TrueLookedUp | HeadingReference::TrueBySetting { .. } => "true",
            HeadingReference::Magnetic => "magnetic",
            HeadingReference::Unknown => "unknown",
        }
    }

    /// A sentence for the summary and the log.
    pub fn describe(&self) -> String {
        match self {
            HeadingReference::TrueLookedUp => {
                "heading: true north (the autopilot looked the declination up from its position, COMPASS_AUTODEC)"
                    .into()
            }
            HeadingReference::TrueBySetting { declination_deg } => format!(
                "heading: true north by the declination set by hand (COMPASS_DEC {declination_deg:.2} deg); without a \
                 position the autopilot cannot check it"
            ),
            HeadingReference::Magnetic => {
                "heading: MAGNETIC north: COMPASS_DEC is 0 and the autopilot has no position \
                                           to look the declination up, so every heading (references included) is off \
                                           true north by the local declination; set COMPASS_DEC (radians) to steer by \
                                           true north"
                    .into()
            }
            HeadingReference::Unknown => {
                "heading: reference unknown (the autopilot did not answer COMPASS_DEC / COMPASS_AUTODEC)".into()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status(flags: u16, compass: f32, pos: f32) -> EkfStatus {
        EkfStatus { t: 0.0, flags, compass_variance: compass, pos_horiz_variance: pos }
    }

    #[test]
    fn attitude_and_heading_are_ready_only_with_the_attitude_flag_and_a_usable_compass() {
        assert!(status(flags::ATTITUDE, 0.1, 0.0).not_ready().is_empty());
        let why = status(flags::UNINITIALIZED, 0.1, 0.0).not_ready();
        assert_eq!(why.len(), 2, "{why:?}");
        let why = status(flags::ATTITUDE, 0.9, 0.0).not_ready();
        assert!(why.len() == 1 && why[0].contains("compass variance 0.90"), "{why:?}");
    }

    #[test]
    fn a_position_is_a_measurement_only_while_the_ekf_fuses_a_source() {
        let gps = flags::ATTITUDE | flags::POS_HORIZ_ABS | flags::POS_HORIZ_REL;
        assert!(status(gps, 0.1, 0.1).position_measured());
        assert!(!status(gps | flags::CONST_POS_MODE, 0.1, 0.1).position_measured());
        assert!(!status(gps, 0.1, 0.9).position_measured(), "variance beyond ArduPilot's bad threshold");
        assert!(!status(flags::ATTITUDE, 0.1, 0.0).position_measured());
    }

    #[test]
    fn a_gps_position_stops_being_a_measurement_when_the_fix_goes_before_the_ekf_says_so() {
        // The flags ArduSub's EKF reports for 7 s after its GPS is lost (831), and its fix then.
        let gps = status(831, 0.02, 0.008);
        let on_gps = Params::from_pairs([("EK3_SRC1_POSXY", 3.0)]);
        assert!(position_measured(Some(&gps), &on_gps, Some(6), None));
        assert!(!position_measured(Some(&gps), &on_gps, Some(1), None));
        // A DVL (external navigation, 6): the GPS's lost fix under water says nothing of it.
        let on_dvl = Params::from_pairs([("EK3_SRC1_POSXY", 6.0)]);
        assert!(position_measured(Some(&gps), &on_dvl, Some(1), None));
        // Stock (167: constant position mode): never a measurement; no report: trusted.
        assert!(!position_measured(Some(&status(167, 0.0, 0.005)), &on_gps, None, None));
        assert!(position_measured(None, &on_gps, None, None));
    }

    #[test]
    fn a_dvl_position_stops_being_a_measurement_when_its_health_clears() {
        // Water Linked's setting (POSXY 6) and the DVL stand-in's (VELXY 6, no position source).
        let good = status(831, 0.02, 0.008);
        for on_dvl in [
            Params::from_pairs([("EK3_SRC1_POSXY", 6.0)]),
            Params::from_pairs([("EK3_SRC1_POSXY", 0.0), ("EK3_SRC1_VELXY", 6.0)]),
        ] {
            assert!(position_measured(Some(&good), &on_dvl, None, Some(true)));
            assert!(!position_measured(Some(&good), &on_dvl, None, Some(false)));
            // No SYS_STATUS yet, or no visual odometry in it: the EKF's word.
            assert!(position_measured(Some(&good), &on_dvl, None, None));
        }
        // A vehicle on GPS is not judged by a DVL it does not use.
        let on_gps = Params::from_pairs([("EK3_SRC1_POSXY", 3.0), ("EK3_SRC1_VELXY", 3.0)]);
        assert!(position_measured(Some(&good), &on_gps, Some(6), Some(false)));
        // SYS_STATUS's bits: present and healthy, present and not, absent.
        assert_eq!(vision_health(128 | 32, 128), Some(true));
        assert_eq!(vision_health(128 | 32, 32), Some(false));
        assert_eq!(vision_health(32, 32), None);
    }

    #[test]
    fn the_heading_is_true_where_the_declination_is_known_and_magnetic_otherwise() {
        let p = |dec: f64, auto: f64| Params::from_pairs([("COMPASS_DEC", dec), ("COMPASS_AUTODEC", auto)]);
        assert_eq!(HeadingReference::of(&p(0.2007, 1.0), true), HeadingReference::TrueLookedUp);
        assert_eq!(HeadingReference::of(&p(0.0, 1.0), false), HeadingReference::Magnetic);
        let set = HeadingReference::of(&p(0.2007, 1.0), false);
        assert!(
            matches!(set, HeadingReference::TrueBySetting { declination_deg } if (declination_deg - 11.5).abs() < 0.01)
        );
        assert_eq!(HeadingReference::of(&Params::default(), true).key(), "unknown");
        assert!(HeadingReference::Magnetic.describe().contains("COMPASS_DEC"));
    }
}
