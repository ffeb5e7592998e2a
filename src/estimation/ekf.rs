//! The extended Kalman filter: the controller's own discrete model as the process (its exact
//! Jacobians from `linearise_horizon`), an input-equivalent disturbance as four extra
//! states, and scalar measurement updates in Joseph form. Fixed-size matrices: nothing is
//! allocated after [`Ekf::new`].

use super::health::{Health, Sensor};
use super::measurement::{Measurement, NoiseSettings};
use super::navigation::larger_variance;
use crate::runtime::{HorizonLinearisation, RuntimeError};
use crate::traits::DiscreteModel;
use crate::types::{Input, NS, NU, SimState};
use crate::vehicle::{to_network, wrap_angle};
use nalgebra::{SMatrix, SVector};

/// Filter state size: the simulator state `x y z psi u v w r`, the disturbance `dX dY dZ dMz`
/// added to the applied input, the heave gain `gZ`: the fraction of the applied heave force
/// the model misses (the applied `Z` acts as `(1 + gZ) Z`), which a model of another vehicle's
/// mass and thrusters gets wrong in proportion to the force, not as an offset; the offset
/// `bN bE` of the positioning sensor's frame from the filter's (docs/MODEL.md section 15); and
/// the DVL's mounting: its yaw misalignment `a` and scale error `k`.
pub const NE: usize = NS + NU + 5;
/// Index of the heave gain `gZ` in the filter state.
pub const HEAVE_GAIN: usize = NS + NU;
/// Index of the fixes' frame offset north (east follows): a fix reads `x + bN, y + bE`.
pub const FIX_OFFSET: usize = NS + NU + 1;
/// Index of the DVL's yaw misalignment (rad, its forward axis turned to starboard of the
/// hull's); its scale error `k` follows (it reads `1 + k` times the velocity).
pub const DVL_YAW: usize = NS + NU + 3;
/// Index of the DVL's scale error.
pub const DVL_SCALE: usize = NS + NU + 4;
/// Prior spread of the heave gain, and its random walk per step (it drifts only as the
/// vehicle's trim or thrusters change).
const HEAVE_GAIN_STD: f64 = 1.0;
const HEAVE_GAIN_STEP_STD: f64 = 0.004;
/// Prior spread (m) of the fixes' frame offset until a fix fixes it: an EKF origin set from a
/// map or a fix, a topside GPS's error, are metres; a site's surveyed origin is not assumed.
pub const FIX_OFFSET_PRIOR_STD: f64 = 100.0;
/// Its random walk (m per square-root second): a USBL's fixes carry the topside GPS's slow
/// wander (a metre over minutes), which the offset follows rather than the vehicle.
pub const FIX_OFFSET_WANDER: f64 = 0.004;
/// Prior spread of the DVL's yaw misalignment (rad, 3 deg: a DVL fitted by eye to the hull's
/// axis); constant, no random walk.
pub const DVL_YAW_PRIOR_STD: f64 = 0.052;
/// Prior spread of the DVL's scale error (3 %); constant.
pub const DVL_SCALE_PRIOR_STD: f64 = 0.03;
/// A fix whose two components' normalised innovation squared is beyond this is left out as an
/// outlier (a multipath fix): 13.8 is the 99.9 % point of the chi-square with two degrees.
pub const FIX_GATE_NIS: f64 = 13.8;
/// After this many fixes in a row beyond the gate, the fixes' frame is taken to have moved (a
/// USBL back after an outage on another topside fix, an origin set again): the offset opens to
/// their innovation, and the estimate of the vehicle stays where it is.
pub const FIX_REACQUIRE_AFTER: u32 = 8;

/// The filter's state vector.
pub type FilterState = SVector<f64, NE>;
/// Its covariance.
pub type FilterCovariance = SMatrix<f64, NE, NE>;

/// What the filter knows at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Autopilot time (s) of the estimate.
    pub t: f64,
    /// `x y z psi u v w r` (m, rad, m/s, rad/s); `psi` is continuous (not wrapped).
    pub sim: SimState,
    /// One standard deviation of each part of `sim`.
    pub std: [f64; NS],
    /// The input-equivalent disturbance `X Y Z Mz` (N, N m): what the applied input misses
    /// (a current, a buoyancy error, a thrust curve that is off).
    pub disturbance: Input,
    /// Its standard deviations.
    pub disturbance_std: [f64; NU],
    /// The heave gain `gZ` (the applied heave force acts as `(1 + gZ) Z`) and its standard
    /// deviation.
    pub heave_gain: (f64, f64),
    /// The positioning sensor's frame offset from the estimate's (north, east, m) and the
    /// larger axis of its standard deviation.
    pub fix_offset: ([f64; 2], f64),
    /// The DVL's yaw misalignment (rad, to starboard) and its standard deviation.
    pub dvl_yaw: (f64, f64),
    /// The DVL's scale error (it reads `1 + k` times the velocity) and its standard deviation.
    pub dvl_scale: (f64, f64),
}

/// How one measurement was taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Update {
    /// Every component was fused.
    Fused,
    /// At least one component lay beyond the gate and was left out.
    Rejected,
}

/// Counters of a filter's life, for logs and summaries.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FilterCounts {
    /// Prediction steps.
    pub predictions: u64,
    /// Scalar components fused.
    pub fused: u64,
    /// Scalar components beyond the gate, left out.
    pub rejected: u64,
    /// Components fused after [`REACQUIRE_AFTER`] rejections in a row, their state's
    /// variance opened first.
    pub reacquired: u64,
    /// Position fixes left out as outliers (beyond [`FIX_GATE_NIS`]).
    pub fixes_rejected: u64,
    /// Times the fixes' frame was taken to have moved ([`FIX_REACQUIRE_AFTER`]).
    pub fix_frame_moves: u64,
}

