//! The controller: its model, plan, QP and persistent solver, and one control cycle in named
//! phases (disturbance update, shift, linearise, write the QP's data, solve, accept the
//! solution, predict the next measurement); docs/MODEL.md section 11. The QP goes to Clarabel
//! (partially condensed, [`Qp`]) or to the Riccati interior-point method ([`RiccatiQp`]),
//! which takes the stages as they come.

use super::error::MpcError;
use super::fallback::Fallback;
use super::qp::Weights;
use super::qp::{ALL_STATES, Qp, WITHOUT_POSITION, soft_steps};
use super::reference::Reference;
use super::report::CycleReport;
use super::riccati::{IpmLimits, RiccatiInfo, RiccatiQp};
use super::settings::solver_settings;
use super::settings::{MpcConfig, QpSolver};
use crate::runtime::{EnvelopeStatus, HorizonLinearisation};
use crate::traits::DiscreteModel;
use crate::types::{Input, NU, NX, State};
use clarabel::solver::{DefaultSolver, IPSolver, SolverStatus, SupportedConeT};
use nalgebra::{SVector, Vector4};
use std::time::Instant;

/// The real-time-iteration LTV-MPC: every sample it shifts its plan, rolls its model out
/// and linearises exactly, writes the new data into a persistent QP solver (Clarabel or the
/// Riccati interior-point method, [`MpcConfig::qp`]) and solves one QP. All buffers are
/// allocated at construction.
///
/// # Example
/// The oracle controller (the analytic vehicle as its model) on one cycle from rest:
/// ```
/// use pinc::mpc::{Mpc, MpcConfig, Reference};
/// use pinc::vehicle::Rk4Vehicle;
/// use pinc::{Input, State};
///
/// let bounds = (Input::new(-10.0, -5.0, -5.0, -1.0), Input::new(10.0, 5.0, 20.0, 1.0));
/// let cfg = MpcConfig { bounds: Some(bounds), ..MpcConfig::default() };
/// let mut mpc = Mpc::new(Rk4Vehicle::default(), cfg)?;
/// let mut x = State::zeros();
/// x[3] = 1.0; // heading 0: (cos, sin) = (1, 0)
/// let dive = [Reference::depth_heading(1.0, 0.0); 20];
/// let report = mpc.step(&x, &dive);
/// assert!(report.fallback.is_none());
/// assert!(report.input[2] > 0.0, "pushes down (z is down) towards 1 m");
/// # Ok::<(), pinc::mpc::MpcError>(())
/// ```
pub struct Mpc<M: DiscreteModel> {
    model: M,
    ws: M::Workspace,
    cfg: MpcConfig,
    lo: Input,
    hi: Input,
    state_weights: [f64; NX],
    /// The 9-state components in the QP, in order.
    states: Vec<usize>,
    backend: Backend,
    /// The input plan `u_0 .. u_{N-1}` of the last cycle.
    plan: Vec<Input>,
    /// The nominal plan of this cycle (shifted previous plan).
    nominal: Vec<Input>,
    /// The nominal rollout of `nominal` and its linearisation.
    lin: HorizonLinearisation,
    predicted: Vec<State>,
    last_applied: Input,
    /// Soft velocity bounds `(component, min, max)`, in the order of the QP's soft bounds.
    soft_bounds: Vec<(usize, f64, f64)>,
    /// The offset the prediction carries at every step (offset-free tracking).
    disturbance: State,
    /// The model's prediction, made last cycle, of the state this cycle will measure.
    expected: Option<State>,
    /// Where each input channel's weight pulls it (see `MpcConfig::input_target_tau`).
    input_target: Input,
}

/// The QP and the solver it goes to.
enum Backend {
    /// The partially condensed QP and the persistent Clarabel solver.
    Clarabel {
        qp: Box<Qp>,
        solver: Box<DefaultSolver<f64>>,
    },
    /// The stage-wise QP with its own interior-point solver, without the horizontal position
    /// (7 kept states) or with it (9): the stage sizes are the solver's type parameters.
    Riccati7(Box<RiccatiQp<7>>),
    Riccati9(Box<RiccatiQp<9>>),
}

