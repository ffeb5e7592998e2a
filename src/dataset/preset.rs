//! What each dataset preset generates: the paper protocol (docs/MODEL.md section 2) and an
//! operating-envelope preset for model-predictive control.

use crate::types::{NS, NU};
use crate::vehicle::{VehicleParams, terminal_speed};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Per-component uniform ranges of the initial state, in the simulator form
/// `[x, y, z, psi, u, v, w, r]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitialRanges {
    /// Lower bounds.
    pub lo: [f64; NS],
    /// Upper bounds (equal to `lo` for a fixed component).
    pub hi: [f64; NS],
}

/// How the inputs of a trajectory are drawn (one value per sample interval, held).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Excitation {
    /// The paper's training inputs: per channel a random sign, an offset
    /// ~ Normal(0, `offset_std`^2) and a triangular ramp 0 -> 1 (mid-trajectory) -> 0;
    /// value = sign * ramp - 0.5 * sign + offset.
    Ramp {
        /// Standard deviation of the offset. Paper: 0.5
        offset_std: f64,
    },
    /// Independent sines per channel, `amplitude * sin(2 pi f t + phase)`.
    Sine {
        /// Amplitude. Paper: 3
        amplitude: f64,
        /// Lowest frequency (Hz). Paper: 0.01
        f_min_hz: f64,
        /// Highest frequency (Hz). Paper: 0.2
        f_max_hz: f64,
    },
    /// The same input throughout.
    Constant {
        /// `[X, Y, Z, Mz]`.
        input: [f64; NU],
    },
    /// Constant surge with a sinusoidal yaw moment.
    Figure8 {
        /// Surge force (N).
        surge: f64,
        /// Yaw-moment amplitude (N m).
        moment: f64,
        /// Yaw-moment frequency (Hz).
        freq_hz: f64,
    },
    /// Per channel and trajectory one of random steps, random ramps or a multisine,
    /// clipped to `[lo, hi]`, so that depth and heading manoeuvres are covered.
    Mixed {
        /// Lower input bounds `[X, Y, Z, Mz]`.
        lo: [f64; NU],
        /// Upper input bounds.
        hi: [f64; NU],
    },
    /// Inputs recorded in the water (`pinc dataset import`): such a set is loaded from its
    /// folder, never generated (generating it would hold zero inputs).
    Recorded,
}

/// One set of trajectories.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetSpec {
    /// Name, also the folder of its arrays.
    pub name: String,
    /// Number of trajectories.
    pub count: usize,
    /// Points per trajectory, including the initial state.
    pub points: usize,
    /// Sample period (s).
    pub dt: f64,
    /// Initial-state distribution.
    pub initial: InitialRanges,
    /// Input distribution.
    pub excitation: Excitation,
    /// Apply the paper's input scaling after generation: `Y *= 0.1, Z = 5|Z|, Mz *= 0.05`.
    pub paper_scaling: bool,
    /// Collocation times per interval for the physics loss: 0 for none, 1 for a single
    /// point at `t = dt`, more for a Latin-hypercube sample of `[0, dt]`.
    pub collocation_points: usize,
}

/// A named collection of sets generated together from one seed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetPreset {
    /// Preset name (`paper` or `mpc`).
    pub name: String,
    /// The sets, in generation order.
    pub sets: Vec<SetSpec>,
    /// The vehicle the trajectories are simulated with (manifests without one were
    /// generated with the BlueROV2). Default: the BlueROV2.
    #[serde(default)]
    pub vehicle: VehicleParams,
}

/// Points per trajectory in both presets: 5.2 s at 0.08 s.
pub const TRAJECTORY_POINTS: usize = 66;

impl DatasetPreset {
    /// Looks a preset up by name.
    pub fn by_name(name: &str) -> Option<Self> {
        match name {
            "paper" => Some(Self::paper()),
            "mpc" => Some(Self::mpc()),
            _ => None,
        }
    }

    /// The set named `name`, if the preset has one.
    pub fn set(&self, name: &str) -> Option<&SetSpec> {
        self.sets.iter().find(|s| s.name == name)
    }

