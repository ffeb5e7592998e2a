//! The controller's settings, with defaults for depth and heading tracking of the BlueROV2
//! at 0.08 s, and the Clarabel settings they imply.

use super::error::MpcError;
use crate::types::{Input, NU};
use clarabel::solver::{DefaultSettings, DefaultSettingsBuilder};

/// Everything the controller can be tuned by, with defaults for depth and heading tracking
/// of the BlueROV2 at 0.08 s.
#[derive(Debug, Clone, PartialEq)]
pub struct MpcConfig {
    /// Prediction horizon (samples).
    pub horizon: usize,
    /// Steps per partially condensed block of the QP: only every this many predicted states
    /// (and the last) stay variables, the others are eliminated into their block (1: the
    /// sparse form, every state a variable). Same solution, a smaller KKT system.
    pub condensing_block: usize,
    /// Weight on `(z - z_ref)^2` (1/m^2).
    pub depth: f64,
    /// Weight on the heading chord `|(cos psi, sin psi) - (cos ref, sin ref)|^2`.
    pub heading: f64,
    /// Weight on the horizontal position error `(x - x_ref)^2 + (y - y_ref)^2` (1/m^2). Zero
    /// (the default): depth and heading only, `x, y` left out of a position-free model's QP.
    /// Positive: the QP keeps `x, y` (the Riccati solver's 9-state stages) and tracks the
    /// references' [`Horizontal`](super::Horizontal) goals ([`MpcConfig::four_axis`]).
    pub position: f64,
    /// Weights on `u, v, w, r`.
    pub velocity: [f64; 4],
    /// Weights on the inputs `X, Y, Z, Mz`.
    pub input: [f64; NU],
    /// Weights on input changes between samples.
    pub input_rate: [f64; NU],
    /// Factor on the state weights at the end of the horizon.
    pub terminal: f64,
    /// Optional bound on `|u_k - u_{k-1}|` per channel.
    pub rate_limit: Option<[f64; NU]>,
    /// Input bounds `(min, max)`; `None` takes the model's training envelope.
    pub bounds: Option<(Input, Input)>,
    /// The QP solver's time limit per solve (s).
    pub solver_time_limit: f64,
    /// The QP solver's iteration limit per solve.
    pub solver_max_iter: u32,
    /// Clarabel's duality-gap (absolute and relative) and feasibility tolerances. A real-time
    /// iteration solves a QP that is itself an approximation, re-solved next sample.
    pub solver_tolerance: f64,
    /// The Riccati solver's tolerance on its residuals and duality gap, relative to the
    /// largest bound, linear cost and objective of the cycle's QP. 1e-4 (against Clarabel's
    /// 1e-3): the default scenario's RMS errors equal 1e-6's to five digits, one or two
    /// iterations fewer.
    pub riccati_tolerance: f64,
    /// Let Clarabel equilibrate (rescale) the QP. Its scaling is computed once, when the
    /// solver is built from the placeholder problem (the cost weights, unit rows, zero
    /// dynamics): that balances the weights' six decades and took the shipped model from 9
    /// to 6 iterations; scaling fitted to a linearisation at rest did worse.
    pub solver_equilibrate: bool,
    /// Iterative refinement of Clarabel's KKT solves (two steps to 1e-8 when on).
    pub solver_refinement: bool,
    /// The real-time budget of one cycle (s); longer cycles are counted as deadline misses.
    pub deadline: f64,
    /// Apply the shifted previous plan when the nominal rollout leaves the model's training
    /// envelope. Off by default: exits are reported in every [`CycleReport`](super::CycleReport) either way, and
    /// the previous plan came from the same model, so it is rarely the safer choice.
    pub envelope_fallback: bool,
    /// Soft bounds keeping the predicted body velocities `u, v, w, r` inside the model's
    /// training envelope (for a model that has one): slack variables with an exact (linear)
    /// penalty, so a plan always exists and the bounds hold whenever they can.
    pub envelope_constraints: bool,
    /// Linear penalty per unit of slack on a velocity bound (per sample).
    pub envelope_penalty: f64,
    /// The velocity bounds sit this fraction of each range inside the envelope.
    pub envelope_margin: f64,
    /// Gain of the disturbance estimate (0 disables it): each cycle the difference between
    /// the measured state and the model's one-step prediction of it, times this gain, is added
    /// to a constant offset the prediction carries at every step (offset-free tracking).
    pub disturbance_gain: f64,
    /// Per input channel: 0 weighs the input itself (`input * u^2`); a time constant (s)
    /// weighs its distance from the applied input averaged over that time instead, so a
    /// channel that must hold a non-zero value (heave against buoyancy, yaw against a
    /// moment) costs nothing for it at steady state and leaves no offset.
    pub input_target_tau: [f64; NU],
    /// The QP solver of every cycle: Clarabel (the general conic solver, the reference) or
    /// the Riccati interior-point method built for this problem (`mpc::riccati`).
    pub qp: QpSolver,
}

