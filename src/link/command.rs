//! The one place a body input `[X, Y, Z, Mz]` becomes what ArduSub is sent, in either of the
//! two ways ArduSub owners command a vehicle:
//!
//! - [`CommandWay::Manual`]: the four pilot axes (`MANUAL_CONTROL`) in MANUAL mode. ArduSub's
//!   mixer turns axes into thruster outputs linearly, `o_i = sum_k mix_ik a_k` clipped to
//!   +-1 and PWM `1500 + 400 o_i`, each axis scaled by the joystick gain (`JS_GAIN_DEFAULT`).
//!   pinc allocates the wrench to thrusts through the vehicle file, inverts each thruster's
//!   curve (deadband and asymmetry included) to the PWM it needs, and picks the axes whose
//!   mixed outputs come nearest to those PWMs (least squares over the file's `mix` factors).
//! - [`CommandWay::Thrusters`]: one PWM per thruster in `RC_CHANNELS_OVERRIDE`, with the
//!   thruster outputs set to RC pass-through (`SERVOn_FUNCTION = RCINn`), straight from the
//!   vehicle file's allocation and curves.

use super::link::{LinkError, VehicleLink};
use crate::types::{Input, NU};
use crate::vehicle::{CommandUnit, Thrusters};
use nalgebra::DMatrix;

/// How commands reach the thrusters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandWay {
    /// `MANUAL_CONTROL` pilot axes through ArduSub's MANUAL-mode mixer.
    Manual,
    /// Per-thruster PWM in `RC_CHANNELS_OVERRIDE` (outputs set to RC pass-through).
    Thrusters,
}

impl CommandWay {
    /// `manual` or `thrusters`.
    pub fn name(self) -> &'static str {
        match self {
            CommandWay::Manual => "manual",
            CommandWay::Thrusters => "thrusters",
        }
    }
}

/// One command as sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `MANUAL_CONTROL`: `x` forward, `y` right, `r` yaw right in -1000..=1000, `z` 0..=1000
    /// with 500 neutral and above 500 up.
    Manual {
        /// Forward axis.
        x: i16,
        /// Lateral axis.
        y: i16,
        /// Throttle axis (500 neutral).
        z: i16,
        /// Yaw axis.
        r: i16,
    },
    /// `RC_CHANNELS_OVERRIDE` channels 1-8 (PWM us; `u16::MAX`: leave the channel alone).
    Override([u16; 8]),
}

/// A vehicle file that cannot command in the way asked.
#[derive(Debug, thiserror::Error)]
pub enum CommandError {
    /// MANUAL_CONTROL needs every thruster's ArduSub mixing factors.
    #[error(
        "thruster {thruster} has no `mix` factors: --command manual needs ArduSub's frame factors for every thruster"
    )]
    NoMix {
        /// The thruster's name.
        thruster: String,
    },
    /// RC_CHANNELS_OVERRIDE (MAVLink 1 fields) reaches channels 1-8 only.
    #[error("thruster {thruster} is on output {channel}: --command thrusters overrides channels 1-8 only")]
    Channel {
        /// The thruster's name.
        thruster: String,
        /// Its output channel.
        channel: u8,
    },
    /// Commands are PWM.
    #[error("thruster {thruster}'s curve is in normalised units; commands to ArduSub are PWM (us)")]
    Unit {
        /// The thruster's name.
        thruster: String,
    },
    /// The joystick gain must be in ArduSub's range.
    #[error("--js-gain {0} is outside ArduSub's JS_GAIN range (0.1 to 1)")]
    Gain(f64),
}

/// ArduSub's motor output range: PWM = 1500 + 400 o, o in [-1, 1] (`MOT_PWM_MIN/MAX` 1100/1900).
const PWM_NEUTRAL: f64 = 1500.0;
const PWM_HALF_RANGE: f64 = 400.0;

/// Turns body inputs into commands for one vehicle file and one [`CommandWay`].
#[derive(Debug, Clone)]
pub struct Commander {
    thrusters: Thrusters,
    way: CommandWay,
    js_gain: f64,
    /// n x 4 least-squares inverse of the mix columns (yaw, throttle, forward, lateral).
    axes_from_outputs: Option<DMatrix<f64>>,
}