/// An extended Kalman filter on a [`DiscreteModel`].
pub struct Ekf<M: DiscreteModel> {
    model: M,
    ws: M::Workspace,
    lin: HorizonLinearisation,
    noise: NoiseSettings,
    x: FilterState,
    p: FilterCovariance,
    q: FilterCovariance,
    /// Disturbance decay per step (first-order Gauss-Markov): bounded covariance where the
    /// disturbance is unobservable.
    decay: f64,
    t: f64,
    counts: FilterCounts,
    /// Consecutive rejections of each measured component (by the state it measures).
    rejected_run: [u32; NS],
    /// The transition matrix of the last prediction (for a smoother).
    last_f: FilterCovariance,
    /// What becomes of the horizontal disturbance `dX dY` (estimated only while something
    /// observes the horizontal motion: otherwise nothing can tell it from a wrong `u v`).
    horizontal_disturbance: HorizontalDisturbance,
    /// The innovations' figures per sensor.
    health: Health,
    /// Factor on each state's process variance, adapted to the innovations (1: as set).
    q_scale: [f64; NS],
    /// When a body velocity over the ground (a DVL) was last fused: while it comes, the
    /// horizontal disturbance is observed directly.
    ground_velocity_at: Option<f64>,
    /// Fixes beyond the gate in a row.
    fixes_rejected_run: u32,
    /// Whether a fix was fused since the filter was made (until then the offset is unknown).
    fix_offset_known: bool,
}

/// A DVL's velocity measured within this long (s) counts as observing the current directly.
pub const GROUND_VELOCITY_FRESH_S: f64 = 1.0;

/// What the filter does with the horizontal disturbance `dX dY`, the input-equivalent of a
/// water current and of what the model misses of the horizontal thrust.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HorizontalDisturbance {
    /// Estimated: a position or velocity observes the horizontal motion.
    Estimated,
    /// Held at its last estimate, without decay or random walk, turned against the vehicle's
    /// turns (dead reckoning: the current is taken to stay as it was over the ground while
    /// nothing measures it).
    Held,
    /// Held at zero: nothing observes the horizontal motion, and nothing did before.
    Off,
}

/// After this many consecutive rejections of one component, the estimate of what it measures
/// is taken as lost (a jump: the autopilot's heading realigned, a position source came back
/// elsewhere): its variance grows by the innovation's square and the measurement is fused.
pub const REACQUIRE_AFTER: u32 = 3;

/// Above this mean NIS (two seconds) the process variance of the motion a sensor observes
/// grows; between 1 and it, it holds (a sensor noisier than set, not a wrong model).
pub const ADAPT_HIGH: f64 = 2.0;
/// Exponent of each step's change of the process variance: at a NIS of 20 it grows tenfold in
/// about 1.6 s (20 steps of 0.08 s).
const ADAPT_GAIN: f64 = 0.05;
/// The most the process variance grows (a tenfold standard deviation).
const ADAPT_MAX: f64 = 100.0;

/// The simulator state's `psi` into the network's `(cos, sin)`: `d net / d sim` (9 x 8).
fn sim_to_net_jacobian(psi: f64) -> SMatrix<f64, 9, NS> {
    let mut j = SMatrix::<f64, 9, NS>::zeros();
    for (net, sim) in [(0, 0), (1, 1), (2, 2), (5, 4), (6, 5), (7, 6), (8, 7)] {
        j[(net, sim)] = 1.0;
    }
    let (s, c) = psi.sin_cos();
    j[(3, 3)] = -s;
    j[(4, 3)] = c;
    j
}

/// The network state's `(cos, sin)` into `psi = atan2(sin, cos)`: `d sim / d net` (8 x 9).
fn net_to_sim_jacobian(c: f64, s: f64) -> SMatrix<f64, NS, 9> {
    let mut j = SMatrix::<f64, NS, 9>::zeros();
    for (net, sim) in [(0, 0), (1, 1), (2, 2), (5, 4), (6, 5), (7, 6), (8, 7)] {
        j[(sim, net)] = 1.0;
    }
    let r2 = c * c + s * s;
    j[(3, 3)] = -s / r2;
    j[(3, 4)] = c / r2;
    j
}

impl<M: DiscreteModel> Ekf<M> {
    /// A filter on `model` with `noise`, at rest at the origin until [`Ekf::reset`].
    pub fn new(model: M, noise: NoiseSettings) -> Self {
        let ws = model.workspace();
        let dt = model.dt();
        let mut q = FilterCovariance::zeros();
        for (i, s) in noise.process_std().iter().enumerate() {
            q[(i, i)] = s * s;
        }
        let decay = (-dt / noise.disturbance_time_constant).exp();
        // The stationary variance of a Gauss-Markov state is q / (1 - decay^2): scale q so the
        // stated disturbance std is that stationary spread.
        for i in 0..NU {
            let s = noise.disturbance_std[i];
            q[(NS + i, NS + i)] = s * s * (1.0 - decay * decay);
        }
        q[(HEAVE_GAIN, HEAVE_GAIN)] = HEAVE_GAIN_STEP_STD * HEAVE_GAIN_STEP_STD;
        for i in [FIX_OFFSET, FIX_OFFSET + 1] {
            q[(i, i)] = FIX_OFFSET_WANDER * FIX_OFFSET_WANDER * dt;
        }
        let mut p = FilterCovariance::identity();
        Self::mounting_prior(&mut p);
        Self {
            model,
            ws,
            lin: HorizonLinearisation::new(1),
            noise,
            x: FilterState::zeros(),
            p,
            q,
            decay,
            t: 0.0,
            counts: FilterCounts::default(),
            rejected_run: [0; NS],
            last_f: FilterCovariance::identity(),
            horizontal_disturbance: HorizontalDisturbance::Estimated,
            ground_velocity_at: None,
            health: Health::default(),
            q_scale: [1.0; NS],
            fixes_rejected_run: 0,
            fix_offset_known: false,
        }
    }