/// [`MpcConfig::four_axis`]'s weight on the horizontal position error (1/m^2).
pub const FOUR_AXIS_POSITION_WEIGHT: f64 = 20.0;

/// Which solver a controller's QP goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum QpSolver {
    /// Clarabel on the partially condensed QP (sparse KKT factorisations).
    #[default]
    Clarabel,
    /// The structure-exploiting interior-point method: a Riccati recursion per Newton step,
    /// the stages' sizes fixed at construction, nothing allocated per cycle.
    Riccati,
}

impl QpSolver {
    /// Every solver, in the order the names list them.
    pub const ALL: [QpSolver; 2] = [QpSolver::Clarabel, QpSolver::Riccati];

    /// The solver's name on command lines and in logs.
    pub fn name(self) -> &'static str {
        match self {
            QpSolver::Clarabel => "clarabel",
            QpSolver::Riccati => "riccati",
        }
    }
}

impl std::fmt::Display for QpSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for QpSolver {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        QpSolver::ALL.into_iter().find(|q| q.name() == s).ok_or_else(|| {
            let names: Vec<&str> = QpSolver::ALL.iter().map(|q| q.name()).collect();
            format!("unknown QP solver {s:?} (one of: {})", names.join(", "))
        })
    }
}

impl Default for MpcConfig {
    fn default() -> Self {
        Self {
            horizon: 20,
            condensing_block: 4,
            depth: 20.0,
            heading: 10.0,
            position: 0.0,
            velocity: [0.05, 0.05, 0.5, 0.2],
            // Surge and sway forces do nothing for depth and heading: weighted 50x more, so a
            // learned model's small spurious couplings cannot make them worth using.
            input: [5e-2, 5e-2, 1e-3, 1e-2],
            // A heavy weight on yaw-moment changes keeps the learned model's Mz from chattering.
            input_rate: [5e-2, 5e-2, 5e-3, 5e-1],
            terminal: 5.0,
            rate_limit: None,
            bounds: None,
            solver_time_limit: 0.04,
            solver_max_iter: 50,
            solver_tolerance: 1e-3,
            riccati_tolerance: 1e-4,
            solver_equilibrate: true,
            solver_refinement: false,
            deadline: 0.08,
            envelope_fallback: false,
            envelope_constraints: true,
            envelope_penalty: 1e3,
            envelope_margin: 0.05,
            disturbance_gain: 0.2,
            input_target_tau: [0.0, 0.0, 2.0, 2.0],
            qp: QpSolver::Clarabel,
        }
    }
}

impl MpcConfig {
    /// The QP as it was solved before partial condensing, for comparison: every predicted
    /// state a variable, tolerance 1e-5, iterative refinement on.
    pub fn with_sparse_qp(self) -> Self {
        Self { condensing_block: 1, solver_tolerance: 1e-5, solver_equilibrate: true, solver_refinement: true, ..self }
    }

