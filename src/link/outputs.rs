//! What the autopilot's servo outputs carry (`SERVOn_FUNCTION`), and so which way of
//! commanding reaches the thrusters. A stock BlueROV2's outputs are the autopilot's own motors
//! (functions 33-44: `Motor1`..`Motor12`): pilot axes (`MANUAL_CONTROL`) reach them through its
//! mixer, while `RC_CHANNELS_OVERRIDE` channels 1-6 are read as pitch, roll, throttle, yaw,
//! forward and lateral, so per-thruster PWMs sent there tumble the vehicle. Per-thruster
//! commands reach a thruster only where its output passes an RC channel through: function
//! `RCINn` (50 + n) for RC channel n, or `RCPassThru` (1, the channel of the same number).

use super::command::CommandWay;
use super::params::Params;
use crate::vehicle::Thrusters;
use std::collections::BTreeMap;

/// The outputs pinc asks about: ArduSub drives at most eight thrusters, and
/// `RC_CHANNELS_OVERRIDE`'s first eight channels are all pinc sends.
pub const OUTPUTS: u8 = 8;

/// `SERVOn_FUNCTION` of `RCPassThru`: the RC input of the output's own number.
const RC_PASS_THRU: i64 = 1;
/// `SERVOn_FUNCTION` of `Motor1`; `Motor12` is 44.
const MOTOR1: i64 = 33;
/// `SERVOn_FUNCTION` of `RCIN1`; `RCIN16` is 66.
const RCIN1: i64 = 51;

/// The parameter name of output `n`'s function.
pub fn function_param(n: u8) -> String {
    format!("SERVO{n}_FUNCTION")
}

/// The parameter names of every output pinc asks about.
pub fn function_params() -> Vec<String> {
    (1..=OUTPUTS).map(function_param).collect()
}

/// ArduPilot's name of a servo function.
pub fn function_name(f: i64) -> String {
    match f {
        0 => "Disabled".into(),
        RC_PASS_THRU => "RCPassThru".into(),
        MOTOR1..=44 => format!("Motor{}", f - MOTOR1 + 1),
        RCIN1..=66 => format!("RCIN{}", f - RCIN1 + 1),
        _ => format!("function {f}"),
    }
}

/// The autopilot's output functions, as read.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct OutputFunctions {
    /// Output number (1-based) to its function; an output whose parameter did not answer is
    /// absent.
    pub by_output: BTreeMap<u8, i64>,
}

/// Why a way of commanding cannot reach the thrusters.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("--command {way} cannot reach the thrusters on this autopilot: {outputs}. {consequence} {remedy}", way = way.name())]
pub struct WayRefused {
    /// The way refused.
    pub way: CommandWay,
    /// Each output that does not carry what the way needs, with what it carries.
    pub outputs: String,
    /// What commanding that way would do.
    pub consequence: String,
    /// What to do instead.
    pub remedy: String,
}

impl OutputFunctions {
    /// The functions among `params` ([`function_params`]).
    pub fn from_params(params: &Params) -> Self {
        let by_output =
            (1..=OUTPUTS).filter_map(|n| params.get(&function_param(n)).map(|v| (n, v.round() as i64))).collect();
        Self { by_output }
    }

    /// Whether output `n` passes RC channel `n` through unchanged.
    pub fn passes_through(&self, n: u8) -> bool {
        self.by_output.get(&n).is_some_and(|&f| f == RC_PASS_THRU || f == RCIN1 - 1 + i64::from(n))
    }

    /// Whether output `n` is one of the autopilot's motors (its mixer drives it).
    pub fn is_motor(&self, n: u8) -> bool {
        self.by_output.get(&n).is_some_and(|f| (MOTOR1..=44).contains(f))
    }

    fn describe(&self, n: u8) -> String {
        match self.by_output.get(&n) {
            Some(&f) => format!("SERVO{n}_FUNCTION is {f} ({})", function_name(f)),
            None => format!("SERVO{n}_FUNCTION was not answered"),
        }
    }

    /// Checks that commands sent `way` reach every thruster of `thrusters`: for
    /// [`CommandWay::Thrusters`] every thruster's output must pass its RC channel through; for
    /// [`CommandWay::Manual`] every thruster's output must be one of the autopilot's motors.
    ///
    /// # Errors
    /// The outputs that do not, each named with its function, what commanding that way would
    /// do, and what to do instead.
    pub fn check(&self, way: CommandWay, thrusters: &Thrusters) -> Result<(), WayRefused> {
        let named: Vec<(String, u8)> =
            thrusters.list.iter().map(|t| (format!("thruster {}", t.name), t.channel)).collect();
        self.check_outputs(way, &named)
    }

