//! Measurements from ArduSub's standard MAVLink messages, for the live link and for recorded
//! `.tlog`s alike:
//!
//! - `ATTITUDE`: heading (`yaw`) and yaw rate (`yawspeed`);
//! - `SCALED_PRESSURE2` (the external depth sensor), or `SCALED_PRESSURE` until one is seen:
//!   depth `(p - p_surface) / (rho g)`;
//! - `LOCAL_POSITION_NED` (only while the autopilot's EKF has a position source): position
//!   (its depth left to the pressure sensor where there is one) and NED velocity;
//! - `GLOBAL_POSITION_INT.vz`: the EKF's vertical velocity, which ArduSub estimates from its
//!   accelerometers and depth sensor without a position too; taken only while the newest
//!   `EKF_STATUS_REPORT` vouches for it (`EKF_VELOCITY_VERT` set, initialised), and left out
//!   while `LOCAL_POSITION_NED` comes (its velocity holds the same number);
//! - `VISION_POSITION_DELTA` (a DVL, forwarded by the autopilot from the DVL's link): the
//!   body velocity over the ground;
//! - `GPS_INPUT` (a USBL such as Water Linked's Underwater GPS through its extension, or a
//!   GPS on MAVLink) and `GLOBAL_VISION_POSITION_ESTIMATE` (ArduPilot takes its `x y` as
//!   metres in the local NED frame), from the sensor's own link: position fixes, placed from
//!   one anchor kept for the session (the autopilot's EKF origin where `GPS_GLOBAL_ORIGIN` told
//!   it before the first fix, else that fix: an origin set later or changed does not move
//!   them; the filter estimates their frame's offset); each stamped at its arrival less the
//!   sensor's latency (the message's own stamp is the sender's clock);
//! - `SERVO_OUTPUT_RAW` through a vehicle file's thrusters: the input actually applied.
//!
//! Messages older than the newest of their kind are dropped (and counted).

use super::measurement::Measurement;
use crate::types::Input;
use crate::vehicle::Thrusters;
use mavlink::dialects::ardupilotmega::{EkfStatusFlags, GpsInputIgnoreFlags, MavMessage, SERVO_OUTPUT_RAW_DATA};

/// Standard gravity (m/s^2), as ArduPilot's `GRAVITY_MSS`.
pub const GRAVITY: f64 = 9.80665;

/// Depth (m, down) of an absolute pressure `hpa` under `surface_hpa` in water of `density`
/// (kg/m^3): `(p - p_surface) / (rho g)`.
pub fn depth_from_pressure(hpa: f64, surface_hpa: f64, density: f64) -> f64 {
    (hpa - surface_hpa) * 100.0 / (density * GRAVITY)
}
/// How long (s) after a `LOCAL_POSITION_NED` its velocity stands for the EKF's vertical
/// velocity (ArduSub sends both at the same rate).
const LOCAL_POSITION_COVERS_S: f64 = 1.0;
/// `SERVO_OUTPUT_RAW.time_usec` wraps every 2^32 us.
pub const USEC_WRAP_S: f64 = 4294.967296;
/// Metres per 1e-7 degree of latitude on ArduPilot's spherical earth (`LOCATION_SCALING_FACTOR`).
pub const METRES_PER_E7_DEGREE: f64 = 0.011131884502145034;
/// `GPS_INPUT.fix_type` from which a fix is a position (2: 2D; its depth is not used).
const FIX_2D: u8 = 2;

/// North and east (m) of `lat_e7 lon_e7` (1e-7 deg) from `origin` on ArduPilot's flat earth
/// about it, as its EKF turns a GPS fix into its local frame.
pub fn north_east_of(origin: (i32, i32), lat_e7: i32, lon_e7: i32) -> (f64, f64) {
    let scale = (f64::from(origin.0) * 1e-7).to_radians().cos();
    let north = f64::from(lat_e7.wrapping_sub(origin.0)) * METRES_PER_E7_DEGREE;
    let east = f64::from(lon_e7.wrapping_sub(origin.1)) * METRES_PER_E7_DEGREE * scale;
    (north, east)
}

/// The eight outputs of a `SERVO_OUTPUT_RAW` (us).
pub fn servo_pwm(o: &SERVO_OUTPUT_RAW_DATA) -> [u16; 8] {
    [o.servo1_raw, o.servo2_raw, o.servo3_raw, o.servo4_raw, o.servo5_raw, o.servo6_raw, o.servo7_raw, o.servo8_raw]
}