    /// The priors of what is kept across restarts: the fixes' frame offset unknown, the DVL's
    /// mounting within a fitting by eye.
    fn mounting_prior(p: &mut FilterCovariance) {
        for (i, s) in [
            (FIX_OFFSET, FIX_OFFSET_PRIOR_STD),
            (FIX_OFFSET + 1, FIX_OFFSET_PRIOR_STD),
            (DVL_YAW, DVL_YAW_PRIOR_STD),
            (DVL_SCALE, DVL_SCALE_PRIOR_STD),
        ] {
            p[(i, i)] = s * s;
        }
    }

    /// The DVL's mounting as the owner measured it: yaw misalignment `yaw` (rad, to starboard)
    /// and scale error `scale` (it reads `1 + scale` times the velocity), each known within its
    /// standard deviation (0: taken as exact).
    pub fn set_dvl_mounting(&mut self, yaw: f64, yaw_std: f64, scale: f64, scale_std: f64) {
        for (i, v, s) in [(DVL_YAW, yaw, yaw_std), (DVL_SCALE, scale, scale_std)] {
            self.x[i] = v;
            self.p.row_mut(i).fill(0.0);
            self.p.column_mut(i).fill(0.0);
            self.p[(i, i)] = s * s;
        }
    }

    /// The estimate's frame is where it stands (a DVL carried it from an unplaced start): its
    /// horizontal position's spread shrinks to the position noise, its correlations cut, so the
    /// fixes that come next place their offset, not the vehicle.
    pub fn place_here(&mut self) {
        let s = self.noise.position_std;
        for i in [0, 1] {
            self.p.row_mut(i).fill(0.0);
            self.p.column_mut(i).fill(0.0);
            self.p[(i, i)] = s * s;
        }
    }

    /// Whether a fix was fused yet: until then the fixes' frame offset is its prior.
    pub fn fix_offset_known(&self) -> bool {
        self.fix_offset_known
    }

    /// The fixes define the estimate's frame: the offset is zero and known (the filter starts
    /// on a fix, with nothing before it to keep).
    pub fn define_frame_by_fixes(&mut self) {
        for i in [FIX_OFFSET, FIX_OFFSET + 1] {
            self.x[i] = 0.0;
            self.p.row_mut(i).fill(0.0);
            self.p.column_mut(i).fill(0.0);
        }
        self.fix_offset_known = true;
    }

    /// The innovations' figures per sensor since the last [`Ekf::reset`].
    pub fn health(&self) -> &Health {
        &self.health
    }

    /// The factor on each state's process variance the innovations led to (1: as set).
    pub fn process_scale(&self) -> [f64; NS] {
        self.q_scale
    }

    /// Adapts the process variance of the motion each sensor observes to its innovations (depth:
    /// `w`; heading and yaw rate: `r`; a position source: `u v`): it grows while their mean NIS
    /// over the last two seconds stays above [`ADAPT_HIGH`] (the model moves the vehicle other
    /// than it moves) and shrinks back while it stays below 1, at most a hundredfold (unbounded,
    /// a heading noisier than set drove `r`'s to 10^4 on a simulator log, and the smoothed turn
    /// followed the gyro's noise: 0.056 rad/s RMS against 0.023 with the bound).
    fn adapt(&mut self) {
        let nis = |s: Sensor| {
            let h = self.health.sensor(s);
            h.warm().then_some(h.nis_fast)
        };
        let horizontal = match (nis(Sensor::Position), nis(Sensor::Velocity)) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        let yaw = match (nis(Sensor::Heading), nis(Sensor::YawRate)) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        // While nothing measures the horizontal motion its sensors' figures are of the past,
        // and what they adapted answered how the model met them: dead reckoning spreads by the
        // model's own process noise.
        let horizontal = if self.horizontal_disturbance == HorizontalDisturbance::Estimated {
            horizontal
        } else {
            self.q_scale[4] = 1.0;
            self.q_scale[5] = 1.0;
            None
        };
        for (states, nis) in [(&[6][..], nis(Sensor::Depth)), (&[7][..], yaw), (&[4, 5][..], horizontal)] {
            let Some(nis) = nis else { continue };
            let factor = if nis > ADAPT_HIGH {
                (nis / ADAPT_HIGH).powf(ADAPT_GAIN)
            } else if nis < 1.0 {
                nis.max(1e-3).powf(ADAPT_GAIN)
            } else {
                1.0
            };
            for &i in states {
                self.q_scale[i] = (self.q_scale[i] * factor).clamp(1.0, ADAPT_MAX);
            }
        }
    }

    /// The transition matrix `F` of the last [`Ekf::predict`] (`d s_{k+1} / d s_k`).
    pub fn last_transition(&self) -> &FilterCovariance {
        &self.last_f
    }

    /// A velocity over the ground (a DVL's) is measured now, here or in what the autopilot's
    /// estimate gives: while it is (within [`GROUND_VELOCITY_FRESH_S`]), the horizontal
    /// disturbance is a current observed directly, without decay and turned with the vehicle.
    pub fn ground_velocity_measured(&mut self) {
        self.ground_velocity_at = Some(self.t);
    }

