//! Real-time-iteration LTV-MPC on Clarabel, generic over the [`DiscreteModel`] interface,
//! so the learned PINC and the analytic vehicle (the "oracle") run the same controller.
//!
//! Each sample: shift the previous input plan, roll the model out from the measured state
//! and linearise along it, overwrite the QP's data in the persistent solver, solve once,
//! apply the first input. Whatever goes wrong (a model error, a solver failure or time-out,
//! a missed deadline) the loop goes on with the shifted previous plan, clipped to the bounds.

mod qp;

pub use qp::Weights;

use crate::runtime::EnvelopeStatus;
use crate::traits::DiscreteModel;
use crate::types::{Input, InputMatrix, NU, NX, State, StateMatrix};
use clarabel::solver::{
    DefaultSettings, DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use qp::{ALL_STATES, Qp, WITHOUT_POSITION};
use std::time::Instant;

/// Everything the controller can be tuned by, with defaults for depth and heading tracking
/// of the BlueROV2 at 0.08 s.
#[derive(Debug, Clone, PartialEq)]
pub struct MpcConfig {
    /// Prediction horizon (samples).
    pub horizon: usize,
    /// Weight on `(z - z_ref)^2` (1/m^2).
    pub depth: f64,
    /// Weight on the heading chord `|(cos psi, sin psi) - (cos ref, sin ref)|^2`.
    pub heading: f64,
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
    /// Clarabel's time limit per solve (s).
    pub solver_time_limit: f64,
    /// Clarabel's iteration limit per solve.
    pub solver_max_iter: u32,
    /// Clarabel's duality-gap (absolute and relative) and feasibility tolerances.
    pub solver_tolerance: f64,
    /// The real-time budget of one cycle (s); longer cycles are counted as deadline misses.
    pub deadline: f64,
    /// Apply the shifted previous plan when the nominal rollout leaves the model's training
    /// envelope. Off by default: exits are reported in every [`CycleReport`] either way, and
    /// the previous plan came from the same model, so it is rarely the safer choice.
    pub envelope_fallback: bool,
}

impl Default for MpcConfig {
    fn default() -> Self {
        Self {
            horizon: 20,
            depth: 20.0,
            heading: 10.0,
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
            solver_tolerance: 1e-5,
            deadline: 0.08,
            envelope_fallback: false,
        }
    }
}

/// What the controller could not do.
#[derive(Debug, thiserror::Error)]
pub enum MpcError {
    /// Neither the configuration nor the model gives input bounds.
    #[error("no input bounds: the model has no training envelope and the configuration sets none")]
    NoBounds,
    /// A configuration value is unusable.
    #[error("invalid MPC configuration: {0}")]
    Config(String),
    /// Clarabel refused the problem at setup.
    #[error("QP setup failed: {0}")]
    Setup(String),
}

/// Why a sample fell back to the shifted previous plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fallback {
    /// The model's rollout or linearisation failed (non-finite state or prediction).
    Model,
    /// Clarabel did not return a solution (status attached).
    Solver(SolverStatus),
    /// The nominal rollout left the training envelope (with [`MpcConfig::envelope_fallback`]).
    Envelope,
}

impl std::fmt::Display for Fallback {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Fallback::Model => f.write_str("model rollout or linearisation failed"),
            Fallback::Solver(status) => write!(f, "QP not solved ({status:?})"),
            Fallback::Envelope => f.write_str("nominal rollout outside the training envelope"),
        }
    }
}

/// The reference of one sample: depth (m, down) and heading (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reference {
    /// Depth `z_ref`.
    pub depth: f64,
    /// Heading `psi_ref`.
    pub heading: f64,
}

/// What one control cycle did.
#[derive(Debug, Clone, PartialEq)]
pub struct CycleReport {
    /// The input to apply.
    pub input: Input,
    /// Channels of `input` at a bound.
    pub saturated: [bool; NU],
    /// Set when the shifted previous plan was applied instead of a fresh solution.
    pub fallback: Option<Fallback>,
    /// Training-envelope exits along the nominal rollout (always inside for a model
    /// without an envelope).
    pub envelope: EnvelopeStatus,
    /// Clarabel's status (`Unsolved` when the model failed first).
    pub status: SolverStatus,
    /// Interior-point iterations.
    pub iterations: u32,
    /// Objective of the QP (deviation form, without constant terms).
    pub objective: f64,
    /// Rollout and linearisation (µs).
    pub linearise_us: f64,
    /// Writing the new data into the solver (µs).
    pub update_us: f64,
    /// Clarabel's solve (µs).
    pub solve_us: f64,
    /// The whole cycle (µs).
    pub cycle_us: f64,
    /// The cycle took longer than the deadline.
    pub deadline_missed: bool,
}

/// The controller: its model, plan, QP and persistent solver. All buffers are allocated at
/// construction.
pub struct Mpc<M: DiscreteModel> {
    model: M,
    ws: M::Workspace,
    cfg: MpcConfig,
    lo: Input,
    hi: Input,
    state_weights: [f64; NX],
    qp: Qp,
    solver: DefaultSolver<f64>,
    /// The input plan `u_0 .. u_{N-1}` of the last cycle.
    plan: Vec<Input>,
    /// The nominal plan of this cycle (shifted previous plan).
    nominal: Vec<Input>,
    traj: Vec<State>,
    predicted: Vec<State>,
    a: Vec<StateMatrix>,
    b: Vec<InputMatrix>,
    last_applied: Input,
}