/// A `SERVO_OUTPUT_RAW`'s own time (`time_usec`, wrapping) put on the autopilot's time line
/// near `now` (s).
pub fn outputs_time(now: f64, o: &SERVO_OUTPUT_RAW_DATA) -> f64 {
    let raw = f64::from(o.time_usec) * 1e-6;
    raw + ((now - raw) / USEC_WRAP_S).round() * USEC_WRAP_S
}

/// The longest gap (s) between two output reports across which a change is dated between
/// them; after a longer one (a lost stream) the change is dated at its report.
const OUTPUTS_GAP_S: f64 = 0.25;

/// When outputs `now_outputs`, reported at `t`, took effect, after `last` (the report before and
/// its time). The autopilot reports its outputs at a stream rate (ArduSub: 50 Hz) while it
/// changes them at its loop rate, so a change first reported at `t` happened at some instant
/// since the report before, equally likely anywhere between: the midpoint is the unbiased date.
/// Dated at its report, every change was applied half a report period late (10 ms at 50 Hz):
/// on the firmware's recordings the fitted yaw inertia came out 0.177 and 0.229 kg m^2 where the
/// simulator has 0.268 (0.265 and 0.281 dated at the midpoint).
pub fn change_time<T: PartialEq>(last: Option<&(f64, T)>, t: f64, now_outputs: &T) -> f64 {
    match last {
        Some((before, previous)) if previous != now_outputs && t > *before && t - before <= OUTPUTS_GAP_S => {
            0.5 * (before + t)
        }
        _ => t,
    }
}

/// What one message gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Observation {
    /// A measurement.
    Measured(Measurement),
    /// The input applied at a time (s).
    Applied(f64, Input),
    /// A reading the estimator leaves out: the position's own depth where a depth sensor
    /// measures it (the autopilot's EKF blends that same sensor in). The raw state keeps it
    /// with the position, so that both are of one time.
    Unfused(Measurement),
}

/// Turns messages into [`Observation`]s.
#[derive(Debug, Clone)]
pub struct MavlinkMeasurements {
    surface_pressure_hpa: f64,
    water_density: f64,
    thrusters: Option<Thrusters>,
    external_pressure: bool,
    /// Newest stamp of attitude, pressure, local position, outputs, global position, DVL,
    /// position fix.
    newest: [f64; 7],
    /// The autopilot's EKF origin (1e-7 deg), once it said it.
    origin: Option<(i32, i32)>,
    /// Times the origin said differed from the one before.
    origin_changes: u64,
    /// Where fixes are placed from (1e-7 deg): the origin known at the first fix, or that fix.
    anchor: Option<(i32, i32)>,
    /// How late (s) the positioning sensor's fixes arrive after they were measured.
    fix_latency: f64,
    /// Fixes that came before the origin was known, and so were left out.
    fixes_before_origin: u64,
    dropped: u64,
    /// The newest EKF_STATUS_REPORT vouches for the vertical velocity.
    vertical_velocity_valid: bool,
    vertical_velocity_left_out: u64,
    /// The last thruster outputs reported, with their report's time.
    last_outputs: Option<(f64, [u16; 8])>,
}

impl MavlinkMeasurements {
    /// Depth from pressure with `surface_pressure_hpa` and `water_density` (kg/m^3); the
    /// applied input from outputs through `thrusters`, if given.
    pub fn new(surface_pressure_hpa: f64, water_density: f64, thrusters: Option<Thrusters>) -> Self {
        Self {
            surface_pressure_hpa,
            water_density,
            thrusters,
            external_pressure: false,
            newest: [f64::NEG_INFINITY; 7],
            origin: None,
            origin_changes: 0,
            anchor: None,
            fix_latency: 0.0,
            fixes_before_origin: 0,
            dropped: 0,
            vertical_velocity_valid: false,
            vertical_velocity_left_out: 0,
            last_outputs: None,
        }
    }

    /// Reads the thruster outputs through `thrusters` (`None`: not at all).
    pub fn set_thrusters(&mut self, thrusters: Option<Thrusters>) {
        self.thrusters = thrusters;
    }