    /// Estimates, holds or clears the horizontal disturbance `dX dY` from now on.
    pub fn set_horizontal_disturbance(&mut self, mode: HorizontalDisturbance) {
        if mode != HorizontalDisturbance::Off && self.horizontal_disturbance == HorizontalDisturbance::Off {
            for i in [NS, NS + 1] {
                let s = self.noise.disturbance_std[i - NS];
                self.p[(i, i)] = s * s;
            }
        }
        // Dead reckoning takes the current as known: its spread while estimated is kept open by
        // its random walk, for tracking, and is not what the filter knows of it (on the
        // firmware, 20 s of dead reckoning ended 0.17 m from the point where that spread,
        // carried on, said 22 m).
        if mode == HorizontalDisturbance::Held && self.horizontal_disturbance == HorizontalDisturbance::Estimated {
            for i in [NS, NS + 1] {
                self.p.row_mut(i).fill(0.0);
                self.p.column_mut(i).fill(0.0);
            }
        }
        // Out of dead reckoning, the position's correlation with the velocity it built is cut:
        // the process noise that built it is pessimistic for a held current (measured on the
        // firmware: 20 s of it added 4 m of spread, the truth 0.14 m from the point), and
        // through it the first velocities measured again moved the estimate 0.6 m, a step
        // the controller followed. The position's own spread is kept.
        if mode == HorizontalDisturbance::Estimated && self.horizontal_disturbance == HorizontalDisturbance::Held {
            for i in [0, 1] {
                for j in 2..NE {
                    self.p[(i, j)] = 0.0;
                    self.p[(j, i)] = 0.0;
                }
            }
        }
        self.horizontal_disturbance = mode;
        if mode == HorizontalDisturbance::Off {
            self.clear_horizontal_disturbance();
        }
    }

    fn clear_horizontal_disturbance(&mut self) {
        for i in [NS, NS + 1] {
            self.x[i] = 0.0;
            self.p.row_mut(i).fill(0.0);
            self.p.column_mut(i).fill(0.0);
        }
    }

    /// The process model.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The noise settings.
    pub fn noise(&self) -> &NoiseSettings {
        &self.noise
    }

    /// Restarts at time `t` from `sim` with standard deviations `std`, the disturbance zero
    /// with its stationary spread.
    pub fn reset(&mut self, t: f64, sim: &SimState, std: &[f64; NS]) {
        // The fixes' frame and the DVL's mounting outlive a restart (a link's gap): their
        // estimates and spreads are kept, their correlations with the motion cut.
        let kept = [FIX_OFFSET, FIX_OFFSET + 1, DVL_YAW, DVL_SCALE];
        let kept_x = kept.map(|i| self.x[i]);
        let kept_p = SMatrix::<f64, 4, 4>::from_fn(|a, b| self.p[(kept[a], kept[b])]);
        self.t = t;
        self.x = FilterState::zeros();
        self.x.fixed_rows_mut::<NS>(0).copy_from(sim);
        self.p = FilterCovariance::zeros();
        for a in 0..4 {
            self.x[kept[a]] = kept_x[a];
            for b in 0..4 {
                self.p[(kept[a], kept[b])] = kept_p[(a, b)];
            }
        }
        self.fixes_rejected_run = 0;
        for i in 0..NS {
            self.p[(i, i)] = std[i] * std[i];
        }
        for i in 0..NU {
            let s = self.noise.disturbance_std[i];
            self.p[(NS + i, NS + i)] = s * s;
        }
        self.p[(HEAVE_GAIN, HEAVE_GAIN)] = HEAVE_GAIN_STD * HEAVE_GAIN_STD;
        self.counts = FilterCounts::default();
        self.rejected_run = [0; NS];
        self.health = Health::default();
        self.q_scale = [1.0; NS];
        if self.horizontal_disturbance == HorizontalDisturbance::Off {
            self.clear_horizontal_disturbance();
        }
    }

    /// Takes the DVL's velocity noise (m/s) as measured on its own readings.
    pub fn set_velocity_body_std(&mut self, std: f64) {
        self.noise.velocity_body_std = std;
    }

    /// Sets the process noise on the horizontal position (m per step): the kinematics' own
    /// error, small where a DVL measures the velocity it integrates.
    pub fn set_position_process_std(&mut self, std: f64) {
        for i in [0, 1] {
            self.noise.process_std[i] = std;
            self.q[(i, i)] = std * std;
        }
    }

    /// Time of the estimate (s).
    pub fn t(&self) -> f64 {
        self.t
    }

    /// The whole state vector.
    pub fn state(&self) -> &FilterState {
        &self.x
    }

    /// Its covariance.
    pub fn covariance(&self) -> &FilterCovariance {
        &self.p
    }

    /// The counters.
    pub fn counts(&self) -> FilterCounts {
        self.counts
    }

    /// The estimate now.
    pub fn estimate(&self) -> Estimate {
        let sim = SimState::from_fn(|i, _| self.x[i]);
        let std = std::array::from_fn(|i| self.p[(i, i)].max(0.0).sqrt());
        let disturbance = Input::from_fn(|i, _| self.x[NS + i]);
        let disturbance_std = std::array::from_fn(|i| self.p[(NS + i, NS + i)].max(0.0).sqrt());
        let sd = |i: usize| self.p[(i, i)].max(0.0).sqrt();
        let heave_gain = (self.x[HEAVE_GAIN], sd(HEAVE_GAIN));
        let (o, p) = (FIX_OFFSET, &self.p);
        let offset_std = larger_variance(p[(o, o)], p[(o, o + 1)], p[(o + 1, o + 1)]).max(0.0).sqrt();
        Estimate {
            t: self.t,
            sim,
            std,
            disturbance,
            disturbance_std,
            heave_gain,
            fix_offset: ([self.x[o], self.x[o + 1]], offset_std),
            dvl_yaw: (self.x[DVL_YAW], sd(DVL_YAW)),
            dvl_scale: (self.x[DVL_SCALE], sd(DVL_SCALE)),
        }
    }