impl Commander {
    /// A commander for `thrusters`, commanding `way`; `js_gain` is ArduSub's
    /// `JS_GAIN_DEFAULT` (used by [`CommandWay::Manual`] only).
    ///
    /// # Errors
    /// A curve is not in PWM; `Manual` without `mix` factors on every thruster or with a gain
    /// outside 0.1-1; `Thrusters` with a thruster beyond channel 8.
    pub fn new(thrusters: Thrusters, way: CommandWay, js_gain: f64) -> Result<Self, CommandError> {
        for t in &thrusters.list {
            if t.curve.unit != CommandUnit::Pwm {
                return Err(CommandError::Unit { thruster: t.name.clone() });
            }
        }
        let axes_from_outputs = match way {
            CommandWay::Thrusters => {
                if let Some(t) = thrusters.list.iter().find(|t| t.channel > 8) {
                    return Err(CommandError::Channel { thruster: t.name.clone(), channel: t.channel });
                }
                None
            }
            CommandWay::Manual => {
                if !(0.1..=1.0).contains(&js_gain) {
                    return Err(CommandError::Gain(js_gain));
                }
                let n = thrusters.list.len();
                let mut m = DMatrix::zeros(n, 4);
                for (i, t) in thrusters.list.iter().enumerate() {
                    let mix = t.mix.ok_or_else(|| CommandError::NoMix { thruster: t.name.clone() })?;
                    // mix = roll, pitch, yaw, throttle, forward, lateral; MANUAL mode has no
                    // roll or pitch axis. A reversed motor's output is inverted by ArduSub
                    // after mixing, which its mirrored curve already accounts for.
                    for k in 0..4 {
                        m[(i, k)] = mix[k + 2];
                    }
                }
                Some(m.pseudo_inverse(1e-9).expect("a non-negative tolerance"))
            }
        };
        Ok(Self { thrusters, way, js_gain, axes_from_outputs })
    }

    /// The same commander with pilot gain `js_gain` (the autopilot's `JS_GAIN_DEFAULT`).
    ///
    /// # Errors
    /// The gain is outside ArduSub's range.
    pub fn with_js_gain(&self, js_gain: f64) -> Result<Self, CommandError> {
        Self::new(self.thrusters.clone(), self.way, js_gain)
    }

    /// The pilot gain the axes are scaled by.
    pub fn js_gain(&self) -> f64 {
        self.js_gain
    }

    /// The way this commander commands.
    pub fn way(&self) -> CommandWay {
        self.way
    }

    /// The vehicle file's thrusters.
    pub fn thrusters(&self) -> &Thrusters {
        &self.thrusters
    }

    /// The command for body input `input` (NaN components are taken as zero).
    pub fn command(&self, input: &Input) -> Command {
        let clean =
            Input::from(std::array::from_fn::<f64, NU, _>(|j| if input[j].is_finite() { input[j] } else { 0.0 }));
        let pwm = self.thrusters.allocate(&clean).commands;
        match &self.axes_from_outputs {
            None => {
                let mut ch = [u16::MAX; 8];
                for (t, p) in self.thrusters.list.iter().zip(&pwm) {
                    ch[usize::from(t.channel) - 1] = p.round().clamp(1100.0, 1900.0) as u16;
                }
                Command::Override(ch)
            }
            Some(pinv) => {
                // ArduSub turns the mixer's output into whole microseconds toward neutral: a
                // PWM just outside a deadband's edge would land on the edge and give no
                // thrust (measured on the firmware: small yaw moments had no effect and the
                // heading limit-cycled). One microsecond more keeps it outside.
                let margin = |p: f64, t: &crate::vehicle::Thruster| {
                    let (lo, hi) = t.curve.deadband;
                    if p > hi {
                        p.max(hi + 1.0)
                    } else if p < lo {
                        p.min(lo - 1.0)
                    } else {
                        p
                    }
                };
                let outputs = nalgebra::DVector::from_iterator(
                    pwm.len(),
                    pwm.iter()
                        .zip(&self.thrusters.list)
                        .map(|(p, t)| ((margin(*p, t) - PWM_NEUTRAL) / PWM_HALF_RANGE).clamp(-1.0, 1.0)),
                );
                let a = pinv * outputs;
                let (yaw, throttle, forward, lateral) = (a[0], a[1], a[2], a[3]);
                let g = self.js_gain;
                let axis = |v: f64| (v * 1000.0 / g).round().clamp(-1000.0, 1000.0) as i16;
                // Throttle above 500 is up; the mixer's throttle factor already carries the
                // sign (vertical thrusters have factor -1 with +z down).
                let z = (500.0 + throttle * 500.0 / g).round().clamp(0.0, 1000.0) as i16;
                Command::Manual { x: axis(forward), y: axis(lateral), z, r: axis(yaw) }
            }
        }
    }

    /// The command that stops every thruster: centred axes, or each thruster at its curve's
    /// neutral (1500 us).
    pub fn neutral(&self) -> Command {
        match self.way {
            CommandWay::Manual => Command::Manual { x: 0, y: 0, z: 500, r: 0 },
            CommandWay::Thrusters => {
                let mut ch = [u16::MAX; 8];
                for t in &self.thrusters.list {
                    ch[usize::from(t.channel) - 1] = t.curve.unit.neutral() as u16;
                }
                Command::Override(ch)
            }
        }
    }

