//! What the two ArduPilot readers share (docs/LOGS_ARDUPILOT.md): their options, the
//! conversion of thruster outputs or pilot commands into body inputs, and the assembly of the
//! decoded messages into a [`StreamSet`].

use super::ImportError;
use super::streams::{Series, StreamSet};
use crate::types::Input;
use std::f64::consts::PI;
use std::path::Path;

/// Converts thruster commands, indexed by output channel (`commands[c - 1]` is channel `c`,
/// PWM in microseconds, 0 where the channel is off), into the body input `[X, Y, Z, Mz]`.
pub type ThrusterConversion = Box<dyn Fn(&[f64]) -> Input + Send + Sync>;

/// Where the body inputs come from.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum InputSource {
    /// No inputs (the stream set has no `input`).
    #[default]
    None,
    /// The thruster outputs the autopilot logged (`RCOU` in a .BIN, `SERVO_OUTPUT_RAW` in a
    /// .tlog), through [`ArdupilotOptions::thrusters`].
    ThrusterOutputs,
    /// The pilot's commands (`MANUAL_CONTROL` in a .tlog, the `RCIN` channels in a .BIN),
    /// turned into thruster PWM by ArduSub's MANUAL-mode map ([`pilot_to_pwm`]) and then
    /// through [`ArdupilotOptions::thrusters`].
    ManualControl {
        /// The joystick gain `g` (ArduSub's `JS_GAIN_DEFAULT` while the pilot did not change it).
        gain: f64,
        /// Per thruster, in channel order: its factors `[forward, lateral, throttle, yaw]`
        /// (ArduSub's frame mixing factors with the motor direction applied), e.g.
        /// [`BLUEROV2_VECTORED_MIX`].
        mix: Vec<[f64; 4]>,
    },
}

/// ArduSub's `vectored` frame (the BlueROV2's), thrusters 1-6 on channels 1-6: factors
/// `[forward, lateral, throttle, yaw]` of `AP_Motors6DOF` for `SUB_FRAME_VECTORED`, checked
/// against the simulator's own `RCIN` -> `RCOU` in `sitl_excite_1.BIN`.
pub const BLUEROV2_VECTORED_MIX: [[f64; 4]; 6] = [
    [-1.0, 1.0, 0.0, 1.0],
    [-1.0, -1.0, 0.0, -1.0],
    [1.0, 1.0, 0.0, -1.0],
    [1.0, -1.0, 0.0, 1.0],
    [0.0, 0.0, -1.0, 0.0],
    [0.0, 0.0, -1.0, 0.0],
];

/// How the ArduPilot readers read a log.
pub struct ArdupilotOptions {
    /// Where the inputs come from.
    pub inputs: InputSource,
    /// PWM by channel -> body input: the vehicle file's thrusters. Required unless `inputs`
    /// is [`InputSource::None`].
    pub thrusters: Option<ThrusterConversion>,
    /// .BIN only: the `BARO` instance whose `Alt` gives the depth; `None` takes the highest
    /// instance in the log (on a BlueROV2 the external water-pressure sensor comes after the
    /// one inside the enclosure).
    pub baro_instance: Option<u8>,
    /// .tlog only: water density (kg/m^3) that turns `press_abs` into depth.
    pub water_density: f64,
    /// .tlog only: the pressure at the surface (Pa); `None` takes the first sample (ArduSub
    /// also calibrates its depth at boot, on the surface).
    pub surface_pressure: Option<f64>,
}

impl Default for ArdupilotOptions {
    fn default() -> Self {
        Self {
            inputs: InputSource::None,
            thrusters: None,
            baro_instance: None,
            water_density: 1000.0,
            surface_pressure: None,
        }
    }
}

impl std::fmt::Debug for ArdupilotOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ArdupilotOptions")
            .field("inputs", &self.inputs)
            .field("thrusters", &self.thrusters.as_ref().map(|_| "conversion"))
            .field("baro_instance", &self.baro_instance)
            .field("water_density", &self.water_density)
            .field("surface_pressure", &self.surface_pressure)
            .finish()
    }
}