    /// One step of the model's sample period under the applied input `u` (plus the
    /// estimated disturbance).
    ///
    /// # Errors
    /// The model fails (non-finite state or input).
    pub fn predict(&mut self, u: &Input) -> Result<(), RuntimeError> {
        let sim = SimState::from_fn(|i, _| self.x[i]);
        let d = Input::from_fn(|i, _| self.x[NS + i]);
        let mut total = u + d;
        total[2] += self.x[HEAVE_GAIN] * u[2];
        let x0 = to_network(&sim);
        self.model.linearise_horizon(&mut self.ws, &x0, std::slice::from_ref(&total), &mut self.lin)?;
        let next = self.lin.trajectory()[1];
        let (a, b) = (self.lin.a()[0], self.lin.b()[0]);
        let (c, s) = (next[3], next[4]);
        let t_in = sim_to_net_jacobian(sim[3]);
        let t_out = net_to_sim_jacobian(c, s);
        let a_sim = t_out * a * t_in;
        let b_sim = t_out * b;
        // The state: the network form back to the simulator's, psi kept continuous.
        for (sim_i, net_i) in [(0, 0), (1, 1), (2, 2), (4, 5), (5, 6), (6, 7), (7, 8)] {
            self.x[sim_i] = next[net_i];
        }
        self.x[3] = sim[3] + wrap_angle(s.atan2(c) - sim[3]);
        // The horizontal disturbance is a current, kept over the ground: held (dead reckoning),
        // and estimated while a DVL measures (its velocities fused, or the autopilot's estimate
        // fused, which carries them), it does not decay and turns against the vehicle's
        // turns. With the decay it settled short of the current by what the velocity's
        // corrections made up every step, a bias dead reckoning then flew on (a simulated 20 s
        // gap ended 0.228 m off the point, 0.088 m without). On positions alone (a GPS, a USBL)
        // the decay stays: it steadies a current read from positions twice differentiated (on
        // the firmware, without it the GPS's loss was dead reckoned 1.3 m off the truth rather
        // than 0.3, and the USBL's station went from 0.57 to 0.68 of GUIDED's).
        let held = self.horizontal_disturbance == HorizontalDisturbance::Held;
        let on_ground_velocity = self.horizontal_disturbance == HorizontalDisturbance::Estimated
            && self.ground_velocity_at.is_some_and(|t| self.t - t <= GROUND_VELOCITY_FRESH_S);
        let current = held || on_ground_velocity;
        let every = self.decay;
        let decay = |i: usize| if i < 2 && current { 1.0 } else { every };
        let mut f = FilterCovariance::zeros();
        for i in 0..NU {
            self.x[NS + i] *= decay(i);
            f[(NS + i, NS + i)] = decay(i);
        }
        if current {
            // A current keeps its direction over the ground: its body-frame force turns against
            // the vehicle's turn (its coupling to the heading's own error left out).
            let (s, c) = (self.x[3] - sim[3]).sin_cos();
            let (dx, dy) = (self.x[NS], self.x[NS + 1]);
            self.x[NS] = c * dx + s * dy;
            self.x[NS + 1] = -s * dx + c * dy;
            f[(NS, NS)] = c;
            f[(NS, NS + 1)] = s;
            f[(NS + 1, NS)] = -s;
            f[(NS + 1, NS + 1)] = c;
        }
        f.fixed_view_mut::<NS, NS>(0, 0).copy_from(&a_sim);
        f.fixed_view_mut::<NS, NU>(0, NS).copy_from(&b_sim);
        // The heave gain acts through the input's heave column, scaled by the applied force.
        f.fixed_view_mut::<NS, 1>(0, HEAVE_GAIN).copy_from(&(b_sim.column(2) * u[2]));
        for i in [HEAVE_GAIN, FIX_OFFSET, FIX_OFFSET + 1, DVL_YAW, DVL_SCALE] {
            f[(i, i)] = 1.0;
        }
        self.adapt();
        let mut q = self.q;
        for i in 0..NS {
            q[(i, i)] *= self.q_scale[i];
        }
        if held {
            // Held is held: no random walk either (it would spread as fast as the current it
            // stands for is estimated, 0.26 N per step, metres of position in seconds).
            q[(NS, NS)] = 0.0;
            q[(NS + 1, NS + 1)] = 0.0;
        }
        self.p = f * self.p * f.transpose() + q;
        self.p = (self.p + self.p.transpose()) * 0.5;
        if self.horizontal_disturbance == HorizontalDisturbance::Off {
            self.clear_horizontal_disturbance();
        }
        self.last_f = f;
        self.t += self.model.dt();
        self.counts.predictions += 1;
        Ok(())
    }