    /// The paper protocol: training (400 ramp trajectories), development (80 for training,
    /// 1000 for evaluation), interpolation (T = 0.06 s) and extrapolation (T = 0.10 s) test
    /// sets of 1000 sine trajectories, and the line / circle / figure-8 trajectories.
    pub fn paper() -> Self {
        let train_initial = InitialRanges {
            lo: [-1.0, -1.0, -1.0, -PI, -1.0, 0.0, 0.0, 0.0],
            // w is |U(-0.1, 0.1)|, which is U(0, 0.1).
            hi: [1.0, 1.0, 1.0, PI, 1.0, 0.0, 0.1, 0.0],
        };
        let test_initial =
            InitialRanges { lo: [0.0, 0.0, 0.0, -PI, 0.0, 0.0, 0.0, 0.0], hi: [0.0, 0.0, 0.0, PI, 0.0, 0.0, 0.0, 0.0] };
        let sine = Excitation::Sine { amplitude: 3.0, f_min_hz: 0.01, f_max_hz: 0.2 };
        let at_rest = InitialRanges { lo: [0.0; NS], hi: [0.0; NS] };
        let set = |name: &str, count, dt, initial: &InitialRanges, excitation: &Excitation, scaled, colloc| SetSpec {
            name: name.into(),
            count,
            points: TRAJECTORY_POINTS,
            dt,
            initial: initial.clone(),
            excitation: excitation.clone(),
            paper_scaling: scaled,
            collocation_points: colloc,
        };
        Self {
            name: "paper".into(),
            sets: vec![
                set("train", 400, 0.08, &train_initial, &Excitation::Ramp { offset_std: 0.5 }, true, 1),
                set("dev", 80, 0.08, &test_initial, &sine, true, 0),
                set("dev_eval", 1000, 0.08, &test_initial, &sine, true, 0),
                set("interp", 1000, 0.06, &test_initial, &sine, true, 0),
                set("extrap", 1000, 0.10, &test_initial, &sine, true, 0),
                set("line", 1, 0.08, &at_rest, &Excitation::Constant { input: [5.0, 0.0, 0.0, 0.0] }, false, 0),
                set("circle", 1, 0.08, &at_rest, &Excitation::Constant { input: [5.0, 0.0, 0.0, 0.5] }, false, 0),
                set(
                    "figure8",
                    1,
                    0.08,
                    &at_rest,
                    &Excitation::Figure8 { surge: 5.0, moment: 1.0, freq_hz: 0.2 },
                    false,
                    0,
                ),
            ],
            vehicle: VehicleParams::default(),
        }
    }

    /// The controller's operating envelope: the BlueROV2's whole thrust range
    /// ([`BLUEROV2_INPUT_LO`], [`BLUEROV2_INPUT_HI`]), with initial velocities inside what those
    /// inputs can reach and mixed step / ramp / multisine excitation.
    pub fn mpc() -> Self {
        Self::mpc_for(VehicleParams::default())
    }

    /// [`DatasetPreset::mpc`] for another vehicle: its initial velocities are what that
    /// vehicle reaches with the same inputs.
    pub fn mpc_for(vehicle: VehicleParams) -> Self {
        Self::mpc_with_bounds(vehicle, BLUEROV2_INPUT_LO, BLUEROV2_INPUT_HI)
    }

    /// [`DatasetPreset::mpc_for`] with its own input bounds, e.g. a vehicle file's thrusters'
    /// reachable box ([`input_bounds_from_file`]).
    pub fn mpc_with_bounds(vehicle: VehicleParams, lo: [f64; NU], hi: [f64; NU]) -> Self {
        let v = reachable_velocities(&vehicle, lo, hi);
        let initial = InitialRanges {
            lo: [-1.0, -1.0, 0.0, -PI, v.lo[0], v.lo[1], v.lo[2], v.lo[3]],
            hi: [1.0, 1.0, 3.0, PI, v.hi[0], v.hi[1], v.hi[2], v.hi[3]],
        };
        let excitation = Excitation::Mixed { lo, hi };
        let set = |name: &str, count, dt, colloc| SetSpec {
            name: name.into(),
            count,
            points: TRAJECTORY_POINTS,
            dt,
            initial: initial.clone(),
            excitation: excitation.clone(),
            paper_scaling: false,
            collocation_points: colloc,
        };
        Self {
            name: "mpc".into(),
            sets: vec![
                set("train", 2000, 0.08, 1),
                set("dev", 100, 0.08, 0),
                set("dev_eval", 1000, 0.08, 0),
                set("interp", 1000, 0.06, 0),
                set("extrap", 1000, 0.10, 0),
            ],
            vehicle,
        }
    }