/// Runs `$body` with `$d` bound to the backend's QP data (a [`StageData`]), whichever it is.
macro_rules! with_stage_data {
    ($backend:expr, $d:ident => $body:expr) => {
        match $backend {
            Backend::Clarabel { qp, .. } => {
                let $d = &mut **qp;
                $body
            }
            Backend::Riccati7(qp) => {
                let $d = &mut **qp;
                $body
            }
            Backend::Riccati9(qp) => {
                let $d = &mut **qp;
                $body
            }
        }
    };
}

impl Backend {
    /// The Riccati solver's QP for `cfg`, its constant weights written.
    fn riccati<const S: usize>(
        cfg: &MpcConfig,
        states: &[usize],
        state_weights: &[f64; NX],
        soft: &[usize],
    ) -> Box<RiccatiQp<S>> {
        let n = cfg.horizon;
        let mut qp = RiccatiQp::<S>::new(n, cfg.rate_limit.is_some(), &soft_steps(n), soft);
        for k in 1..=n {
            let f = if k == n { cfg.terminal } else { 1.0 };
            qp.wx[k - 1] = SVector::from_fn(|s, _| 2.0 * f * state_weights[states[s]]);
        }
        qp.ru = Vector4::from_fn(|j, _| 2.0 * cfg.input[j]);
        qp.rd = Vector4::from_fn(|j, _| 2.0 * cfg.input_rate[j]);
        // Priced as in Clarabel's QP: the quadratic price equals the linear one.
        (qp.slack_linear, qp.slack_quad) = (cfg.envelope_penalty, 2.0 * cfg.envelope_penalty);
        Box::new(qp)
    }

    /// `du_k` of the last solution.
    fn input_deviation(&self, k: usize) -> Input {
        match self {
            Backend::Clarabel { qp, solver } => Input::from_fn(|j, _| solver.solution.x[qp.u_index(k, j)]),
            Backend::Riccati7(qp) => qp.input(k),
            Backend::Riccati9(qp) => qp.input(k),
        }
    }

    /// `dx_k` of kept component `s` in the last solution, where the QP keeps it.
    fn state_deviation(&self, k: usize, s: usize) -> Option<f64> {
        match self {
            Backend::Clarabel { qp, solver } => qp.x_index(k, s).map(|at| solver.solution.x[at]),
            Backend::Riccati7(qp) => Some(qp.x[k][s]),
            Backend::Riccati9(qp) => Some(qp.x[k][s]),
        }
    }
}

/// Where a cycle's stage data go: the same values, whichever QP holds them.
trait StageData {
    /// The linear cost of `dx_k[states[s]]`, `k = 1..=N`.
    fn state_cost(&mut self, k: usize, s: usize, q: f64);
    /// The linear cost of `du_k[j]`, its bounds `du <= upper`, `-du <= lower`, and the rate
    /// limits' right-hand sides.
    fn input_data(&mut self, k: usize, j: usize, q: f64, upper: f64, lower: f64, rate: Option<(f64, f64)>);
    /// The disturbance on kept component `r`.
    fn disturbance(&mut self, r: usize, v: f64);
    /// The step of the `j`-th set of soft bounds (`None` past the last).
    fn soft_step(&self, j: usize) -> Option<usize>;
    /// Soft bound `b` at `soft_steps[j]`: `dx <= hi`, `-dx <= lo`, priced `penalty` per unit.
    fn soft_bound(&mut self, j: usize, b: usize, hi: f64, lo: f64, penalty: f64);
}

impl StageData for Qp {
    fn state_cost(&mut self, k: usize, s: usize, q: f64) {
        let m = self.states.len();
        self.state_q[(k - 1) * m + s] = q;
    }

    fn input_data(&mut self, k: usize, j: usize, q: f64, upper: f64, lower: f64, rate: Option<(f64, f64)>) {
        self.input_q[k * NU + j] = q;
        let (ub, lb) = (self.bound_row(k, j, true), self.bound_row(k, j, false));
        (self.b[ub], self.b[lb]) = (upper, lower);
        if let Some((ru, rl)) = rate {
            let (rup, rlo) = (self.rate_row(k, j, true), self.rate_row(k, j, false));
            (self.b[rup], self.b[rlo]) = (ru, rl);
        }
    }