    /// Fuses one scalar: measurement `z` of `h(x)` with row `h` of `dh/dx`, innovation
    /// `y = z - h(x)` already formed (wrapped where it is an angle), variance `r`, from
    /// `sensor`. Left out beyond the gate where `gated`.
    fn scalar(&mut self, y: f64, h: &SMatrix<f64, 1, NE>, r: f64, sensor: Sensor, gated: bool) -> bool {
        // The state a row measures most directly, for the count of consecutive rejections.
        let main = (0..NS).max_by(|&a, &b| h[(0, a)].abs().total_cmp(&h[(0, b)].abs())).unwrap_or(0);
        let mut s = (h * self.p * h.transpose())[(0, 0)] + r;
        if !(s > 0.0 && y.is_finite()) {
            self.counts.rejected += 1;
            self.health.add(sensor, f64::INFINITY, true);
            return false;
        }
        let beyond = y * y > self.noise.gate * self.noise.gate * s;
        self.health.add(sensor, y * y / s, beyond);
        if beyond && gated {
            self.rejected_run[main] += 1;
            if self.rejected_run[main] < REACQUIRE_AFTER {
                self.counts.rejected += 1;
                return false;
            }
            // Lost: open the variance of what it measures to the innovation, then fuse.
            let gain = h[(0, main)];
            self.p[(main, main)] += y * y / (gain * gain);
            s = (h * self.p * h.transpose())[(0, 0)] + r;
            self.counts.reacquired += 1;
        }
        self.rejected_run[main] = 0;
        let ph = self.p * h.transpose();
        let mut k = ph / s;
        // While the horizontal motion is dead reckoned (its disturbance held), what does not
        // measure it leaves it alone: the model's couplings build correlations between the yaw
        // rate and a sway and position whose spread has grown to metres, and through them a
        // yaw-rate reading moved the position 0.6 m in one sample (simulated, 15 s into a DVL
        // gap; the controller followed it 4 m). The update stays consistent (Joseph form).
        const HORIZONTAL: [usize; 4] = [0, 1, 4, 5];
        if self.horizontal_disturbance == HorizontalDisturbance::Held && HORIZONTAL.iter().all(|&i| h[(0, i)] == 0.0) {
            for i in HORIZONTAL {
                k[i] = 0.0;
            }
        }
        self.x += k * y;
        // Joseph form keeps P symmetric and positive under rounding.
        let ikh = FilterCovariance::identity() - k * h;
        self.p = ikh * self.p * ikh.transpose() + k * k.transpose() * r;
        self.counts.fused += 1;
        true
    }

    /// A fix `x y` (variance `r` each) of the position in the sensor's frame, `x + bN, y + bE`:
    /// gated on both components together (a multipath fix is off in a direction, and one
    /// component alone can pass), and after [`FIX_REACQUIRE_AFTER`] in a row beyond the gate the
    /// frame's offset opens to the innovation: the frame moved, the vehicle did not.
    fn fix(&mut self, x: f64, y: f64, r: f64) -> bool {
        let o = FIX_OFFSET;
        let hx = Self::row(&[(0, 1.0), (o, 1.0)]);
        let hy = Self::row(&[(1, 1.0), (o + 1, 1.0)]);
        let (ix, iy) = (x - self.x[0] - self.x[o], y - self.x[1] - self.x[o + 1]);
        let sxx = (hx * self.p * hx.transpose())[(0, 0)] + r;
        let syy = (hy * self.p * hy.transpose())[(0, 0)] + r;
        let sxy = (hx * self.p * hy.transpose())[(0, 0)];
        let det = sxx * syy - sxy * sxy;
        let nis = (syy * ix * ix - 2.0 * sxy * ix * iy + sxx * iy * iy) / det;
        if !(det > 0.0 && nis.is_finite()) {
            self.counts.rejected += 2;
            self.health.add(Sensor::Position, f64::INFINITY, true);
            return false;
        }
        if nis > FIX_GATE_NIS {
            self.fixes_rejected_run += 1;
            if self.fixes_rejected_run < FIX_REACQUIRE_AFTER {
                self.counts.rejected += 2;
                self.counts.fixes_rejected += 1;
                self.health.add(Sensor::Position, 0.5 * nis, true);
                return false;
            }
            self.p[(o, o)] += ix * ix;
            self.p[(o + 1, o + 1)] += iy * iy;
            self.counts.fix_frame_moves += 1;
        }
        self.fixes_rejected_run = 0;
        let a = self.scalar(x - self.x[0] - self.x[o], &hx, r, Sensor::Position, false);
        let b = self.scalar(y - self.x[1] - self.x[o + 1], &hy, r, Sensor::Position, false);
        self.fix_offset_known = true;
        a && b
    }

    fn row(entries: &[(usize, f64)]) -> SMatrix<f64, 1, NE> {
        let mut h = SMatrix::<f64, 1, NE>::zeros();
        for &(i, v) in entries {
            h[(0, i)] = v;
        }
        h
    }