    /// The body input ArduSub's mixer (manual) or the thrusters (override) make of
    /// `command`: the PWM per output it leads to, through the vehicle file's curves.
    pub fn input_of(&self, command: &Command) -> Input {
        let mut pwm = vec![f64::NAN; 32];
        match command {
            Command::Override(ch) => {
                for t in &self.thrusters.list {
                    let c = ch[usize::from(t.channel) - 1];
                    pwm[usize::from(t.channel) - 1] = if c == u16::MAX || c == 0 { PWM_NEUTRAL } else { f64::from(c) };
                }
            }
            Command::Manual { x, y, z, r } => {
                let g = self.js_gain;
                let axes = [
                    g * f64::from(*r) / 1000.0,
                    g * (f64::from(*z) - 500.0) / 500.0,
                    g * f64::from(*x) / 1000.0,
                    g * f64::from(*y) / 1000.0,
                ];
                for t in &self.thrusters.list {
                    let mix = t.mix.unwrap_or([0.0; 6]);
                    let o: f64 = (0..4).map(|k| mix[k + 2] * axes[k]).sum();
                    // ArduSub rounds to whole microseconds.
                    pwm[usize::from(t.channel) - 1] = (PWM_NEUTRAL + PWM_HALF_RANGE * o.clamp(-1.0, 1.0)).round();
                }
            }
        }
        self.thrusters.input_from_commands(&pwm)
    }

    /// Sends `command` on `link`.
    ///
    /// # Errors
    /// Writing fails.
    pub fn send(&self, link: &VehicleLink, command: &Command) -> Result<(), LinkError> {
        match *command {
            Command::Manual { x, y, z, r } => link.manual_control(x, y, z, r),
            Command::Override(ch) => link.rc_override(ch),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sitl() -> Thrusters {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ardusub/sitl_vectored.toml");
        Thrusters::load(path).unwrap()
    }

    /// Both ways give back the asked input through the vehicle file's own curves (the
    /// override exactly up to whole-microsecond rounding, the axes as far as the mixer's
    /// linear outputs can follow the curve's inverse).
    #[test]
    fn both_ways_deliver_the_asked_input() {
        for (way, tol) in [(CommandWay::Thrusters, 0.02), (CommandWay::Manual, 0.06)] {
            let c = Commander::new(sitl(), way, 1.0).unwrap();
            for want in
                [[60.0, 0.0, 0.0, 0.0], [0.0, -40.0, 30.0, 0.0], [20.0, 10.0, -50.0, 8.0], [0.0, 0.0, 0.0, -15.0]]
            {
                let got = c.input_of(&c.command(&Input::from(want)));
                for j in 0..NU {
                    let scale = if j == 3 { 51.5 } else { 100.0 };
                    assert!((got[j] - want[j]).abs() <= tol * scale, "{way:?} {want:?}: got {:?}", got.as_slice());
                }
            }
            assert!(c.input_of(&c.neutral()).iter().all(|v| *v == 0.0));
        }
    }

    /// Forward alone on the vectored frame: the forward axis only, with ArduSub's sign
    /// (thrusters 1-2 back, 3-4 forward); up (Z < 0) is throttle above 500.
    #[test]
    fn forward_is_the_x_axis_and_up_is_throttle_above_neutral() {
        let c = Commander::new(sitl(), CommandWay::Manual, 1.0).unwrap();
        let Command::Manual { x, y, z, r } = c.command(&Input::from([30.0, 0.0, 0.0, 0.0])) else { panic!() };
        // 7.5 N along each horizontal thruster's axis, 10.6 N along its 45-degree direction:
        // s = sqrt(10.6 / 72.8) = 0.38 of full output.
        assert!((370..=395).contains(&x) && y == 0 && z == 500 && r == 0, "{x} {y} {z} {r}");
        let Command::Manual { z, .. } = c.command(&Input::from([0.0, 0.0, -40.0, 0.0])) else { panic!() };
        assert!(z > 500);
        // A gain of 0.5 doubles the axis for the same input.
        let half = Commander::new(sitl(), CommandWay::Manual, 0.5).unwrap();
        let Command::Manual { x: x2, .. } = half.command(&Input::from([30.0, 0.0, 0.0, 0.0])) else { panic!() };
        assert!((i32::from(x2) - 2 * i32::from(x)).abs() <= 1);
    }

    #[test]
    fn manual_without_mix_factors_is_refused_by_name() {
        let mut t = sitl();
        t.list[2].mix = None;
        let e = Commander::new(Thrusters::new(t.list), CommandWay::Manual, 1.0).unwrap_err();
        assert!(e.to_string().contains("rear_right"), "{e}");
    }
}