/// `MANUAL_CONTROL`'s `x, y, z, r` (-1000..1000, `z` 0..1000) as the normalised pilot axes
/// `[forward, lateral, throttle, yaw]` ArduSub's MANUAL mode feeds its mixer: its RC override
/// is `1500 + 0.4 g x` (also `y`, `r`) and `1500 + 0.8 g (z - 500)` microseconds, and an axis
/// is `(pwm - 1500) / 400`.
pub fn manual_control_axes(x: f64, y: f64, z: f64, r: f64, gain: f64) -> [f64; 4] {
    [gain * x / 1000.0, gain * y / 1000.0, gain * (z - 500.0) / 500.0, gain * r / 1000.0]
}

/// ArduSub's MANUAL-mode mixing: per thruster `i`, PWM `1500 + 400 s_i` with
/// `s_i = clamp(F_i a_fwd + L_i a_lat + T_i a_thr + Y_i a_yaw, -1, 1)`, where `mix[i]` is
/// `[F_i, L_i, T_i, Y_i]` and `axes` the normalised pilot axes `[forward, lateral, throttle,
/// yaw]` ([`manual_control_axes`]). Index `i` is channel `i + 1`.
pub fn pilot_to_pwm(axes: [f64; 4], mix: &[[f64; 4]]) -> Vec<f64> {
    mix.iter()
        .map(|m| {
            let s: f64 = m.iter().zip(axes).map(|(f, a)| f * a).sum();
            1500.0 + 400.0 * s.clamp(-1.0, 1.0)
        })
        .collect()
}