    /// As [`OutputFunctions::check`], for outputs named by what drives them (`pinc vehicle
    /// status` without a vehicle file checks a BlueROV2's six, "output 1".."output 6").
    ///
    /// # Errors
    /// As [`OutputFunctions::check`].
    pub fn check_outputs(&self, way: CommandWay, outputs: &[(String, u8)]) -> Result<(), WayRefused> {
        let wrong: Vec<String> = outputs
            .iter()
            .filter(|(_, n)| match way {
                CommandWay::Thrusters => !self.passes_through(*n),
                CommandWay::Manual => !self.is_motor(*n),
            })
            .map(|(name, n)| format!("{name} is on output {n}, whose {}", self.describe(*n)))
            .collect();
        if wrong.is_empty() {
            return Ok(());
        }
        let outputs = wrong.join("; ");
        Err(match way {
            CommandWay::Thrusters => WayRefused {
                way,
                outputs,
                consequence: "Per-thruster PWMs on RC channels that are not passed through reach the autopilot as \
                              pilot axes (channels 1-6: pitch, roll, throttle, yaw, forward, lateral) and tumble the \
                              vehicle."
                    .into(),
                remedy: "Use --command manual (pilot axes through the autopilot's own mixer, as a stock vehicle \
                         takes them), or set SERVOn_FUNCTION = 50 + n on each thruster's output n; pass-through \
                         bypasses the autopilot's mixer and its motor failsafes (pinc's stops remain)."
                    .into(),
            },
            CommandWay::Manual => WayRefused {
                way,
                outputs,
                consequence: "Pilot axes (MANUAL_CONTROL) reach only the outputs the autopilot mixes as its motors."
                    .into(),
                remedy: "Use --command thrusters on outputs set to RC pass-through, or give the outputs their motor \
                         functions (SERVOn_FUNCTION = 32 + n)."
                    .into(),
            },
        })
    }

    /// Which ways reach `outputs`, each with its refusal if it does not.
    pub fn ways(&self, outputs: &[(String, u8)]) -> Vec<(CommandWay, Result<(), WayRefused>)> {
        [CommandWay::Manual, CommandWay::Thrusters].into_iter().map(|w| (w, self.check_outputs(w, outputs))).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ArduSub's simulator's vectored frame: six thrusters on outputs 1-6.
    fn six_thrusters() -> Thrusters {
        Thrusters::load(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/ardusub/sitl_vectored.toml"))
            .expect("the fixture's thrusters")
    }

    fn functions(f: impl Fn(u8) -> f64) -> OutputFunctions {
        let names = function_params();
        OutputFunctions::from_params(&Params::from_pairs(
            names.iter().zip(1..=OUTPUTS).map(|(k, n)| (k.as_str(), f(n))),
        ))
    }

    #[test]
    fn a_stock_autopilot_takes_pilot_axes_and_refuses_per_thruster_pwm_naming_each_output() {
        let stock = functions(|n| 32.0 + f64::from(n));
        let t = six_thrusters();
        assert!(stock.check(CommandWay::Manual, &t).is_ok());
        let refused = stock.check(CommandWay::Thrusters, &t).unwrap_err();
        let text = refused.to_string();
        for n in 1..=6 {
            assert!(text.contains(&format!("SERVO{n}_FUNCTION is {} (Motor{n})", 32 + n)), "{text}");
        }
        assert!(text.contains("pilot axes") && text.contains("--command manual"), "{text}");
    }

    #[test]
    fn pass_through_outputs_take_per_thruster_pwm_and_not_pilot_axes() {
        let through = functions(|n| 50.0 + f64::from(n));
        let t = six_thrusters();
        assert!(through.check(CommandWay::Thrusters, &t).is_ok());
        assert!(through.check(CommandWay::Manual, &t).is_err());
        // RCPassThru (1) passes the output's own channel too; RCIN of another channel does not.
        let mixed = functions(|n| match n {
            1 => 1.0,
            2 => 53.0,
            n => 50.0 + f64::from(n),
        });
        let e = mixed.check(CommandWay::Thrusters, &t).unwrap_err().to_string();
        assert!(e.contains("output 2") && e.contains("RCIN3") && !e.contains("output 1,"), "{e}");
    }

    #[test]
    fn an_output_the_autopilot_did_not_answer_is_refused_for_either_way() {
        let names = function_params();
        let partial =
            OutputFunctions::from_params(&Params::from_pairs(names.iter().take(5).map(|k| (k.as_str(), 33.0))));
        let e = partial.check(CommandWay::Manual, &six_thrusters()).unwrap_err().to_string();
        assert!(e.contains("SERVO6_FUNCTION was not answered"), "{e}");
    }
}