    fn disturbance(&mut self, r: usize, v: f64) {
        self.disturbance[r] = v;
    }

    fn soft_step(&self, j: usize) -> Option<usize> {
        self.soft_steps.get(j).copied()
    }

    fn soft_bound(&mut self, j: usize, b: usize, hi: f64, lo: f64, penalty: f64) {
        let (upper, lower, sign) = (self.soft_row(j, b, 0), self.soft_row(j, b, 1), self.soft_row(j, b, 2));
        (self.b[upper], self.b[lower], self.b[sign]) = (hi, lo, 0.0);
        let at = self.slack_index(j, b);
        self.q[at] = penalty;
    }
}

impl<const S: usize> StageData for RiccatiQp<S> {
    fn state_cost(&mut self, k: usize, s: usize, q: f64) {
        self.qx[k - 1][s] = q;
    }

    fn input_data(&mut self, k: usize, j: usize, q: f64, upper: f64, lower: f64, rate: Option<(f64, f64)>) {
        (self.qu[k][j], self.u_hi[k][j], self.u_lo[k][j]) = (q, upper, lower);
        if let Some((ru, rl)) = rate {
            (self.r_hi[k][j], self.r_lo[k][j]) = (ru, rl);
        }
    }

    fn disturbance(&mut self, r: usize, v: f64) {
        self.d[r] = v;
    }

    fn soft_step(&self, j: usize) -> Option<usize> {
        self.soft_steps.get(j).copied()
    }

    fn soft_bound(&mut self, j: usize, b: usize, hi: f64, lo: f64, _penalty: f64) {
        let at = j * self.soft.len() + b;
        (self.h_hi[at], self.h_lo[at]) = (hi, lo);
    }
}

/// A Riccati solve: the kept rows of the linearisation in, the solver's outcome out
/// (status, iterations, objective, whether the solution is finite).
fn solve_riccati<const S: usize>(
    qp: &mut RiccatiQp<S>,
    states: &[usize],
    lin: &HorizonLinearisation,
    cfg: &MpcConfig,
) -> (SolverStatus, u32, f64, bool) {
    qp.write_stages(states, lin.a(), lin.b());
    let limits =
        IpmLimits { max_iter: cfg.solver_max_iter, tol: cfg.riccati_tolerance, time_limit: cfg.solver_time_limit };
    qp.solve(limits);
    (qp.info.status, qp.info.iterations, qp.info.objective, qp.finite())
}