    /// The controller on four axes: the horizontal position weighed as the depth is, surge and
    /// sway forces priced as heave is and, like heave, against their own recent average, so
    /// that holding against a current costs nothing at steady state and leaves no offset
    /// (docs/MODEL.md section 11.4).
    pub fn four_axis(self) -> Self {
        let [_, _, z, mz] = self.input;
        let [_, _, tz, tmz] = self.input_target_tau;
        let [_, _, rz, rmz] = self.input_rate;
        Self {
            position: FOUR_AXIS_POSITION_WEIGHT,
            velocity: [0.5, 0.5, self.velocity[2], self.velocity[3]],
            input: [z, z, z, mz],
            input_rate: [rz, rz, rz, rmz],
            input_target_tau: [tz, tz, tz, tmz],
            ..self
        }
    }

    /// Whether the horizontal position is in the problem.
    pub fn tracks_position(&self) -> bool {
        self.position > 0.0
    }

    /// Refuses a horizon under 2, weights, penalties, time constants or rate limits that are
    /// negative or not finite, a disturbance gain outside `[0, 1]` and a margin outside `[0, 0.5)`.
    ///
    /// # Errors
    /// [`MpcError::Config`] naming what is wrong.
    pub fn validate(&self) -> Result<(), MpcError> {
        if self.horizon < 2 {
            return Err(MpcError::Config(format!("horizon {} (at least 2)", self.horizon)));
        }
        if self.condensing_block == 0 {
            return Err(MpcError::Config("condensing block of 0 steps (at least 1)".into()));
        }
        if !(self.disturbance_gain.is_finite() && (0.0..=1.0).contains(&self.disturbance_gain)) {
            return Err(MpcError::Config(format!("disturbance gain {} (0 to 1)", self.disturbance_gain)));
        }
        if !(self.envelope_margin.is_finite() && (0.0..0.5).contains(&self.envelope_margin)) {
            return Err(MpcError::Config(format!("envelope margin {} (0 to 0.5)", self.envelope_margin)));
        }
        if !(self.riccati_tolerance.is_finite() && self.riccati_tolerance > 0.0) {
            return Err(MpcError::Config(format!("Riccati tolerance {} (positive)", self.riccati_tolerance)));
        }
        let all = [self.depth, self.heading, self.position, self.terminal, self.envelope_penalty]
            .into_iter()
            .chain(self.input_target_tau)
            .chain(self.velocity)
            .chain(self.input)
            .chain(self.input_rate)
            .chain(self.rate_limit.into_iter().flatten());
        if all.into_iter().any(|w| !(w.is_finite() && w >= 0.0)) {
            return Err(MpcError::Config("weights and rate limits must be finite and non-negative".into()));
        }
        Ok(())
    }
}

/// Clarabel's settings for `cfg`: no presolve and no zero dropping, so that the sparsity
/// pattern set up once stays valid for every cycle's data.
pub(super) fn solver_settings(cfg: &MpcConfig) -> Result<DefaultSettings<f64>, MpcError> {
    DefaultSettingsBuilder::default()
        .verbose(false)
        .presolve_enable(false)
        .input_sparse_dropzeros(false)
        .time_limit(cfg.solver_time_limit)
        .max_iter(cfg.solver_max_iter)
        .tol_gap_abs(cfg.solver_tolerance)
        .tol_gap_rel(cfg.solver_tolerance)
        .tol_feas(cfg.solver_tolerance)
        // Two refinement steps to 1e-8 instead of up to ten to 1e-13: the KKT solves are a
        // quarter of the solve time, and a tolerance of 1e-5 needs no more.
        .iterative_refinement_reltol(1e-8)
        .iterative_refinement_abstol(1e-8)
        .iterative_refinement_max_iter(2)
        .equilibrate_enable(cfg.solver_equilibrate)
        .iterative_refinement_enable(cfg.solver_refinement)
        .build()
        .map_err(|e| MpcError::Config(e.to_string()))
}