    /// Starts the time line over (the autopilot rebooted: its stamps begin again near 0); the
    /// fixes' anchor is kept.
    pub fn restart(&mut self) {
        self.newest = [f64::NEG_INFINITY; 7];
        self.origin = None;
        self.external_pressure = false;
        self.vertical_velocity_valid = false;
    }

    /// Position fixes are stamped `latency` s before they arrive (a USBL's acoustic round trip
    /// and processing: Water Linked's Underwater GPS is some 0.5 s late).
    pub fn set_fix_latency(&mut self, latency: f64) {
        self.fix_latency = latency;
    }

    /// The latency (s) position fixes are stamped with.
    pub fn fix_latency(&self) -> f64 {
        self.fix_latency
    }

    /// The autopilot's EKF origin (1e-7 deg), once `GPS_GLOBAL_ORIGIN` said it.
    pub fn origin(&self) -> Option<(i32, i32)> {
        self.origin
    }

    /// Position fixes that came before the autopilot said its origin (placed from the anchor
    /// all the same).
    pub fn fixes_before_origin(&self) -> u64 {
        self.fixes_before_origin
    }

    /// Times the autopilot's origin changed after it was first said.
    pub fn origin_changes(&self) -> u64 {
        self.origin_changes
    }

    /// Where position fixes are placed from (1e-7 deg), once the first came.
    pub fn anchor(&self) -> Option<(i32, i32)> {
        self.anchor
    }

    fn fix(&mut self, now: f64, lat_e7: i32, lon_e7: i32, std: f64, mut out: impl FnMut(Observation)) {
        if self.origin.is_none() {
            self.fixes_before_origin += 1;
        }
        let anchor = *self.anchor.get_or_insert(self.origin.unwrap_or((lat_e7, lon_e7)));
        let t = now - self.fix_latency;
        if self.in_order(6, t) {
            let (x, y) = north_east_of(anchor, lat_e7, lon_e7);
            out(Observation::Measured(Measurement::Fix { t, x, y, std }));
        }
    }

    /// Whether the newest `EKF_STATUS_REPORT` vouches for the autopilot's vertical velocity.
    pub fn vertical_velocity_valid(&self) -> bool {
        self.vertical_velocity_valid
    }

    /// Vertical velocities left out while the autopilot's EKF did not vouch for them (before
    /// its first `EKF_STATUS_REPORT`, while initialising).
    pub fn vertical_velocity_left_out(&self) -> u64 {
        self.vertical_velocity_left_out
    }

    /// Messages dropped as older than the newest of their kind.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Whether an external depth sensor (`SCALED_PRESSURE2`) was seen.
    pub fn external_pressure(&self) -> bool {
        self.external_pressure
    }

    fn in_order(&mut self, kind: usize, t: f64) -> bool {
        if t <= self.newest[kind] {
            self.dropped += 1;
            return false;
        }
        self.newest[kind] = t;
        true
    }

    fn depth(&self, hpa: f32) -> f64 {
        depth_from_pressure(f64::from(hpa), self.surface_pressure_hpa, self.water_density)
    }