    /// The preset `name` (`paper` or `mpc`) simulated with `vehicle`.
    pub fn by_name_for(name: &str, vehicle: VehicleParams) -> Option<Self> {
        match name {
            "mpc" => Some(Self::mpc_for(vehicle)),
            _ => Self::by_name(name).map(|p| Self { vehicle, ..p }),
        }
    }
}

/// The BlueROV2's largest body forces and yaw moment `[X, Y, Z, Mz]` (N, N m), from Blue
/// Robotics' published bollard thrust of the standard six-thruster vehicle (9 kgf forward and
/// lateral, 7 kgf vertical) and the vectored thrusters' 0.1888 m yaw arm (docs/MODEL.md
/// section 2.3 gives the sources and the arithmetic).
pub const BLUEROV2_INPUT_HI: [f64; NU] = [88.3, 88.3, 68.7, 23.6];
/// The lower limits: the vectored and vertical layouts push both ways (see [`BLUEROV2_INPUT_HI`]).
pub const BLUEROV2_INPUT_LO: [f64; NU] = [-88.3, -88.3, -68.7, -23.6];

/// Input bounds `(lo, hi)` of `[X, Y, Z, Mz]` (N, N m).
pub type InputBounds = ([f64; NU], [f64; NU]);

/// The input bounds `(lo, hi)` of a vehicle file's thrusters (their reachable box of
/// `[X, Y, Z, Mz]`, [`crate::vehicle::Thrusters::input_bounds`]); `None` for a file without
/// thrusters. The constants [`BLUEROV2_INPUT_LO`] / `_HI` stay the paper's values: the shipped
/// models/bluerov2.toml's T200 curve at 16 V gives more (docs/THRUSTERS.md).
///
/// # Errors
/// The file cannot be read or its thruster tables are wrong.
pub fn input_bounds_from_file(path: &std::path::Path) -> Result<Option<InputBounds>, crate::vehicle::VehicleFileError> {
    let text = std::fs::read_to_string(path)
        .map_err(|source| crate::vehicle::VehicleFileError::Io { path: path.into(), source })?;
    Ok(crate::vehicle::Thrusters::from_toml(&text, path)?.map(|t| {
        let (lo, hi) = t.input_bounds();
        (lo.into(), hi.into())
    }))
}

/// Steady body velocities `[u, v, w, r]` reachable with inputs in `[lo, hi]`: each axis's
/// terminal speed under its extreme force (heave includes the net buoyancy). Cross-coupling
/// is ignored, which is conservative for the initial states drawn inside.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityBox {
    /// Lower bounds of `[u, v, w, r]`.
    pub lo: [f64; 4],
    /// Upper bounds of `[u, v, w, r]`.
    pub hi: [f64; 4],
}

/// See [`VelocityBox`].
pub fn reachable_velocities(p: &VehicleParams, lo: [f64; NU], hi: [f64; NU]) -> VelocityBox {
    let damping = [(p.x_u, p.x_uu), (p.y_v, p.y_vv), (p.z_w, p.z_ww), (p.n_r, p.n_rr)];
    let bias = [0.0, 0.0, p.net_buoyancy(), 0.0];
    let mut b = VelocityBox { lo: [0.0; 4], hi: [0.0; 4] };
    for i in 0..4 {
        let (lin, quad) = damping[i];
        let speed = |f: f64| f.signum() * terminal_speed(f.abs(), lin, quad);
        b.lo[i] = speed(lo[i] + bias[i]).min(0.0);
        b.hi[i] = speed(hi[i] + bias[i]).max(0.0);
    }
    b
}