/// Wraps an angle to `(-pi, pi]`.
pub(crate) fn wrap_pi(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

/// What a reader decoded, before it becomes a [`StreamSet`]: times on the autopilot's boot
/// clock (s), values already in pinc's units and frames.
#[derive(Debug, Default)]
pub(crate) struct Decoded {
    pub attitude: Option<Series<3>>,
    pub yaw_rate: Option<Series<1>>,
    pub position: Option<Series<3>>,
    pub velocity_ned: Option<Series<3>>,
    pub depth: Option<Series<1>>,
    /// Thruster PWM by channel.
    pub outputs: Option<(String, Vec<f64>, Vec<Vec<f64>>)>,
    /// Normalised pilot axes `[forward, lateral, throttle, yaw]` (ArduSub's gain already
    /// applied where the log holds the RC channels; for `MANUAL_CONTROL` the raw `x y z r`).
    pub pilot: Option<Series<4>>,
    pub notes: Vec<String>,
}

/// `n samples at f Hz over [a, b] s` for the notes.
pub(crate) fn rate_note<const N: usize>(s: &Series<N>) -> String {
    let n = s.len();
    match (s.t.first(), s.t.last()) {
        (Some(a), Some(b)) if n > 1 && b > a => {
            format!("{}: {n} samples, {:.1} Hz, boot time {a:.3}-{b:.3} s", s.source, (n - 1) as f64 / (b - a))
        }
        _ => format!("{}: {n} samples", s.source),
    }
}

/// Assembles the stream set, converting the inputs as `opts` says.
pub(crate) fn build(
    path: &Path,
    mut d: Decoded,
    opts: &ArdupilotOptions,
    manual_control_raw: bool,
) -> Result<StreamSet, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: path.to_path_buf(), message };
    let mut set = StreamSet { notes: std::mem::take(&mut d.notes), ..StreamSet::default() };
    let nonempty = |s: Option<Series<3>>| s.filter(|s| !s.is_empty());
    set.attitude = nonempty(d.attitude);
    set.position = nonempty(d.position);
    set.velocity_ned = nonempty(d.velocity_ned);
    set.yaw_rate = d.yaw_rate.filter(|s| !s.is_empty());
    let Some(att) = &set.attitude else {
        return Err(malformed("no attitude: the log holds no ATT / ATTITUDE message".into()));
    };
    set.notes.push(rate_note(att));
    if let Some(r) = &set.yaw_rate {
        set.notes.push(rate_note(r));
    } else {
        set.notes.push("yaw rate: not logged; taken from the yaw's derivative".into());
    }
    match &set.position {
        Some(p) => {
            set.notes.push(rate_note(p));
            let t0 = att.t[0];
            if p.t[0] > t0 + 1.0 {
                set.notes.push(format!(
                    "{}: the EKF's position starts {:.1} s after the attitude (boot time {:.3} s): no position before",
                    p.source,
                    p.t[0] - t0,
                    p.t[0]
                ));
            }
        }
        None => set.notes.push("position: none in the log (the EKF never gave one)".into()),
    }
    if let Some(v) = &set.velocity_ned {
        set.notes.push(rate_note(v));
    }
    // The pressure depth only where there is no position: the EKF's z already fuses it.
    match (d.depth.filter(|s| !s.is_empty()), &set.position) {
        (Some(depth), None) => {
            set.notes.push(rate_note(&depth));
            set.depth = Some(depth);
        }
        (Some(depth), Some(_)) => set.notes.push(format!("{}: not used, the EKF's position gives z", depth.source)),
        (None, None) => {
            return Err(malformed("no position (EKF) and no depth (pressure sensor) in the log".into()));
        }
        (None, Some(_)) => {}
    }
    let convert = |what: &str| {
        opts.thrusters.as_ref().ok_or_else(|| {
            ImportError::Unusable(format!(
                "inputs from {what} need the vehicle's thrusters (ArdupilotOptions::thrusters)"
            ))
        })
    };
    match &opts.inputs {
        InputSource::None => set.notes.push("inputs: none read".into()),
        InputSource::ThrusterOutputs => {
            let conv = convert("thruster outputs")?;
            let Some((source, t, pwm)) = d.outputs.filter(|o| !o.1.is_empty()) else {
                return Err(malformed("inputs from thruster outputs: no RCOU / SERVO_OUTPUT_RAW message".into()));
            };
            let mut s = Series::new(format!("{source} through the vehicle's thrusters"));
            for (t, p) in t.iter().zip(&pwm) {
                let u = conv(p);
                s.push(*t, [u[0], u[1], u[2], u[3]]);
            }
            set.notes.push(rate_note(&s));
            set.input = Some(s);
        }
        InputSource::ManualControl { gain, mix } => {
            let conv = convert("pilot commands")?;
            let Some(pilot) = d.pilot.filter(|p| !p.is_empty()) else {
                return Err(malformed("inputs from pilot commands: no MANUAL_CONTROL / RCIN message".into()));
            };
            let mut s = Series::new(format!(
                "{} through ArduSub's MANUAL map (gain {gain}) and the vehicle's thrusters",
                pilot.source
            ));
            for (t, a) in pilot.t.iter().zip(&pilot.v) {
                let axes = if manual_control_raw { manual_control_axes(a[0], a[1], a[2], a[3], *gain) } else { *a };
                let u = conv(&pilot_to_pwm(axes, mix));
                s.push(*t, [u[0], u[1], u[2], u[3]]);
            }
            set.notes.push(rate_note(&s));
            set.notes.push(format!(
                "inputs: pilot commands mapped as ArduSub's MANUAL mode does, PWM_i = 1500 + 400 clamp(sum mix_i * axis, -1, 1) over {} thrusters",
                mix.len()
            ));
            set.input = Some(s);
        }
    }
    Ok(set)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_control_map_matches_ardusub_rc_override() {
        // Full forward stick, gain 1: forward axis 1; z at mid (500) is no throttle.
        assert_eq!(manual_control_axes(1000.0, 0.0, 500.0, 0.0, 1.0), [1.0, 0.0, 0.0, 0.0]);
        // z = 0 is full down: throttle axis -1 at gain 1, -0.5 at gain 0.5.
        assert_eq!(manual_control_axes(0.0, 0.0, 0.0, 0.0, 0.5)[2], -0.5);
        // Forward 0.5: thrusters 1, 2 at 1300, 3, 4 at 1700, vertical ones idle.
        let pwm = pilot_to_pwm([0.5, 0.0, 0.0, 0.0], &BLUEROV2_VECTORED_MIX);
        assert_eq!(pwm, vec![1300.0, 1300.0, 1700.0, 1700.0, 1500.0, 1500.0]);
        // Saturation at +-1 per thruster.
        let pwm = pilot_to_pwm([1.0, 1.0, 0.0, 1.0], &BLUEROV2_VECTORED_MIX);
        assert_eq!(pwm[0], 1900.0);
        assert_eq!(pwm[1], 1100.0);
    }

    #[test]
    fn wrap_pi_range() {
        assert!((wrap_pi(1.5 * PI) + 0.5 * PI).abs() < 1e-12);
        assert!((wrap_pi(PI) - PI).abs() < 1e-12);
        assert!((wrap_pi(-PI) - PI).abs() < 1e-12);
    }
}