    /// Fuses `m` into the estimate now (its stamp is not used: the caller fuses measurements
    /// at the sample they belong to). Comparing depth and heading with the state at their own
    /// stamps instead was tried on the firmware and made the heave estimate worse (w RMS error
    /// 0.19-0.23 m/s against 0.12 with the shipped model).
    pub fn update(&mut self, m: &Measurement) -> Update {
        let n = &self.noise;
        let (sd, sh, sr, sp, sv, sb) =
            (n.depth_std, n.heading_std, n.yaw_rate_std, n.position_std, n.velocity_ned_std, n.velocity_body_std);
        let all = match *m {
            Measurement::Depth { z, .. } => {
                // A sensor that lags by `delay` reads z(t - delay) ~ z(t) - delay w(t).
                let delay = n.depth_delay;
                let h = Self::row(&[(2, 1.0), (6, -delay)]);
                self.scalar(z - (self.x[2] - delay * self.x[6]), &h, sd * sd, Sensor::Depth, true)
            }
            Measurement::Heading { psi, .. } => {
                let h = Self::row(&[(3, 1.0)]);
                let y = wrap_angle(psi - self.x[3]);
                self.scalar(y, &h, sh * sh, Sensor::Heading, true)
            }
            // The gyro measures the turn directly: gating it out would leave the turn to the
            // model alone, which is how an estimate loses a vehicle whose model is wrong.
            Measurement::YawRate { r, .. } => {
                self.scalar(r - self.x[7], &Self::row(&[(7, 1.0)]), sr * sr, Sensor::YawRate, false)
            }
            Measurement::Position { x, y, z, .. } => {
                let p = Sensor::Position;
                let a = self.scalar(x - self.x[0], &Self::row(&[(0, 1.0)]), sp * sp, p, true);
                let b = self.scalar(y - self.x[1], &Self::row(&[(1, 1.0)]), sp * sp, p, true);
                // A NaN depth: the position source's depth is left to the depth sensor.
                let c = !z.is_finite() || self.scalar(z - self.x[2], &Self::row(&[(2, 1.0)]), sp * sp, p, true);
                a && b && c
            }
            // The sensor's own word on its accuracy where it gives one.
            Measurement::Fix { x, y, std, .. } => {
                let r = if std.is_finite() && std > 0.0 { std * std } else { sp * sp };
                self.fix(x, y, r)
            }
            Measurement::VelocityNed { vn, ve, vd, .. } => {
                // vn = c u - s v, ve = s u + c v, vd = w (roll and pitch taken as zero).
                let mut ok = true;
                for axis in 0..2 {
                    let (s, c) = self.x[3].sin_cos();
                    let (u, v) = (self.x[4], self.x[5]);
                    let (pred, z, h) = if axis == 0 {
                        (c * u - s * v, vn, Self::row(&[(4, c), (5, -s), (3, -s * u - c * v)]))
                    } else {
                        (s * u + c * v, ve, Self::row(&[(4, s), (5, c), (3, c * u - s * v)]))
                    };
                    ok &= self.scalar(z - pred, &h, sv * sv, Sensor::Velocity, true);
                }
                ok & self.scalar(vd - self.x[6], &Self::row(&[(6, 1.0)]), sv * sv, Sensor::Velocity, true)
            }
            Measurement::VerticalVelocity { vd, .. } => {
                let s = n.vertical_velocity_std;
                self.scalar(vd - self.x[6], &Self::row(&[(6, 1.0)]), s * s, Sensor::Velocity, true)
            }
            // The DVL reads the body velocity turned into its own axes and scaled:
            // `(1 + k) (c u + s v, -s u + c v, w)`, `a` its yaw misalignment.
            Measurement::VelocityBody { u, v, w, .. } => {
                let v_ = Sensor::Velocity;
                let row_u = |x: &FilterState| {
                    let (s, c) = x[DVL_YAW].sin_cos();
                    let (g, along, across) = (1.0 + x[DVL_SCALE], c * x[4] + s * x[5], -s * x[4] + c * x[5]);
                    let h = Self::row(&[(4, g * c), (5, g * s), (DVL_YAW, g * across), (DVL_SCALE, along)]);
                    (g * along, h)
                };
                let row_v = |x: &FilterState| {
                    let (s, c) = x[DVL_YAW].sin_cos();
                    let (g, along, across) = (1.0 + x[DVL_SCALE], c * x[4] + s * x[5], -s * x[4] + c * x[5]);
                    let h = Self::row(&[(4, -g * s), (5, g * c), (DVL_YAW, -g * along), (DVL_SCALE, across)]);
                    (g * across, h)
                };
                let (pred, h) = row_u(&self.x);
                let a = self.scalar(u - pred, &h, sb * sb, v_, true);
                let (pred, h) = row_v(&self.x);
                let b = self.scalar(v - pred, &h, sb * sb, v_, true);
                let g = 1.0 + self.x[DVL_SCALE];
                let h = Self::row(&[(6, g), (DVL_SCALE, self.x[6])]);
                let c = self.scalar(w - g * self.x[6], &h, sb * sb, v_, true);
                if a && b {
                    self.ground_velocity_measured();
                }
                a && b && c
            }
        };
        self.p = (self.p + self.p.transpose()) * 0.5;
        if all { Update::Fused } else { Update::Rejected }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vehicle::{Rk4Vehicle, VehicleParams};

    #[test]
    fn the_sim_and_network_jacobians_match_finite_differences() {
        let psi = 2.7;
        let j = sim_to_net_jacobian(psi);
        let h = 1e-6;
        assert!((j[(3, 3)] - ((psi + h).cos() - (psi - h).cos()) / (2.0 * h)).abs() < 1e-8);
        assert!((j[(4, 3)] - ((psi + h).sin() - (psi - h).sin()) / (2.0 * h)).abs() < 1e-8);
        let (c, s) = (0.8 * psi.cos(), 0.8 * psi.sin()); // off the unit circle on purpose
        let k = net_to_sim_jacobian(c, s);
        let fd_c = ((s).atan2(c + h) - (s).atan2(c - h)) / (2.0 * h);
        let fd_s = ((s + h).atan2(c) - (s - h).atan2(c)) / (2.0 * h);
        assert!((k[(3, 3)] - fd_c).abs() < 1e-7 && (k[(3, 4)] - fd_s).abs() < 1e-7);
    }

    /// The filter's transition Jacobian (through the network form) against finite
    /// differences of its own state update.
    #[test]
    fn the_transition_jacobian_matches_finite_differences_of_the_step() {
        let model = Rk4Vehicle::with_dt(0.08);
        let noise = NoiseSettings::default();
        let x0 = SimState::from([1.0, -2.0, 3.0, 3.1, 0.4, -0.2, 0.1, 0.3]);
        let u = Input::new(10.0, -5.0, 8.0, 1.5);
        let step = |x: &FilterState| {
            let mut e = Ekf::new(model, noise.clone());
            e.reset(0.0, &SimState::from_fn(|i, _| x[i]), &[1.0; NS]);
            for i in NS..NE {
                e.x[i] = x[i];
            }
            e.predict(&u).unwrap();
            (e.x, e.p)
        };
        let mut base = FilterState::zeros();
        base.fixed_rows_mut::<NS>(0).copy_from(&x0);
        base[NS + 2] = 2.0;
        base[HEAVE_GAIN] = 0.3;
        // P after one step from P0 = I (the disturbance's and heave gain's prior too) minus Q
        // is F F'.
        let mut e = Ekf::new(model, noise.clone());
        e.reset(0.0, &x0, &[1.0; NS]);
        for i in NS..NE {
            e.p[(i, i)] = 1.0;
        }
        e.x[HEAVE_GAIN] = 0.3;
        e.x[NS + 2] = 2.0;
        e.predict(&u).unwrap();
        let ff = e.p - e.q;
        let h = 1e-6;
        let mut f = FilterCovariance::zeros();
        for j in 0..NE {
            let (mut xp, mut xm) = (base, base);
            xp[j] += h;
            xm[j] -= h;
            let col = (step(&xp).0 - step(&xm).0) / (2.0 * h);
            f.set_column(j, &col);
        }
        let want = f * f.transpose();
        let err = (ff - want).abs().max();
        assert!(err < 1e-5 * want.abs().max(), "F F' differs by {err}");
        let _ = VehicleParams::default();
    }

    /// A filter on the true model, fed depth, heading and yaw rate only (a stock BlueROV2),
    /// recovers the body velocities of a simulated run within a few cm/s.
    #[test]
    fn depth_and_heading_alone_recover_the_velocities_of_a_known_motion() {
        let model = Rk4Vehicle::with_dt(0.08);
        let mut truth = SimState::from([0.0, 0.0, 1.0, 0.3, 0.0, 0.0, 0.0, 0.0]);
        let mut e = Ekf::new(model, NoiseSettings::default());
        e.reset(
            0.0,
            &SimState::from([0.0, 0.0, 1.0, 0.3, 0.0, 0.0, 0.0, 0.0]),
            &[10.0, 10.0, 0.1, 0.05, 0.3, 0.3, 0.3, 0.1],
        );
        let mut ws = ();
        let mut err = [0.0f64; 4];
        let n = 500;
        let mut seed = 1u64;
        let mut noise = || {
            // Small deterministic pseudo-noise, uniform in +-1.
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        for k in 0..n {
            let t = k as f64 * 0.08;
            let u = Input::new(
                20.0 * (0.3 * t).sin(),
                10.0 * (0.2 * t).cos(),
                15.0 * (0.5 * t).sin(),
                2.0 * (0.4 * t).sin(),
            );
            let mut next = crate::types::State::zeros();
            model.step(&mut ws, &to_network(&truth), &u, &mut next).unwrap();
            truth = crate::vehicle::to_simulator(&next);
            e.predict(&u).unwrap();
            e.update(&Measurement::Depth { t, z: truth[2] + 0.05 * noise() });
            e.update(&Measurement::Heading { t, psi: truth[3] + 0.01 * noise() });
            e.update(&Measurement::YawRate { t, r: truth[7] + 0.01 * noise() });
            if k >= 100 {
                for (j, i) in [4, 5, 6, 7].into_iter().enumerate() {
                    err[j] += (e.x[i] - truth[i]).powi(2);
                }
            }
        }
        let rms = err.map(|s| (s / (n - 100) as f64).sqrt());
        assert!(rms[0] < 0.02 && rms[1] < 0.02 && rms[2] < 0.02 && rms[3] < 0.02, "u v w r RMS {rms:?}");
        assert_eq!(e.counts().rejected, 0);
    }

    /// On a model whose heave is wrong (drag and added mass halved, 10 % more buoyant) and a
    /// depth sensor as noisy as ArduSub's simulator's, the autopilot's vertical velocity holds
    /// the heave estimate near the truth; without it the wrong model carries it.
    #[test]
    fn the_autopilots_vertical_velocity_holds_the_heave_on_a_wrong_model() {
        let truth_model = Rk4Vehicle::with_dt(0.08);
        let d = VehicleParams::default();
        let params = VehicleParams { z_ww: 0.5 * d.z_ww, z_wd: 0.5 * d.z_wd, volume: 1.1 * d.volume, ..d };
        let wrong = Rk4Vehicle { params, ..Rk4Vehicle::with_dt(0.08) };
        let heave_error = |with_velocity: bool| {
            let mut truth = SimState::from([0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            let mut e =
                Ekf::new(wrong, NoiseSettings { depth_std: 0.12, depth_delay: 0.0, ..NoiseSettings::default() });
            e.reset(0.0, &truth, &[10.0, 10.0, 0.1, 0.05, 0.3, 0.3, 0.3, 0.1]);
            let mut seed = 7u64;
            let mut noise = || {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
            };
            let (mut err, mut n) = (0.0, 0);
            for k in 0..600 {
                let t = k as f64 * 0.08;
                let u = Input::new(0.0, 0.0, 40.0 * (0.7 * t).sin(), 0.0);
                let mut next = crate::types::State::zeros();
                truth_model.step(&mut (), &to_network(&truth), &u, &mut next).unwrap();
                truth = crate::vehicle::to_simulator(&next);
                e.predict(&u).unwrap();
                // Uniform noise of +-0.2 m has 0.12 m standard deviation.
                e.update(&Measurement::Depth { t, z: truth[2] + 0.2 * noise() });
                e.update(&Measurement::Heading { t, psi: truth[3] });
                e.update(&Measurement::YawRate { t, r: truth[7] });
                if with_velocity {
                    e.update(&Measurement::VerticalVelocity { t, vd: truth[6] + 0.03 * noise() });
                }
                if k >= 100 {
                    err += (e.x[6] - truth[6]).powi(2);
                    n += 1;
                }
            }
            (err / f64::from(n)).sqrt()
        };
        let (with, without) = (heave_error(true), heave_error(false));
        assert!(with < 0.03 && without > 2.0 * with, "w RMS error {with} with, {without} without");
    }
}