    /// The observations in `message` (autopilot time `now` s where the message has no stamp
    /// of its own on the boot time line), passed to `out`.
    pub fn observe(&mut self, now: f64, message: &MavMessage, mut out: impl FnMut(Observation)) {
        let ms = |v: u32| f64::from(v) * 1e-3;
        let f = f64::from;
        match message {
            MavMessage::ATTITUDE(m) if self.in_order(0, ms(m.time_boot_ms)) => {
                let t = ms(m.time_boot_ms);
                out(Observation::Measured(Measurement::Heading { t, psi: f(m.yaw) }));
                out(Observation::Measured(Measurement::YawRate { t, r: f(m.yawspeed) }));
            }
            MavMessage::SCALED_PRESSURE2(m) => {
                self.external_pressure = true;
                if self.in_order(1, ms(m.time_boot_ms)) {
                    let z = self.depth(m.press_abs);
                    out(Observation::Measured(Measurement::Depth { t: ms(m.time_boot_ms), z }));
                }
            }
            MavMessage::SCALED_PRESSURE(m) if !self.external_pressure && self.in_order(1, ms(m.time_boot_ms)) => {
                let z = self.depth(m.press_abs);
                out(Observation::Measured(Measurement::Depth { t: ms(m.time_boot_ms), z }));
            }
            MavMessage::LOCAL_POSITION_NED(m) if self.in_order(2, ms(m.time_boot_ms)) => {
                let t = ms(m.time_boot_ms);
                let z = if self.external_pressure { f64::NAN } else { f(m.z) };
                out(Observation::Measured(Measurement::Position { t, x: f(m.x), y: f(m.y), z }));
                out(Observation::Measured(Measurement::VelocityNed { t, vn: f(m.vx), ve: f(m.vy), vd: f(m.vz) }));
                if self.external_pressure {
                    out(Observation::Unfused(Measurement::Depth { t, z: f(m.z) }));
                }
            }
            MavMessage::GLOBAL_POSITION_INT(m) if self.in_order(4, ms(m.time_boot_ms)) => {
                let t = ms(m.time_boot_ms);
                // A local position within the last second carries this velocity already.
                let covered = self.newest[2] >= t - LOCAL_POSITION_COVERS_S;
                match (covered, self.vertical_velocity_valid) {
                    (true, _) => {}
                    (false, true) => {
                        out(Observation::Measured(Measurement::VerticalVelocity { t, vd: f64::from(m.vz) * 0.01 }));
                    }
                    (false, false) => self.vertical_velocity_left_out += 1,
                }
            }
            // A DVL's body-frame distance over the ground in its last interval (forward, right,
            // down), forwarded by the autopilot from the DVL's own link: its mean velocity,
            // stamped at the middle of the interval on the autopilot's clock (the message's
            // own stamp is the sender's clock, which need not be the autopilot's).
            MavMessage::VISION_POSITION_DELTA(d) if d.time_delta_usec > 0 => {
                let dt = d.time_delta_usec as f64 * 1e-6;
                let [u, v, w] = d.position_delta.map(|p| f64::from(p) / dt);
                let t = now - 0.5 * dt;
                if [u, v, w].iter().all(|x| x.is_finite()) && self.in_order(5, t) {
                    out(Observation::Measured(Measurement::VelocityBody { t, u, v, w }));
                }
            }
            MavMessage::GPS_GLOBAL_ORIGIN(o) => {
                let said = (o.latitude, o.longitude);
                self.origin_changes += u64::from(self.origin.is_some_and(|before| before != said));
                self.origin = Some(said);
            }
            MavMessage::GPS_INPUT(g) if g.fix_type as u8 >= FIX_2D => {
                let stated = !g.ignore_flags.contains(GpsInputIgnoreFlags::GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY)
                    && g.horiz_accuracy > 0.0;
                let std = if stated { f64::from(g.horiz_accuracy) } else { f64::NAN };
                self.fix(now, g.lat, g.lon, std, out);
            }
            MavMessage::GLOBAL_VISION_POSITION_ESTIMATE(g) if g.x.is_finite() && g.y.is_finite() => {
                let t = now - self.fix_latency;
                if self.in_order(6, t) {
                    let (x, y) = (f64::from(g.x), f64::from(g.y));
                    out(Observation::Measured(Measurement::Fix { t, x, y, std: f64::NAN }));
                }
            }
            MavMessage::EKF_STATUS_REPORT(e) => {
                self.vertical_velocity_valid = e.flags.contains(EkfStatusFlags::EKF_VELOCITY_VERT)
                    && !e.flags.contains(EkfStatusFlags::EKF_UNINITIALIZED);
            }
            MavMessage::SERVO_OUTPUT_RAW(o) if o.port == 0 => {
                let t = outputs_time(now, o);
                if self.thrusters.is_some() && self.in_order(3, t) {
                    let raw = servo_pwm(o);
                    let since = change_time(self.last_outputs.as_ref(), t, &raw);
                    self.last_outputs = Some((t, raw));
                    let th = self.thrusters.as_ref().expect("checked");
                    out(Observation::Applied(since, th.input_from_commands(&raw.map(f64::from))));
                }
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega::{ATTITUDE_DATA, LOCAL_POSITION_NED_DATA, SCALED_PRESSURE2_DATA};

    /// A change of outputs is dated halfway between the report that first shows it and the one
    /// before; a repeat keeps its report's time, and so does a change after a lost stream.
    #[test]
    fn an_output_change_is_dated_between_the_reports_that_bracket_it() {
        let (a, b) = ([1500u16; 8], [1600u16; 8]);
        assert_eq!(change_time(None, 1.0, &a), 1.0);
        assert!((change_time(Some(&(1.00, a)), 1.02, &b) - 1.01).abs() < 1e-12);
        assert_eq!(change_time(Some(&(1.00, a)), 1.02, &a), 1.02);
        assert_eq!(change_time(Some(&(1.00, a)), 1.50, &b), 1.50);
        // Through the reader: the applied input of the changed report carries the midpoint.
        let vehicle =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ardusub/sitl_vectored.toml");
        let mut m = MavlinkMeasurements::new(1013.25, 1000.0, Some(Thrusters::load(vehicle).unwrap()));
        let mut times = Vec::new();
        for (usec, pwm) in [(1_000_000u32, 1500u16), (1_020_000, 1500), (1_040_000, 1700), (1_060_000, 1700)] {
            let o = SERVO_OUTPUT_RAW_DATA { time_usec: usec, servo1_raw: pwm, ..Default::default() };
            m.observe(1.0, &MavMessage::SERVO_OUTPUT_RAW(o), |ob| {
                if let Observation::Applied(t, _) = ob {
                    times.push(t);
                }
            });
        }
        let want = [1.0, 1.02, 1.03, 1.06];
        assert!(times.iter().zip(want).all(|(t, w)| (t - w).abs() < 1e-9), "{times:?}");
    }

    /// `GLOBAL_POSITION_INT.vz` (cm/s, down) is a vertical velocity once the autopilot's EKF
    /// vouches for it, and not while a local position carries the same number.
    #[test]
    fn the_autopilots_vertical_velocity_is_taken_while_its_ekf_vouches_for_it() {
        use mavlink::dialects::ardupilotmega::{EKF_STATUS_REPORT_DATA, GLOBAL_POSITION_INT_DATA};
        let mut m = MavlinkMeasurements::new(1013.25, 1000.0, None);
        let mut got = Vec::new();
        let global = |ms, vz| {
            MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA { time_boot_ms: ms, vz, ..Default::default() })
        };
        let ekf = |flags| MavMessage::EKF_STATUS_REPORT(EKF_STATUS_REPORT_DATA { flags, ..Default::default() });
        m.observe(0.0, &global(1000, 25), |o| got.push(o));
        m.observe(0.0, &ekf(EkfStatusFlags::EKF_ATTITUDE | EkfStatusFlags::EKF_UNINITIALIZED), |o| got.push(o));
        m.observe(0.0, &global(1080, 25), |o| got.push(o));
        assert!(got.is_empty() && m.vertical_velocity_left_out() == 2);
        m.observe(0.0, &ekf(EkfStatusFlags::EKF_ATTITUDE | EkfStatusFlags::EKF_VELOCITY_VERT), |o| got.push(o));
        m.observe(0.0, &global(1160, -40), |o| got.push(o));
        assert_eq!(got, [Observation::Measured(Measurement::VerticalVelocity { t: 1.16, vd: -0.4 })]);
        let lp = MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA { time_boot_ms: 1200, ..Default::default() });
        m.observe(0.0, &lp, |o| got.push(o));
        m.observe(0.0, &global(1240, 10), |o| got.push(o));
        assert_eq!(got.len(), 3, "the position's velocity holds it: {got:?}");
    }

    /// A `GPS_INPUT` fix is metres north and east of the anchor on ArduPilot's flat earth: the
    /// first fix where it came before the EKF origin, and an origin said later moves nothing;
    /// stamped its latency before it came, with the stated accuracy.
    #[test]
    fn gps_input_fixes_are_placed_from_the_anchor_and_stamped_when_measured() {
        use mavlink::dialects::ardupilotmega::{GPS_GLOBAL_ORIGIN_DATA, GPS_INPUT_DATA, GpsFixType};
        let mut m = MavlinkMeasurements::new(1013.25, 1000.0, None);
        m.set_fix_latency(0.5);
        let mut got = Vec::new();
        let origin = (338_103_130, -1_183_938_670);
        let fix = |dlat: i32, dlon: i32, acc: f32, flags| {
            MavMessage::GPS_INPUT(GPS_INPUT_DATA {
                lat: origin.0 + dlat,
                lon: origin.1 + dlon,
                horiz_accuracy: acc,
                ignore_flags: flags,
                fix_type: GpsFixType::GPS_FIX_TYPE_3D_FIX,
                ..Default::default()
            })
        };
        // Before any origin: the first fix is the anchor, at zero.
        m.observe(10.0, &fix(100, 0, 0.25, GpsInputIgnoreFlags::empty()), |o| got.push(o));
        assert!(matches!(got[0], Observation::Measured(Measurement::Fix { x, y, .. }) if x == 0.0 && y == 0.0));
        assert_eq!((m.fixes_before_origin(), m.anchor()), (1, Some((origin.0 + 100, origin.1))));
        // The origin said later, and then changed: the fixes stay where the anchor puts them.
        for dlat in [0, 300] {
            let o = GPS_GLOBAL_ORIGIN_DATA { latitude: origin.0 + dlat, longitude: origin.1, altitude: 0 };
            m.observe(10.1, &MavMessage::GPS_GLOBAL_ORIGIN(o), |o| got.push(o));
        }
        assert_eq!(m.origin_changes(), 1);
        // 100e-7 deg east at 33.81 deg north is 0.925 m; 100e-7 deg north is 1.113 m.
        m.observe(10.25, &fix(200, 100, 0.25, GpsInputIgnoreFlags::empty()), |o| got.push(o));
        let Observation::Measured(Measurement::Fix { t, x, y, std }) = got[1] else { panic!("{got:?}") };
        assert!((t - 9.75).abs() < 1e-12 && (std - 0.25).abs() < 1e-7, "{t} {std}");
        let scale = (f64::from(origin.0 + 100) * 1e-7).to_radians().cos();
        assert!((x - 1.113188).abs() < 1e-5 && (y - 1.113188 * scale).abs() < 1e-5, "{x} {y}");
        // No stated accuracy: NaN (the filter's own figure); no fix: nothing.
        let ignore = GpsInputIgnoreFlags::GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY;
        m.observe(10.5, &fix(0, 0, 0.25, ignore), |o| got.push(o));
        assert!(matches!(got[2], Observation::Measured(Measurement::Fix { std, .. }) if std.is_nan()));
        let mut none = fix(0, 0, 0.25, ignore);
        if let MavMessage::GPS_INPUT(g) = &mut none {
            g.fix_type = GpsFixType::GPS_FIX_TYPE_NO_FIX;
        }
        m.observe(10.75, &none, |o| got.push(o));
        assert_eq!(got.len(), 3);
    }

    #[test]
    fn messages_become_measurements_and_late_ones_are_dropped() {
        let mut m = MavlinkMeasurements::new(1013.25, 1000.0, None);
        let mut got = Vec::new();
        let attitude = |ms, yaw| {
            MavMessage::ATTITUDE(ATTITUDE_DATA { time_boot_ms: ms, yaw, yawspeed: 0.1, ..Default::default() })
        };
        m.observe(0.0, &attitude(1000, 0.5), |o| got.push(o));
        m.observe(0.0, &attitude(960, 0.4), |o| got.push(o));
        assert_eq!(got.len(), 2, "the late attitude is dropped");
        assert_eq!(m.dropped(), 1);
        // 2 m of fresh water is 196.133 hPa above the surface.
        let p = MavMessage::SCALED_PRESSURE2(SCALED_PRESSURE2_DATA {
            time_boot_ms: 1010,
            press_abs: 1013.25 + 196.133,
            ..Default::default()
        });
        m.observe(0.0, &p, |o| got.push(o));
        let Observation::Measured(Measurement::Depth { z, .. }) = got[2] else { panic!("{:?}", got[2]) };
        assert!((z - 2.0).abs() < 1e-4, "{z}");
        let lp = MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: 990,
            x: 1.0,
            y: 2.0,
            z: 2.1,
            vx: 0.1,
            vy: 0.2,
            vz: 0.3,
        });
        m.observe(0.0, &lp, |o| got.push(o));
        // An older stamp than the newest attitude is fine: each kind keeps its own order. With a
        // depth sensor, the position's depth is left to it.
        let Observation::Measured(Measurement::Position { x, z, .. }) = got[3] else { panic!("{:?}", got[3]) };
        assert!(x == 1.0 && z.is_nan());
        assert!(
            matches!(got[4], Observation::Measured(Measurement::VelocityNed { vd, .. }) if (vd - 0.3).abs() < 1e-6)
        );
        assert!(matches!(got[5], Observation::Unfused(Measurement::Depth { z, .. }) if (z - 2.1).abs() < 1e-6));
    }
}