impl<M: DiscreteModel> Mpc<M> {
    /// A controller for `model`, starting from rest with a zero-force plan clipped to the bounds.
    ///
    /// # Errors
    /// No input bounds, a zero horizon, negative weights, or a QP Clarabel refuses.
    pub fn new(model: M, cfg: MpcConfig) -> Result<Self, MpcError> {
        let (lo, hi) = cfg.bounds.or_else(|| model.input_bounds()).ok_or(MpcError::NoBounds)?;
        cfg.validate()?;
        if (0..NU).any(|j| !(lo[j].is_finite() && hi[j].is_finite() && lo[j] <= hi[j])) {
            return Err(MpcError::Config(format!("input bounds {lo:?} .. {hi:?}")));
        }
        let mut state_weights = [0.0; NX];
        (state_weights[0], state_weights[1]) = (cfg.position, cfg.position);
        state_weights[2] = cfg.depth;
        state_weights[3] = cfg.heading;
        state_weights[4] = cfg.heading;
        state_weights[5..].copy_from_slice(&cfg.velocity);
        let w = Weights { state: state_weights, terminal: cfg.terminal, input: cfg.input, input_rate: cfg.input_rate };
        let n = cfg.horizon;
        // A position-free model's x, y matter only where the horizontal position is tracked.
        let states: &[usize] =
            if model.position_free() && !cfg.tracks_position() { &WITHOUT_POSITION } else { &ALL_STATES };
        // The body velocities the network sees, inside its envelope less the margin.
        let soft_bounds: Vec<(usize, f64, f64)> = match model.state_bounds() {
            Some((lo, hi)) if cfg.envelope_constraints => (5..NX)
                .filter(|&i| lo[i].is_finite() && hi[i].is_finite())
                .map(|i| {
                    let margin = cfg.envelope_margin * (hi[i] - lo[i]);
                    (i, lo[i] + margin, hi[i] - margin)
                })
                .collect(),
            _ => Vec::new(),
        };
        let soft: Vec<usize> = soft_bounds
            .iter()
            .map(|(i, ..)| states.iter().position(|s| s == i).expect("velocities are always kept"))
            .collect();
        // The slacks' quadratic price equals the exact (linear) one: it keeps the QP strictly
        // convex in them and Clarabel's iterations as few as without the bounds (a 1000 times
        // smaller one took about twice as many).
        let backend = match cfg.qp {
            QpSolver::Clarabel => {
                let qp =
                    Qp::new(n, cfg.condensing_block, &w, cfg.rate_limit.is_some(), states, &soft, cfg.envelope_penalty);
                let n_ineq = qp.b.len() - qp.n_eq;
                let cones = [SupportedConeT::ZeroConeT(qp.n_eq), SupportedConeT::NonnegativeConeT(n_ineq)];
                // A placeholder problem with the final pattern; every cycle overwrites its data.
                let mut b = qp.b.clone();
                b[qp.n_eq..].fill(1.0);
                let solver = DefaultSolver::new(&qp.p, &qp.q, &qp.a, &b, &cones, solver_settings(&cfg)?)
                    .map_err(|e| MpcError::Setup(e.to_string()))?;
                Backend::Clarabel { qp: Box::new(qp), solver: Box::new(solver) }
            }
            QpSolver::Riccati if states.len() == 7 => {
                Backend::Riccati7(Backend::riccati(&cfg, states, &state_weights, &soft))
            }
            QpSolver::Riccati => Backend::Riccati9(Backend::riccati(&cfg, states, &state_weights, &soft)),
        };
        let rest = Input::from_fn(|j, _| 0.0f64.clamp(lo[j], hi[j]));
        Ok(Self {
            ws: model.workspace(),
            model,
            lo,
            hi,
            state_weights,
            states: states.to_vec(),
            backend,
            plan: vec![rest; n],
            nominal: vec![rest; n],
            lin: HorizonLinearisation::new(n),
            predicted: vec![State::zeros(); n + 1],
            last_applied: rest,
            soft_bounds,
            disturbance: State::zeros(),
            expected: None,
            input_target: rest,
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

    /// The Clarabel solver inside, when it is the QP's solver: its `info` and `timers`
    /// describe the last solve (iterations, and the time in KKT factorisations, solves and
    /// cone updates).
    pub fn solver(&self) -> Option<&DefaultSolver<f64>> {
        match &self.backend {
            Backend::Clarabel { solver, .. } => Some(solver),
            Backend::Riccati7(_) | Backend::Riccati9(_) => None,
        }
    }

    /// The Riccati solver's account of its last solve, when it is the QP's solver
    /// (residuals and complementarity at the end).
    pub fn riccati_info(&self) -> Option<RiccatiInfo> {
        match &self.backend {
            Backend::Riccati7(qp) => Some(qp.info),
            Backend::Riccati9(qp) => Some(qp.info),
            Backend::Clarabel { .. } => None,
        }
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

    /// The disturbance estimate: the offset added to every predicted step (zero with
    /// `disturbance_gain = 0`).
    pub fn disturbance(&self) -> &State {
        &self.disturbance
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
        self.update_disturbance(x);
        self.shift_plan();
        let mut report = CycleReport::holding(self.nominal[0]);
        let linearised = self.model.linearise_horizon(&mut self.ws, x, &self.nominal, &mut self.lin);
        let t1 = Instant::now();
        report.linearise_us = (t1 - t0).as_secs_f64() * 1e6;
        report.envelope = self.model.envelope_status(&self.ws);
        report.fallback = if linearised.is_err() {
            Some(Fallback::Model)
        } else if self.cfg.envelope_fallback && !report.envelope.inside() {
            Some(Fallback::Envelope)
        } else {
            self.solve(refs, t1, &mut report)
        };
        if report.fallback.is_some() {
            self.plan.copy_from_slice(&self.nominal);
        }
        self.expect_next(x, &report.input);
        self.finish_report(&mut report, t0);
        report
    }

    /// Moves the disturbance estimate towards what the model got wrong about `x`: the
    /// difference between `x` and last cycle's prediction of it, for the components in the QP.
    fn update_disturbance(&mut self, x: &State) {
        let gain = self.cfg.disturbance_gain;
        if let Some(e) = self.expected.take()
            && gain > 0.0
        {
            let miss = x - e;
            if miss.iter().all(|v| v.is_finite()) {
                for &i in &self.states {
                    self.disturbance[i] += gain * miss[i];
                }
            }
        }
    }

    /// The model's prediction of the next measured state under the applied input, with the
    /// disturbance, for the next cycle's estimate; and the input targets' averages.
    fn expect_next(&mut self, x: &State, applied: &Input) {
        if self.cfg.disturbance_gain > 0.0 {
            let mut next = State::zeros();
            self.expected = self.model.step(&mut self.ws, x, applied, &mut next).ok().map(|()| next + self.disturbance);
        }
        let dt = self.model.dt();
        for j in 0..NU {
            let tau = self.cfg.input_target_tau[j];
            if tau > 0.0 {
                self.input_target[j] += (applied[j] - self.input_target[j]) * (dt / tau).min(1.0);
            }
        }
    }

    /// The nominal plan of this cycle: the previous plan shifted by one sample (`u_k <-
    /// u_{k+1}`, the last repeated), clipped to the bounds.
    fn shift_plan(&mut self) {
        let n = self.cfg.horizon;
        for k in 0..n {
            self.nominal[k] = self.clip(&self.plan[(k + 1).min(n - 1)]);
        }
    }

    /// Writes this cycle's data into the solver, solves, and on success takes the solution
    /// as the new plan and prediction. Returns why it fell back, if it did.
    fn solve(&mut self, refs: &[Reference], t1: Instant, report: &mut CycleReport) -> Option<Fallback> {
        self.fill_stage_data(refs);
        let written = match &mut self.backend {
            Backend::Clarabel { qp, solver } => {
                qp.condense(self.lin.a(), self.lin.b());
                // P changes only where inner states are condensed into it.
                let p_written = qp.block == 1 || solver.update_P(&qp.p_values).is_ok();
                p_written
                    && solver.update_A(&qp.a_values).is_ok()
                    && solver.update_q(&qp.q).is_ok()
                    && solver.update_b(&qp.b).is_ok()
            }
            Backend::Riccati7(_) | Backend::Riccati9(_) => true,
        };
        let t2 = Instant::now();
        report.update_us = (t2 - t1).as_secs_f64() * 1e6;
        if !written {
            return Some(Fallback::Solver(SolverStatus::Unsolved));
        }
        let finite;
        (report.status, report.iterations, report.objective, finite) = match &mut self.backend {
            Backend::Clarabel { solver, .. } => {
                solver.solve();
                let sol = &solver.solution;
                (sol.status, sol.iterations, sol.obj_val, sol.x.iter().all(|v| v.is_finite()))
            }
            Backend::Riccati7(qp) => solve_riccati(qp, &self.states, &self.lin, &self.cfg),
            Backend::Riccati9(qp) => solve_riccati(qp, &self.states, &self.lin, &self.cfg),
        };
        report.solve_us = t2.elapsed().as_secs_f64() * 1e6;
        if !(matches!(report.status, SolverStatus::Solved | SolverStatus::AlmostSolved) && finite) {
            return Some(Fallback::Solver(report.status));
        }
        self.accept_solution();
        report.input = self.plan[0];
        None
    }

    /// The new plan (nominal plus the QP's input deviations, clipped) and the prediction.
    fn accept_solution(&mut self) {
        let n = self.cfg.horizon;
        let backend = &self.backend;
        let du = |k: usize| backend.input_deviation(k);
        let kept = |k: usize, s: usize| backend.state_deviation(k, s);
        for k in 0..n {
            self.plan[k] = self.clip(&(self.nominal[k] + du(k)));
        }
        // The QP's kept states from its solution, the condensed ones and any left out (x, y)
        // by propagating the linearised dynamics: all the same linear prediction.
        let (traj, a, b) = (self.lin.trajectory(), self.lin.a(), self.lin.b());
        self.predicted[0] = traj[0];
        let mut dx = State::zeros();
        for k in 0..n {
            let mut next = a[k] * dx + b[k] * du(k);
            for (s, &i) in self.states.iter().enumerate() {
                next[i] = kept(k + 1, s).unwrap_or(next[i] + self.disturbance[i]);
            }
            dx = next;
            self.predicted[k + 1] = traj[k + 1] + dx;
        }
    }

    /// Saturation flags, the applied input, the cycle time and the deadline.
    fn finish_report(&mut self, report: &mut CycleReport, t0: Instant) {
        for j in 0..NU {
            let span = (self.hi[j] - self.lo[j]).max(1e-12);
            report.saturated[j] =
                report.input[j] <= self.lo[j] + 1e-6 * span || report.input[j] >= self.hi[j] - 1e-6 * span;
        }
        self.last_applied = report.input;
        report.cycle_us = t0.elapsed().as_secs_f64() * 1e6;
        report.deadline_missed = report.cycle_us > self.cfg.deadline * 1e6;
    }

    /// This cycle's linear costs, bounds and disturbance for the nominal trajectory, written
    /// into the QP of whichever solver runs (Clarabel's is condensed afterwards).
    fn fill_stage_data(&mut self, refs: &[Reference]) {
        let n = self.cfg.horizon;
        let traj = self.lin.trajectory();
        let (cfg, states, nominal) = (&self.cfg, &self.states, &self.nominal);
        with_stage_data!(&mut self.backend, data => {
            for k in 1..=n {
                let r = refs[(k - 1).min(refs.len() - 1)];
                let mut target = [0.0; NX];
                (target[2], target[3], target[4]) = (r.depth, r.heading.cos(), r.heading.sin());
                match r.horizontal {
                    // The path's velocity, turned into the body frame of the predicted heading.
                    Some(h) => {
                        (target[0], target[1]) = (h.north, h.east);
                        (target[5], target[6]) = h.body_velocity(traj[k][3], traj[k][4]);
                    }
                    // No horizontal goal: the position's cost stays at its nominal value.
                    None => (target[0], target[1]) = (traj[k][0], traj[k][1]),
                }
                let f = if k == n { cfg.terminal } else { 1.0 };
                for (s, &i) in states.iter().enumerate() {
                    data.state_cost(k, s, 2.0 * f * self.state_weights[i] * (traj[k][i] - target[i]));
                }
            }
            for k in 0..n {
                let prev = if k == 0 { self.last_applied } else { nominal[k - 1] };
                for j in 0..NU {
                    let ubar = nominal[k][j];
                    let rate_w = 2.0 * cfg.input_rate[j];
                    let d_here = ubar - prev[j];
                    let target = if cfg.input_target_tau[j] > 0.0 { self.input_target[j] } else { 0.0 };
                    let mut q = 2.0 * cfg.input[j] * (ubar - target) + rate_w * d_here;
                    if k + 1 < n {
                        q -= rate_w * (nominal[k + 1][j] - ubar);
                    }
                    let rate = cfg.rate_limit.map(|rate| (rate[j] - d_here, rate[j] + d_here));
                    data.input_data(k, j, q, self.hi[j] - ubar, ubar - self.lo[j], rate);
                }
            }
            // The rollout has no defect: the dynamics carry only the disturbance.
            for (r, &i) in states.iter().enumerate() {
                data.disturbance(r, self.disturbance[i]);
            }
            for (b, &(i, lo, hi)) in self.soft_bounds.iter().enumerate() {
                let mut j = 0;
                while let Some(k) = data.soft_step(j) {
                    data.soft_bound(j, b, hi - traj[k][i], traj[k][i] - lo, cfg.envelope_penalty);
                    j += 1;
                }
            }
        });
    }
}

impl CycleReport {
    /// A report that applies `input` (the shifted plan) until the cycle says otherwise.
    fn holding(input: Input) -> Self {
        Self {
            input,
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
        }
    }
}