fn settings(cfg: &MpcConfig) -> Result<DefaultSettings<f64>, MpcError> {
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
        .build()
        .map_err(|e| MpcError::Config(e.to_string()))
}

impl<M: DiscreteModel> Mpc<M> {
    /// A controller for `model`, starting from rest with a zero-force plan clipped to the bounds.
    ///
    /// # Errors
    /// No input bounds, a zero horizon, negative weights, or a QP Clarabel refuses.
    pub fn new(model: M, cfg: MpcConfig) -> Result<Self, MpcError> {
        let (lo, hi) = cfg.bounds.or_else(|| model.input_bounds()).ok_or(MpcError::NoBounds)?;
        if cfg.horizon < 2 {
            return Err(MpcError::Config(format!("horizon {} (at least 2)", cfg.horizon)));
        }
        let all = [cfg.depth, cfg.heading, cfg.terminal]
            .into_iter()
            .chain(cfg.velocity)
            .chain(cfg.input)
            .chain(cfg.input_rate)
            .chain(cfg.rate_limit.into_iter().flatten());
        if all.into_iter().any(|w| !(w.is_finite() && w >= 0.0)) {
            return Err(MpcError::Config("weights and rate limits must be finite and non-negative".into()));
        }
        if (0..NU).any(|j| !(lo[j].is_finite() && hi[j].is_finite() && lo[j] <= hi[j])) {
            return Err(MpcError::Config(format!("input bounds {lo:?} .. {hi:?}")));
        }
        let mut state_weights = [0.0; NX];
        state_weights[2] = cfg.depth;
        state_weights[3] = cfg.heading;
        state_weights[4] = cfg.heading;
        state_weights[5..].copy_from_slice(&cfg.velocity);
        let w = Weights { state: state_weights, terminal: cfg.terminal, input: cfg.input, input_rate: cfg.input_rate };
        let n = cfg.horizon;
        let states: &[usize] = if model.position_free() { &WITHOUT_POSITION } else { &ALL_STATES };
        let qp = Qp::new(n, &w, cfg.rate_limit.is_some(), states);
        let n_ineq = qp.b.len() - qp.n_eq;
        let cones = [SupportedConeT::ZeroConeT(qp.n_eq), SupportedConeT::NonnegativeConeT(n_ineq)];
        // A placeholder problem with the final pattern; every cycle overwrites its data.
        let mut b = qp.b.clone();
        b[qp.n_eq..].fill(1.0);
        let solver = DefaultSolver::new(&qp.p, &qp.q, &qp.a, &b, &cones, settings(&cfg)?)
            .map_err(|e| MpcError::Setup(e.to_string()))?;
        let rest = Input::from_fn(|j, _| 0.0f64.clamp(lo[j], hi[j]));
        Ok(Self {
            ws: model.workspace(),
            model,
            lo,
            hi,
            state_weights,
            qp,
            solver,
            plan: vec![rest; n],
            nominal: vec![rest; n],
            traj: vec![State::zeros(); n + 1],
            predicted: vec![State::zeros(); n + 1],
            a: vec![StateMatrix::zeros(); n],
            b: vec![InputMatrix::zeros(); n],
            last_applied: rest,
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &MpcConfig {
        &self.cfg
    }

    /// The input bounds in force `(min, max)`.
    pub fn bounds(&self) -> (Input, Input) {
        (self.lo, self.hi)
    }

    /// The model inside.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The predicted states `x_0 .. x_N` of the last successful cycle (the linearised
    /// prediction `xbar_k + dx_k`).
    pub fn prediction(&self) -> &[State] {
        &self.predicted
    }

    /// The input plan of the last cycle.
    pub fn plan(&self) -> &[Input] {
        &self.plan
    }

    fn clip(&self, u: &Input) -> Input {
        Input::from_fn(|j, _| u[j].clamp(self.lo[j], self.hi[j]))
    }

    /// One control cycle from the measured state `x` with references `refs[k]` for the
    /// predicted states `k = 1..=N` (`refs.len() == horizon`; the last is reused if shorter).
    ///
    /// # Panics
    /// If `refs` is empty.
    pub fn step(&mut self, x: &State, refs: &[Reference]) -> CycleReport {
        assert!(!refs.is_empty(), "at least one reference");
        let t0 = Instant::now();
        let n = self.cfg.horizon;
        // Shift the previous plan: u_k <- u_{k+1}, the last repeated.
        for k in 0..n {
            self.nominal[k] = self.clip(&self.plan[(k + 1).min(n - 1)]);
        }
        let mut report = CycleReport {
            input: self.nominal[0],
            saturated: [false; NU],
            fallback: None,
            envelope: EnvelopeStatus::default(),
            status: SolverStatus::Unsolved,
            iterations: 0,
            objective: f64::NAN,
            linearise_us: 0.0,
            update_us: 0.0,
            solve_us: 0.0,
            cycle_us: 0.0,
            deadline_missed: false,
        };
        let lin =
            self.model.linearise_horizon(&mut self.ws, x, &self.nominal, &mut self.traj, &mut self.a, &mut self.b);
        let t1 = Instant::now();
        report.linearise_us = (t1 - t0).as_secs_f64() * 1e6;
        report.envelope = self.model.envelope_status(&self.ws);
        if lin.is_err() {
            report.fallback = Some(Fallback::Model);
        } else if self.cfg.envelope_fallback && !report.envelope.inside() {
            report.fallback = Some(Fallback::Envelope);
        } else {
            self.fill_data(refs);
            let ok = self.solver.update_A(&self.qp.a_values).is_ok()
                && self.solver.update_q(&self.qp.q).is_ok()
                && self.solver.update_b(&self.qp.b).is_ok();
            let t2 = Instant::now();
            report.update_us = (t2 - t1).as_secs_f64() * 1e6;
            if !ok {
                report.fallback = Some(Fallback::Solver(SolverStatus::Unsolved));
            } else {
                self.solver.solve();
                report.solve_us = t2.elapsed().as_secs_f64() * 1e6;
                let sol = &self.solver.solution;
                report.status = sol.status;
                report.iterations = sol.iterations;
                report.objective = sol.obj_val;
                let finite = sol.x.iter().all(|v| v.is_finite());
                if matches!(sol.status, SolverStatus::Solved | SolverStatus::AlmostSolved) && finite {
                    for k in 0..n {
                        let du = Input::from_fn(|j, _| sol.x[self.qp.u_index(k, j)]);
                        self.plan[k] = self.clip(&(self.nominal[k] + du));
                    }
                    // The QP's states from its solution, any left out (x, y) by propagating
                    // the linearised dynamics: both are the same linear prediction.
                    self.predicted[0] = self.traj[0];
                    let mut dx = State::zeros();
                    for k in 0..n {
                        let du = Input::from_fn(|j, _| sol.x[self.qp.u_index(k, j)]);
                        let mut next = self.a[k] * dx + self.b[k] * du;
                        for (s, &i) in self.qp.states.iter().enumerate() {
                            next[i] = sol.x[self.qp.x_index(k + 1, s)];
                        }
                        dx = next;
                        self.predicted[k + 1] = self.traj[k + 1] + dx;
                    }
                    report.input = self.plan[0];
                } else {
                    report.fallback = Some(Fallback::Solver(sol.status));
                }
            }
        }
        if report.fallback.is_some() {
            self.plan.copy_from_slice(&self.nominal);
        }
        for j in 0..NU {
            let span = (self.hi[j] - self.lo[j]).max(1e-12);
            report.saturated[j] =
                report.input[j] <= self.lo[j] + 1e-6 * span || report.input[j] >= self.hi[j] - 1e-6 * span;
        }
        self.last_applied = report.input;
        report.cycle_us = t0.elapsed().as_secs_f64() * 1e6;
        report.deadline_missed = report.cycle_us > self.cfg.deadline * 1e6;
        report
    }

    /// The QP's linear cost, bounds and dynamics for this cycle's nominal trajectory.
    fn fill_data(&mut self, refs: &[Reference]) {
        let n = self.cfg.horizon;
        let qp = &mut self.qp;
        qp.set_dynamics(&self.a, &self.b);
        for k in 1..=n {
            let r = refs[(k - 1).min(refs.len() - 1)];
            let mut target = [0.0; NX];
            (target[2], target[3], target[4]) = (r.depth, r.heading.cos(), r.heading.sin());
            let f = if k == n { self.cfg.terminal } else { 1.0 };
            for (s, &i) in qp.states.iter().enumerate() {
                let at = qp.x_index(k, s);
                qp.q[at] = 2.0 * f * self.state_weights[i] * (self.traj[k][i] - target[i]);
            }
        }
        for k in 0..n {
            let prev = if k == 0 { self.last_applied } else { self.nominal[k - 1] };
            for j in 0..NU {
                let ubar = self.nominal[k][j];
                let rate_w = 2.0 * self.cfg.input_rate[j];
                let d_here = ubar - prev[j];
                let mut q = 2.0 * self.cfg.input[j] * ubar + rate_w * d_here;
                if k + 1 < n {
                    q -= rate_w * (self.nominal[k + 1][j] - ubar);
                }
                let at = qp.u_index(k, j);
                qp.q[at] = q;
                let (ub, lb) = (qp.bound_row(k, j, true), qp.bound_row(k, j, false));
                qp.b[ub] = self.hi[j] - ubar;
                qp.b[lb] = ubar - self.lo[j];
                if let Some(rate) = self.cfg.rate_limit {
                    let (ru, rl) = (qp.rate_row(k, j, true), qp.rate_row(k, j, false));
                    qp.b[ru] = rate[j] - d_here;
                    qp.b[rl] = rate[j] + d_here;
                }
            }
        }
        // The equality rows of `b` stay zero from construction (the rollout has no defect).
    }
}
