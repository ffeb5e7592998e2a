//! A primal-dual interior-point solver for exactly the MPC's QP, whose Newton step is a
//! Riccati recursion over the horizon (docs/MODEL.md section 11.4).
//!
//! The problem, in deviations from the nominal rollout over the kept state components
//! (`M` of them: 7 without the horizontal position, 9 with it) and the four inputs:
//!
//! ```text
//! min  sum_{k=1..N} 1/2 x_k' W_k x_k + qx_k' x_k
//!    + sum_{k=0..N-1} 1/2 u_k' R u_k + qu_k' u_k + 1/2 (u_k - u_{k-1})' D (u_k - u_{k-1})
//!    + sum_soft rho s + 1/2 kappa s^2
//! s.t. x_{k+1} = A_k x_k + B_k u_k + d,  x_0 = 0,  u_{-1} = 0
//!      -u_lo_k <= u_k <= u_hi_k
//!      -r_lo_k <= u_k - u_{k-1} <= r_hi_k            (with rate limits)
//!      x_k[c] - s <= h_hi,  -x_k[c] - s <= h_lo,  s >= 0   (soft bounds, one slack each)
//! ```
//!
//! `W_k`, `R`, `D` are diagonal. The input-rate term couples neighbouring inputs, so the
//! recursion runs on the state augmented with the previous input, `xi_k = [x_k; u_{k-1}]`,
//! kept as its blocks (`P_xx`, `P_xv`, `P_vv`). Each soft bound's slack is eliminated from its
//! step's Newton system (a 2 x 2 block with its state component), so the recursion never
//! sees it.
//!
//! Each iteration factors the stage matrices once and solves twice (Mehrotra's predictor and
//! corrector): `O(N (M + 4)^3)` per iteration. The sizes are type parameters, so every stage
//! product is a fixed-size (unrolled) nalgebra product; all buffers are allocated when the
//! solver is built.

use crate::types::{Input, NU};
use clarabel::solver::SolverStatus;
use nalgebra::{Matrix4, SMatrix, SVector, Vector4};
use std::time::Instant;

/// What the solver did on its last solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RiccatiInfo {
    /// How the last solve ended (Clarabel's status names, so both solvers report alike).
    pub status: SolverStatus,
    /// Interior-point iterations of the last solve.
    pub iterations: u32,
    /// The objective at the solution (deviation form, without constant terms).
    pub objective: f64,
    /// Largest primal residual (dynamics and inequality rows) at the end.
    pub primal_residual: f64,
    /// Largest dual (stationarity) residual at the end.
    pub dual_residual: f64,
    /// Mean complementarity `lambda' t / rows` at the end.
    pub mu: f64,
}

/// Limits of one solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct IpmLimits {
    pub(crate) max_iter: u32,
    /// Relative tolerance on the residuals and the duality gap.
    pub(crate) tol: f64,
    /// Wall-clock limit (s).
    pub(crate) time_limit: f64,
}

/// Fraction of the distance to the boundary a step may go.
const STEP_TO_BOUNDARY: f64 = 0.995;
/// Steps shorter than this for three iterations in a row end the solve as stalled.
const STALL_STEP: f64 = 1e-8;
/// The start's smallest row slack and a soft slack's margin beyond its bound's violation:
/// measured on the shipped model and the oracle (default scenario and the bench's state),
/// these took the mean iterations from 5.0 / 5.0 and 8.6 / 7.7 to 4.9 / 4.0 and 5.4 / 3.4
/// against a start at `t >= 1`, `lambda = 1`, slacks 1 beyond their violation.
const INITIAL_ROW_SLACK: f64 = 0.1;
const INITIAL_SLACK_MARGIN: f64 = 0.01;

type Sq<const M: usize> = SMatrix<f64, M, M>;
type In<const M: usize> = SMatrix<f64, M, NU>;
type Gain<const M: usize> = SMatrix<f64, NU, M>;
type Vx<const M: usize> = SVector<f64, M>;

/// The stage data (written by the controller each cycle), the iterates and every work buffer,
/// for `M` kept state components.
pub(crate) struct RiccatiQp<const M: usize> {
    /// Horizon.
    pub(crate) n: usize,
    /// `A_k`, `B_k` over the kept components, `k < N`.
    pub(crate) a: Vec<Sq<M>>,
    pub(crate) b: Vec<In<M>>,
    /// The disturbance every step carries.
    pub(crate) d: Vx<M>,
    /// Diagonal state weight and linear cost of `x_k`, `k = 1..=N`, at `k - 1`.
    pub(crate) wx: Vec<Vx<M>>,
    pub(crate) qx: Vec<Vx<M>>,
    /// Diagonal input weight `R` and input-change weight `D` (Hessian entries).
    pub(crate) ru: Vector4<f64>,
    pub(crate) rd: Vector4<f64>,
    /// Linear cost of `u_k`.
    pub(crate) qu: Vec<Vector4<f64>>,
    /// Input bounds `u_k <= u_hi`, `-u_k <= u_lo`.
    pub(crate) u_hi: Vec<Vector4<f64>>,
    pub(crate) u_lo: Vec<Vector4<f64>>,
    /// Rate limits `u_k - u_{k-1} <= r_hi`, `u_{k-1} - u_k <= r_lo` (when set).
    pub(crate) rate_limited: bool,
    pub(crate) r_hi: Vec<Vector4<f64>>,
    pub(crate) r_lo: Vec<Vector4<f64>>,
    /// Steps with soft bounds, the bounded components (positions among the kept ones), the
    /// bounds `x_k[c] - s <= h_hi`, `-x_k[c] - s <= h_lo` at `j ns + i`, and the slack's
    /// linear and quadratic (Hessian) prices.
    pub(crate) soft_steps: Vec<usize>,
    pub(crate) soft: Vec<usize>,
    pub(crate) h_hi: Vec<f64>,
    pub(crate) h_lo: Vec<f64>,
    pub(crate) slack_linear: f64,
    pub(crate) slack_quad: f64,

    /// Iterates: states `x_0..x_N` (`x_0 = 0`), inputs, slacks, the dynamics' multipliers
    /// (`pi_k`, `k = 1..=N`), and every row's multiplier and slack.
    pub(crate) x: Vec<Vx<M>>,
    pub(crate) u: Vec<Vector4<f64>>,
    s: Vec<f64>,
    pi: Vec<Vx<M>>,
    lam: Vec<f64>,
    t: Vec<f64>,

    /// Residuals: dynamics (`x_{k+1}`'s at `k`), rows, and the gradients of the Lagrangian
    /// without the dynamics' term (the recursion's linear costs).
    r_dyn: Vec<Vx<M>>,
    r_row: Vec<f64>,
    gx: Vec<Vx<M>>,
    gu: Vec<Vector4<f64>>,
    gs: Vec<f64>,
    /// Complementarity right-hand side, and `(lam r_row - r_mu) / t` per row.
    r_mu: Vec<f64>,
    rho: Vec<f64>,

    /// Newton step: directions and the new multipliers `pi+` of the dynamics; the affine
    /// (predictor) step's `dlam`, `dt`, kept for the corrector.
    dx: Vec<Vx<M>>,
    du: Vec<Vector4<f64>>,
    ds: Vec<f64>,
    dlam: Vec<f64>,
    dt: Vec<f64>,
    pi_new: Vec<Vx<M>>,
    dlam_aff: Vec<f64>,
    dt_aff: Vec<f64>,

    /// Stage Hessians after the barrier: the diagonals of `Q_xx` (steps `0..=N`), `R`,
    /// `Q_vv` and the `u`-`v` coupling; each soft bound's slack block.
    qxx: Vec<Vx<M>>,
    rdiag: Vec<Vector4<f64>>,
    qvv: Vec<Vector4<f64>>,
    svu: Vec<Vector4<f64>>,
    hss: Vec<f64>,
    hxs: Vec<f64>,
    /// The recursion: `P_k`'s blocks and `p_k`; `L_k^-1` (`L_k` the Cholesky factor of
    /// `R~_k`); `Y_k = L_k^-1 S~_k` as its `x` and `v` blocks; `y_k = L_k^-1 r~_k`.
    pxx: Vec<Sq<M>>,
    pxv: Vec<In<M>>,
    pvv: Vec<Matrix4<f64>>,
    px: Vec<Vx<M>>,
    pv: Vec<Vector4<f64>>,
    linv: Vec<Matrix4<f64>>,
    yx: Vec<Gain<M>>,
    yv: Vec<Matrix4<f64>>,
    y: Vec<Vector4<f64>>,

    pub(crate) info: RiccatiInfo,
}

/// Rows of one step's input bounds (and rate limits).
fn rows_per_step(rate_limited: bool) -> usize {
    if rate_limited { 4 * NU } else { 2 * NU }
}

impl<const M: usize> RiccatiQp<M> {
    /// The solver for a horizon `n`, with soft bounds at `soft_steps` on the kept components
    /// at positions `soft`.
    pub(crate) fn new(n: usize, rate_limited: bool, soft_steps: &[usize], soft: &[usize]) -> Self {
        let nb = soft_steps.len() * soft.len();
        let rows = n * rows_per_step(rate_limited) + 3 * nb;
        let f = |len: usize| vec![0.0; len];
        let vx = |len: usize| vec![Vx::<M>::zeros(); len];
        let v4 = |len: usize| vec![Vector4::zeros(); len];
        let m4 = |len: usize| vec![Matrix4::zeros(); len];
        Self {
            n,
            a: vec![Sq::zeros(); n],
            b: vec![In::zeros(); n],
            d: Vx::zeros(),
            wx: vx(n),
            qx: vx(n),
            ru: Vector4::zeros(),
            rd: Vector4::zeros(),
            qu: v4(n),
            u_hi: v4(n),
            u_lo: v4(n),
            rate_limited,
            r_hi: v4(if rate_limited { n } else { 0 }),
            r_lo: v4(if rate_limited { n } else { 0 }),
            soft_steps: soft_steps.to_vec(),
            soft: soft.to_vec(),
            h_hi: f(nb),
            h_lo: f(nb),
            slack_linear: 0.0,
            slack_quad: 0.0,
            x: vx(n + 1),
            u: v4(n),
            s: f(nb),
            pi: vx(n + 1),
            lam: f(rows),
            t: f(rows),
            r_dyn: vx(n),
            r_row: f(rows),
            gx: vx(n + 1),
            gu: v4(n),
            gs: f(nb),
            r_mu: f(rows),
            rho: f(rows),
            dx: vx(n + 1),
            du: v4(n),
            ds: f(nb),
            dlam: f(rows),
            dt: f(rows),
            pi_new: vx(n + 1),
            dlam_aff: f(rows),
            dt_aff: f(rows),
            qxx: vx(n + 1),
            rdiag: v4(n),
            qvv: v4(n),
            svu: v4(n),
            hss: f(nb),
            hxs: f(nb),
            pxx: vec![Sq::zeros(); n + 1],
            pxv: vec![In::zeros(); n + 1],
            pvv: m4(n + 1),
            px: vx(n + 1),
            pv: v4(n + 1),
            linv: m4(n),
            yx: vec![Gain::zeros(); n],
            yv: m4(n),
            y: v4(n),
            info: RiccatiInfo {
                status: SolverStatus::Unsolved,
                iterations: 0,
                objective: f64::NAN,
                primal_residual: f64::NAN,
                dual_residual: f64::NAN,
                mu: f64::NAN,
            },
        }
    }

    fn rows(&self) -> usize {
        self.lam.len()
    }

    /// First row of the soft bounds.
    fn soft_base(&self) -> usize {
        self.n * rows_per_step(self.rate_limited)
    }

    /// The kept rows and columns (`states`, of the 9) of every `A_k`, `B_k`.
    pub(crate) fn write_stages(&mut self, states: &[usize], a: &[crate::StateMatrix], b: &[crate::InputMatrix]) {
        for k in 0..self.n {
            self.a[k] = Sq::from_fn(|r, c| a[k][(states[r], states[c])]);
            self.b[k] = In::from_fn(|r, j| b[k][(states[r], j)]);
        }
    }

    /// `u_k` of the solution.
    pub(crate) fn input(&self, k: usize) -> Input {
        self.u[k]
    }

    /// Whether every input and state of the solution is finite.
    pub(crate) fn finite(&self) -> bool {
        self.u.iter().all(|u| u.iter().all(|v| v.is_finite())) && self.x.iter().all(|x| x.iter().all(|v| v.is_finite()))
    }

    /// Solves the QP from the data written into the public fields, from the centred start of
    /// [`Self::initialise`] (nothing is carried over from the last solve). The solution is in `x`, `u` whatever the status; it is
    /// the optimum only when the status is `Solved` (or `AlmostSolved`).
    pub(crate) fn solve(&mut self, limits: IpmLimits) -> SolverStatus {
        let start = Instant::now();
        self.initialise();
        let scale_p = 1.0 + self.primal_scale();
        let scale_d = 1.0 + self.dual_scale();
        let mut stalled = 0;
        let mut status = SolverStatus::MaxIterations;
        let mut iterations = 0;
        loop {
            let (primal, dual, mu) = self.residuals();
            self.info.primal_residual = primal;
            self.info.dual_residual = dual;
            self.info.mu = mu;
            if !(primal.is_finite() && dual.is_finite() && mu.is_finite()) {
                status = SolverStatus::NumericalError;
                break;
            }
            // The gap: every row's complementarity summed, against the objective's size.
            let gap = mu * self.rows() as f64;
            if primal <= limits.tol * scale_p
                && dual <= limits.tol * scale_d
                && gap <= limits.tol * (1.0 + self.objective().abs())
            {
                status = SolverStatus::Solved;
                break;
            }
            if iterations >= limits.max_iter {
                break;
            }
            if start.elapsed().as_secs_f64() > limits.time_limit {
                status = SolverStatus::MaxTime;
                break;
            }
            iterations += 1;
            if !self.factor() {
                status = self.near_or(SolverStatus::NumericalError, limits.tol, scale_p, scale_d);
                break;
            }
            // Predictor: the affine step to complementarity zero.
            for i in 0..self.rows() {
                self.r_mu[i] = self.lam[i] * self.t[i];
            }
            self.newton();
            let alpha_aff = self.step_length();
            let mu_aff = (0..self.rows())
                .map(|i| (self.lam[i] + alpha_aff * self.dlam[i]) * (self.t[i] + alpha_aff * self.dt[i]))
                .sum::<f64>()
                / self.rows() as f64;
            let sigma = (mu_aff / mu).clamp(0.0, 1.0).powi(3);
            // Corrector: centred, with the affine step's second-order term. Where the affine
            // step was blocked early that term is not a correction but a different direction:
            // the iterates then cycled between badly centred points (seen on rate-limited
            // cycles), so it is damped by the step the affine direction could take.
            self.dlam_aff.copy_from_slice(&self.dlam);
            self.dt_aff.copy_from_slice(&self.dt);
            for i in 0..self.rows() {
                self.r_mu[i] = self.lam[i] * self.t[i] + alpha_aff * self.dlam_aff[i] * self.dt_aff[i] - sigma * mu;
            }
            self.newton();
            let alpha = self.step_length();
            self.take_step(alpha);
            stalled = if alpha < STALL_STEP { stalled + 1 } else { 0 };
            if stalled >= 3 {
                status = self.near_or(SolverStatus::InsufficientProgress, limits.tol, scale_p, scale_d);
                break;
            }
        }
        self.info.status = status;
        self.info.iterations = iterations;
        self.info.objective = self.objective();
        status
    }

    /// `AlmostSolved` when the iterate meets a thousand times the tolerance (the barrier's
    /// conditioning ends some solves asked for more than double precision allows), else `why`.
    fn near_or(&self, why: SolverStatus, tol: f64, scale_p: f64, scale_d: f64) -> SolverStatus {
        let loose = 1e3 * tol;
        let i = &self.info;
        if i.primal_residual <= loose * scale_p && i.dual_residual <= loose * scale_d && i.mu <= loose * scale_d {
            SolverStatus::AlmostSolved
        } else {
            why
        }
    }

    /// Largest magnitude among the rows' right-hand sides and the disturbance.
    fn primal_scale(&self) -> f64 {
        let boxes = self.u_hi.iter().chain(&self.u_lo).chain(&self.r_hi).chain(&self.r_lo).map(|v| v.amax());
        let soft = self.h_hi.iter().chain(&self.h_lo).map(|v| v.abs());
        boxes.chain(soft).fold(self.d.amax(), f64::max)
    }

    /// Largest magnitude among the linear costs and the slack price.
    fn dual_scale(&self) -> f64 {
        let costs = self.qx.iter().map(|v| v.amax()).chain(self.qu.iter().map(|v| v.amax())).fold(0.0, f64::max);
        costs.max(if self.s.is_empty() { 0.0 } else { self.slack_linear.abs() })
    }

    /// The starting point: the nominal plan (zero input deviations) with the states it gives
    /// (so the dynamics hold from the start), each slack 0.01 beyond its soft bound's violation, every row's `t` its distance to its bound (at least 0.1) and
    /// `lambda = 1 / t`, so every row starts at the same complementarity `lambda t = 1` (a
    /// centred start); a soft bound's sign row takes the slack's price instead (what it
    /// carries while the bound is inactive).
    fn initialise(&mut self) {
        self.u.fill(Vector4::zeros());
        self.pi.fill(Vx::zeros());
        self.x[0] = Vx::zeros();
        for k in 0..self.n {
            self.x[k + 1] = self.a[k] * self.x[k] + self.d;
        }
        let ns = self.soft.len();
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let (b, xc) = (j * ns + i, self.x[k][c]);
                self.s[b] = (xc - self.h_hi[b]).max(-xc - self.h_lo[b]).max(0.0) + INITIAL_SLACK_MARGIN;
            }
        }
        self.row_values();
        for i in 0..self.rows() {
            // r_row holds C z - e here (no t yet).
            self.t[i] = (-self.r_row[i]).max(INITIAL_ROW_SLACK);
            self.lam[i] = 1.0 / self.t[i];
        }
        let base = self.soft_base();
        for b in 0..self.s.len() {
            self.lam[base + 3 * b + 2] = self.slack_linear.max(1.0);
        }
    }

    /// `r_row = C z - e` for every row (without `t`).
    fn row_values(&mut self) {
        let per = rows_per_step(self.rate_limited);
        for k in 0..self.n {
            let base = k * per;
            let u = self.u[k];
            let prev = if k > 0 { self.u[k - 1] } else { Vector4::zeros() };
            for j in 0..NU {
                self.r_row[base + j] = u[j] - self.u_hi[k][j];
                self.r_row[base + NU + j] = -u[j] - self.u_lo[k][j];
                if self.rate_limited {
                    self.r_row[base + 2 * NU + j] = u[j] - prev[j] - self.r_hi[k][j];
                    self.r_row[base + 3 * NU + j] = prev[j] - u[j] - self.r_lo[k][j];
                }
            }
        }
        let (ns, base) = (self.soft.len(), self.soft_base());
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                let (xc, s) = (self.x[k][c], self.s[b]);
                self.r_row[base + 3 * b] = xc - s - self.h_hi[b];
                self.r_row[base + 3 * b + 1] = -xc - s - self.h_lo[b];
                self.r_row[base + 3 * b + 2] = -s;
            }
        }
    }

    /// Every residual at the current iterate; returns the largest primal and dual residual and
    /// the mean complementarity.
    fn residuals(&mut self) -> (f64, f64, f64) {
        let n = self.n;
        self.row_values();
        let mut primal = 0.0f64;
        for i in 0..self.rows() {
            self.r_row[i] += self.t[i];
            primal = primal.max(self.r_row[i].abs());
        }
        for k in 0..n {
            self.r_dyn[k] = self.a[k] * self.x[k] + self.b[k] * self.u[k] + self.d - self.x[k + 1];
            primal = primal.max(self.r_dyn[k].amax());
        }
        // Gradients of the cost plus C' lam.
        for k in 1..=n {
            self.gx[k] = self.wx[k - 1].component_mul(&self.x[k]) + self.qx[k - 1];
        }
        let per = rows_per_step(self.rate_limited);
        for k in 0..n {
            let u = self.u[k];
            let prev = if k > 0 { self.u[k - 1] } else { Vector4::zeros() };
            let mut g = self.ru.component_mul(&u) + self.qu[k] + self.rd.component_mul(&(u - prev));
            if k + 1 < n {
                g -= self.rd.component_mul(&(self.u[k + 1] - u));
            }
            let base = k * per;
            for j in 0..NU {
                g[j] += self.lam[base + j] - self.lam[base + NU + j];
                if self.rate_limited {
                    g[j] += self.lam[base + 2 * NU + j] - self.lam[base + 3 * NU + j];
                    if k + 1 < n {
                        g[j] -= self.lam[base + per + 2 * NU + j] - self.lam[base + per + 3 * NU + j];
                    }
                }
            }
            self.gu[k] = g;
        }
        let (ns, base) = (self.soft.len(), self.soft_base());
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                let (l1, l2, l3) = (self.lam[base + 3 * b], self.lam[base + 3 * b + 1], self.lam[base + 3 * b + 2]);
                self.gx[k][c] += l1 - l2;
                self.gs[b] = self.slack_quad * self.s[b] + self.slack_linear - l1 - l2 - l3;
            }
        }
        // The dual residual adds the dynamics' multipliers: pi_k - A_k' pi_{k+1}, -B_k' pi_{k+1}.
        let mut dual = self.gs.iter().fold(0.0f64, |acc, v| acc.max(v.abs()));
        for k in 0..n {
            let next = &self.pi[k + 1];
            dual = dual.max((self.gu[k] - self.b[k].tr_mul(next)).amax());
            if k > 0 {
                dual = dual.max((self.gx[k] + self.pi[k] - self.a[k].tr_mul(next)).amax());
            }
        }
        dual = dual.max((self.gx[n] + self.pi[n]).amax());
        let gap: f64 = self.lam.iter().zip(&self.t).map(|(l, t)| l * t).sum();
        (primal, dual, gap / self.rows().max(1) as f64)
    }

    /// The stage Hessians with the barrier's terms, the slacks eliminated, and the matrix
    /// half of the Riccati recursion. `false` when a stage's `R~` is not positive definite.
    fn factor(&mut self) -> bool {
        let n = self.n;
        let per = rows_per_step(self.rate_limited);
        let sigma = |s: &Self, row: usize| s.lam[row] / s.t[row];
        self.qxx[0] = Vx::zeros();
        for k in 1..=n {
            self.qxx[k] = self.wx[k - 1];
        }
        for k in 0..n {
            let base = k * per;
            for j in 0..NU {
                let mut r = self.ru[j] + self.rd[j] + sigma(self, base + j) + sigma(self, base + NU + j);
                let (mut vv, mut vu) = (if k > 0 { self.rd[j] } else { 0.0 }, -self.rd[j]);
                if self.rate_limited {
                    let s = sigma(self, base + 2 * NU + j) + sigma(self, base + 3 * NU + j);
                    r += s;
                    vv += s;
                    vu -= s;
                }
                self.rdiag[k][j] = r;
                self.qvv[k][j] = vv;
                self.svu[k][j] = if k > 0 { vu } else { 0.0 };
            }
        }
        let (ns, sbase) = (self.soft.len(), self.soft_base());
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                let (s1, s2, s3) =
                    (sigma(self, sbase + 3 * b), sigma(self, sbase + 3 * b + 1), sigma(self, sbase + 3 * b + 2));
                let hss = self.slack_quad + s1 + s2 + s3;
                let hxs = s2 - s1;
                self.hss[b] = hss;
                self.hxs[b] = hxs;
                self.qxx[k][c] += s1 + s2 - hxs * hxs / hss;
            }
        }

        // P_N: the terminal state's weight; the last input has no successor to cost.
        self.pxx[n] = Sq::from_diagonal(&self.qxx[n]);
        self.pxv[n] = In::zeros();
        self.pvv[n] = Matrix4::zeros();
        for k in (0..n).rev() {
            let (a, b) = (&self.a[k], &self.b[k]);
            // G = P_xx B + P_xv; R~ = R + B' G + P_xv' B + P_vv.
            let g = self.pxx[k + 1] * b + self.pxv[k + 1];
            let r = b.tr_mul(&g) + self.pxv[k + 1].tr_mul(b) + self.pvv[k + 1] + Matrix4::from_diagonal(&self.rdiag[k]);
            let Some(linv) = lower_inverse(&r) else {
                return false;
            };
            self.linv[k] = linv;
            if k == 0 {
                break;
            }
            // S~ = [G' A, diag(svu)]; Y = L^-1 S~.
            let yx = linv * g.tr_mul(a);
            let yv = Matrix4::from_fn(|r, c| linv[(r, c)] * self.svu[k][c]);
            // P_xx = Q_xx + A' P_xx+ A - Yx' Yx (symmetric: one triangle computed);
            // P_xv = -Yx' Yv; P_vv = Q_vv - Yv' Yv.
            let pa = self.pxx[k + 1] * a;
            let pxx = &mut self.pxx[k];
            for c in 0..M {
                for r in c..M {
                    let v = a.column(r).dot(&pa.column(c)) - yx.column(r).dot(&yx.column(c));
                    pxx[(r, c)] = v;
                    pxx[(c, r)] = v;
                }
                pxx[(c, c)] += self.qxx[k][c];
            }
            self.pxv[k] = -yx.tr_mul(&yv);
            self.pvv[k] = Matrix4::from_diagonal(&self.qvv[k]) - yv.tr_mul(&yv);
            self.yx[k] = yx;
            self.yv[k] = yv;
        }
        true
    }

    /// One Newton direction for the complementarity right-hand side in `r_mu`, from the
    /// factors of [`Self::factor`]: the vector half of the recursion, the forward pass, then
    /// the slacks', rows' and multipliers' directions.
    fn newton(&mut self) {
        let n = self.n;
        let per = rows_per_step(self.rate_limited);
        for i in 0..self.rows() {
            self.rho[i] = (self.lam[i] * self.r_row[i] - self.r_mu[i]) / self.t[i];
        }
        // Linear costs of the reduced system: the gradients plus C' rho, the slacks eliminated
        // (the inputs' in `du`, the slacks' in `ds`, the states' in `dx` until the forward pass).
        for k in 0..n {
            let base = k * per;
            let mut g = self.gu[k];
            for j in 0..NU {
                g[j] += self.rho[base + j] - self.rho[base + NU + j];
                if self.rate_limited {
                    g[j] += self.rho[base + 2 * NU + j] - self.rho[base + 3 * NU + j];
                    if k + 1 < n {
                        g[j] -= self.rho[base + per + 2 * NU + j] - self.rho[base + per + 3 * NU + j];
                    }
                }
            }
            self.du[k] = g;
        }
        self.dx.copy_from_slice(&self.gx);
        let (ns, sbase) = (self.soft.len(), self.soft_base());
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                let (r1, r2, r3) = (self.rho[sbase + 3 * b], self.rho[sbase + 3 * b + 1], self.rho[sbase + 3 * b + 2]);
                let ls = self.gs[b] - r1 - r2 - r3;
                self.ds[b] = ls;
                self.dx[k][c] += r1 - r2 - self.hxs[b] * ls / self.hss[b];
            }
        }
        // Backward: p_N = lx_N; w = P_{k+1} [e_k; 0] + p_{k+1}; y = L^-1 r~; p_k = q~ - Y' y.
        self.px[n] = self.dx[n];
        self.pv[n] = Vector4::zeros();
        for k in (0..n).rev() {
            let e = &self.r_dyn[k];
            let wx = self.pxx[k + 1] * e + self.px[k + 1];
            let wv = self.pxv[k + 1].tr_mul(e) + self.pv[k + 1];
            let y = self.linv[k] * (self.du[k] + wv + self.b[k].tr_mul(&wx));
            self.y[k] = y;
            if k == 0 {
                break;
            }
            self.px[k] = self.dx[k] + self.a[k].tr_mul(&wx) - self.yx[k].tr_mul(&y);
            self.pv[k] = -self.yv[k].tr_mul(&y);
        }
        // Forward: du_k = -L^-T (Y xi_k + y_k); x_{k+1} = A x_k + B du_k + e_k; pi+ = -(P xi + p).
        self.dx[0] = Vx::zeros();
        for k in 0..n {
            let mut v = self.y[k];
            if k > 0 {
                v += self.yx[k] * self.dx[k] + self.yv[k] * self.du[k - 1];
            }
            let du = -self.linv[k].tr_mul(&v);
            self.du[k] = du;
            let next = self.a[k] * self.dx[k] + self.b[k] * du + self.r_dyn[k];
            self.dx[k + 1] = next;
            self.pi_new[k + 1] = -(self.pxx[k + 1] * next + self.pxv[k + 1] * du + self.px[k + 1]);
        }
        // The slacks, then every row's slack and multiplier direction.
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                self.ds[b] = -(self.ds[b] + self.hxs[b] * self.dx[k][c]) / self.hss[b];
            }
        }
        for k in 0..n {
            let base = k * per;
            let du = self.du[k];
            let prev = if k > 0 { self.du[k - 1] } else { Vector4::zeros() };
            for j in 0..NU {
                self.dt[base + j] = -du[j];
                self.dt[base + NU + j] = du[j];
                if self.rate_limited {
                    self.dt[base + 2 * NU + j] = prev[j] - du[j];
                    self.dt[base + 3 * NU + j] = du[j] - prev[j];
                }
            }
        }
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                let (dxc, ds) = (self.dx[k][c], self.ds[b]);
                self.dt[sbase + 3 * b] = -dxc + ds;
                self.dt[sbase + 3 * b + 1] = dxc + ds;
                self.dt[sbase + 3 * b + 2] = ds;
            }
        }
        for i in 0..self.rows() {
            self.dt[i] -= self.r_row[i];
            self.dlam[i] = -(self.r_mu[i] + self.lam[i] * self.dt[i]) / self.t[i];
        }
    }

    /// The longest step in `(0, 1]` keeping every `lam` and `t` positive, shortened by
    /// [`STEP_TO_BOUNDARY`].
    fn step_length(&self) -> f64 {
        let mut alpha = 1.0f64;
        for i in 0..self.rows() {
            if self.dlam[i] < 0.0 {
                alpha = alpha.min(-STEP_TO_BOUNDARY * self.lam[i] / self.dlam[i]);
            }
            if self.dt[i] < 0.0 {
                alpha = alpha.min(-STEP_TO_BOUNDARY * self.t[i] / self.dt[i]);
            }
        }
        alpha
    }

    fn take_step(&mut self, alpha: f64) {
        for (x, d) in self.x.iter_mut().zip(&self.dx) {
            *x += alpha * d;
        }
        for (u, d) in self.u.iter_mut().zip(&self.du) {
            *u += alpha * d;
        }
        for (s, d) in self.s.iter_mut().zip(&self.ds) {
            *s += alpha * d;
        }
        for (p, q) in self.pi.iter_mut().zip(&self.pi_new) {
            *p += alpha * (q - *p);
        }
        for i in 0..self.rows() {
            self.lam[i] += alpha * self.dlam[i];
            self.t[i] += alpha * self.dt[i];
        }
    }

    /// The cost at the current iterate.
    fn objective(&self) -> f64 {
        let n = self.n;
        let mut f = 0.0;
        for k in 1..=n {
            let x = &self.x[k];
            f += 0.5 * self.wx[k - 1].component_mul(x).dot(x) + self.qx[k - 1].dot(x);
        }
        for k in 0..n {
            let u = &self.u[k];
            let change = u - if k > 0 { self.u[k - 1] } else { Vector4::zeros() };
            f += 0.5 * self.ru.component_mul(u).dot(u)
                + self.qu[k].dot(u)
                + 0.5 * self.rd.component_mul(&change).dot(&change);
        }
        f + self.s.iter().map(|s| self.slack_linear * s + 0.5 * self.slack_quad * s * s).sum::<f64>()
    }

    /// The slack of soft bound `i` at `soft_steps[j]` (for tests).
    #[cfg(test)]
    pub(crate) fn slack(&self, j: usize, i: usize) -> f64 {
        self.s[j * self.soft.len() + i]
    }
}

/// `L^-1` for the Cholesky factor `L` of the symmetric 4 x 4 `r` (its lower triangle read);
/// `None` unless `r` is positive definite.
fn lower_inverse(r: &Matrix4<f64>) -> Option<Matrix4<f64>> {
    let mut l = Matrix4::zeros();
    for c in 0..NU {
        let mut d = r[(c, c)];
        for i in 0..c {
            d -= l[(c, i)] * l[(c, i)];
        }
        if !(d > 0.0 && d.is_finite()) {
            return None;
        }
        let d = d.sqrt();
        l[(c, c)] = d;
        for row in c + 1..NU {
            let mut v = r[(row, c)];
            for i in 0..c {
                v -= l[(row, i)] * l[(c, i)];
            }
            l[(row, c)] = v / d;
        }
    }
    // Forward substitution on the identity, column by column.
    let mut inv = Matrix4::zeros();
    for c in 0..NU {
        for row in c..NU {
            let mut v = if row == c { 1.0 } else { 0.0 };
            for i in c..row {
                v -= l[(row, i)] * inv[(i, c)];
            }
            inv[(row, c)] = v / l[(row, row)];
        }
    }
    Some(inv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mpc::qp::{ALL_STATES, Qp, WITHOUT_POSITION, Weights, hash, soft_steps, solve_condensed};
    use crate::types::{InputMatrix, StateMatrix};
    use nalgebra::{DMatrix, DVector, SVector, Vector4};

    /// One random problem of the MPC's shape: near-identity dynamics, dense inputs, diagonal
    /// weights, bounds `bound` wide around the nominal, soft bounds `soft_width` wide.
    struct Case {
        n: usize,
        states: Vec<usize>,
        soft: Vec<usize>,
        rate: Option<f64>,
        a: Vec<StateMatrix>,
        b: Vec<InputMatrix>,
        w: Weights,
        state_q: Vec<f64>,
        input_q: Vec<f64>,
        d: Vec<f64>,
        bound: f64,
        soft_width: f64,
        penalty: f64,
    }

    impl Case {
        fn new(seed: usize, n: usize, states: &[usize], soft: &[usize], rate: Option<f64>, bound: f64) -> Self {
            let m = states.len();
            let a = (0..n)
                .map(|k| StateMatrix::from_fn(|r, c| if r == c { 0.97 } else { 0.0 } + 0.05 * hash(seed + k, r, c)))
                .collect();
            let b = (0..n).map(|k| InputMatrix::from_fn(|r, j| 0.2 * hash(seed + k + 100, r, j))).collect();
            let w = Weights {
                state: std::array::from_fn(|i| 0.1 + 5.0 * hash(seed, i, 7).abs()),
                terminal: 3.0,
                input: std::array::from_fn(|j| 0.01 + 0.05 * hash(seed, j, 8).abs()),
                input_rate: std::array::from_fn(|j| 0.1 * hash(seed, j, 9).abs()),
            };
            Self {
                n,
                states: states.to_vec(),
                soft: soft.to_vec(),
                rate,
                a,
                b,
                w,
                state_q: (0..n * m).map(|i| hash(seed + i, 1, 2)).collect(),
                input_q: (0..n * NU).map(|i| 0.5 * hash(seed + i, 3, 4)).collect(),
                d: (0..m).map(|r| 0.01 * hash(seed + r, 5, 6)).collect(),
                bound,
                soft_width: 0.02,
                penalty: 3.0,
            }
        }

        /// The Riccati solver with this case's data.
        fn riccati<const M: usize>(&self) -> RiccatiQp<M> {
            let (n, m) = (self.n, self.states.len());
            assert_eq!(m, M);
            let mut qp = RiccatiQp::<M>::new(n, self.rate.is_some(), &soft_steps(n), &self.soft);
            qp.write_stages(&self.states, &self.a, &self.b);
            for k in 1..=n {
                let f = if k == n { self.w.terminal } else { 1.0 };
                for (s, &i) in self.states.iter().enumerate() {
                    qp.wx[k - 1][s] = 2.0 * f * self.w.state[i];
                    qp.qx[k - 1][s] = self.state_q[(k - 1) * m + s];
                }
            }
            for k in 0..n {
                qp.qu[k] = Vector4::from_fn(|j, _| self.input_q[k * NU + j]);
            }
            qp.d = SVector::from_fn(|r, _| self.d[r]);
            qp.ru = Vector4::from_fn(|j, _| 2.0 * self.w.input[j]);
            qp.rd = Vector4::from_fn(|j, _| 2.0 * self.w.input_rate[j]);
            qp.u_hi.fill(Vector4::repeat(self.bound));
            qp.u_lo.fill(Vector4::repeat(0.75 * self.bound));
            if let Some(r) = self.rate {
                qp.r_hi.fill(Vector4::repeat(r));
                qp.r_lo.fill(Vector4::repeat(r));
            }
            qp.h_hi.fill(self.soft_width);
            qp.h_lo.fill(self.soft_width);
            (qp.slack_linear, qp.slack_quad) = (self.penalty, 2.0 * self.penalty);
            qp
        }

        /// Clarabel on the sparse QP of `mpc::qp` with the same data, to 1e-10: `du`.
        fn clarabel(&self) -> Vec<f64> {
            let n = self.n;
            let mut qp = Qp::new(n, 1, &self.w, self.rate.is_some(), &self.states, &self.soft, self.penalty);
            qp.state_q.copy_from_slice(&self.state_q);
            qp.input_q.copy_from_slice(&self.input_q);
            qp.disturbance.copy_from_slice(&self.d);
            for k in 0..n {
                for j in 0..NU {
                    let (ub, lb) = (qp.bound_row(k, j, true), qp.bound_row(k, j, false));
                    (qp.b[ub], qp.b[lb]) = (self.bound, 0.75 * self.bound);
                    if let Some(r) = self.rate {
                        let (ru, rl) = (qp.rate_row(k, j, true), qp.rate_row(k, j, false));
                        (qp.b[ru], qp.b[rl]) = (r, r);
                    }
                }
            }
            for j in 0..qp.soft_steps.len() {
                for i in 0..qp.soft.len() {
                    let (up, lo, sign) = (qp.soft_row(j, i, 0), qp.soft_row(j, i, 1), qp.soft_row(j, i, 2));
                    (qp.b[up], qp.b[lo], qp.b[sign]) = (self.soft_width, self.soft_width, 0.0);
                    let at = qp.slack_index(j, i);
                    qp.q[at] = self.penalty;
                }
            }
            qp.condense(&self.a, &self.b);
            let z = solve_condensed(&qp, 1e-11);
            (0..n).flat_map(|k| (0..NU).map(move |j| (k, j))).map(|(k, j)| z[qp.u_index(k, j)]).collect()
        }

        /// The equality-constrained QP (no inequality rows) as one dense KKT system: `du`, `dx`.
        fn dense_kkt(&self) -> (Vec<f64>, Vec<f64>) {
            let (n, m) = (self.n, self.states.len());
            let (nx, nu) = (n * m, n * NU);
            let dim = nx + nu + nx;
            let (xi, ui) = (|k: usize, s: usize| (k - 1) * m + s, |k: usize, j: usize| nx + k * NU + j);
            let mut kkt = DMatrix::<f64>::zeros(dim, dim);
            let mut rhs = DVector::<f64>::zeros(dim);
            for k in 1..=n {
                let f = if k == n { self.w.terminal } else { 1.0 };
                for (s, &i) in self.states.iter().enumerate() {
                    kkt[(xi(k, s), xi(k, s))] = 2.0 * f * self.w.state[i];
                    rhs[xi(k, s)] = -self.state_q[(k - 1) * m + s];
                }
            }
            for k in 0..n {
                for j in 0..NU {
                    let (r, d) = (2.0 * self.w.input[j], 2.0 * self.w.input_rate[j]);
                    kkt[(ui(k, j), ui(k, j))] += r + d + if k + 1 < n { d } else { 0.0 };
                    if k > 0 {
                        kkt[(ui(k, j), ui(k - 1, j))] -= d;
                        kkt[(ui(k - 1, j), ui(k, j))] -= d;
                    }
                    rhs[ui(k, j)] = -self.input_q[k * NU + j];
                }
            }
            // x_{k+1} - A_k x_k - B_k u_k = d.
            for k in 0..n {
                for (r, &ir) in self.states.iter().enumerate() {
                    let row = nx + nu + k * m + r;
                    let mut put = |col: usize, v: f64| {
                        kkt[(row, col)] = v;
                        kkt[(col, row)] = v;
                    };
                    put(xi(k + 1, r), 1.0);
                    for (c, &ic) in self.states.iter().enumerate() {
                        if k > 0 {
                            put(xi(k, c), -self.a[k][(ir, ic)]);
                        }
                    }
                    for j in 0..NU {
                        put(ui(k, j), -self.b[k][(ir, j)]);
                    }
                    rhs[row] = self.d[r];
                }
            }
            let z = kkt.lu().solve(&rhs).expect("the KKT matrix is regular");
            (z.as_slice()[nx..nx + nu].to_vec(), z.as_slice()[..nx].to_vec())
        }
    }

    fn limits(tol: f64) -> IpmLimits {
        IpmLimits { max_iter: 100, tol, time_limit: f64::INFINITY }
    }

    fn worst(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
    }

    /// The solution's inputs and states `x_1..x_N`, flat.
    fn flat<const M: usize>(qp: &RiccatiQp<M>) -> (Vec<f64>, Vec<f64>) {
        let u = qp.u.iter().flat_map(|u| u.iter().copied()).collect();
        let x = qp.x[1..].iter().flat_map(|x| x.iter().copied()).collect();
        (u, x)
    }

    fn against_dense<const M: usize>(case: &Case) {
        let mut qp = case.riccati::<M>();
        assert_eq!(qp.solve(limits(1e-12)), SolverStatus::Solved);
        let (du, dx) = case.dense_kkt();
        let (u, x) = flat(&qp);
        assert!(worst(&u, &du) < 1e-8, "inputs differ by {:e}", worst(&u, &du));
        assert!(worst(&x, &dx) < 1e-8, "states differ by {:e}", worst(&x, &dx));
        assert!(du.iter().any(|v| v.abs() > 0.05), "the problem moves the inputs");
    }

    #[test]
    fn unconstrained_solution_equals_the_dense_kkt_solve() {
        for (seed, states) in [(1, &WITHOUT_POSITION[..]), (2, &ALL_STATES[..])] {
            let mut case = Case::new(seed, 9, states, &[], None, 1e6);
            case.soft_width = 1e6;
            if states.len() == 7 { against_dense::<7>(&case) } else { against_dense::<9>(&case) }
        }
    }

    /// Solves `case` to 1e-10 against Clarabel; returns the inputs and slacks at a bound.
    fn against_clarabel<const M: usize>(case: &Case, seed: usize) -> usize {
        let mut qp = case.riccati::<M>();
        assert_eq!(qp.solve(limits(1e-10)), SolverStatus::Solved, "seed {seed}");
        let du = case.clarabel();
        let (u, _) = flat(&qp);
        assert!(worst(&u, &du) < 1e-6, "seed {seed}: inputs differ from Clarabel's by {:e}", worst(&u, &du));
        let at_bound = u.iter().filter(|&&u| u >= 0.4 - 1e-6 || u <= -0.3 + 1e-6).count();
        at_bound + (0..qp.soft_steps.len()).filter(|&j| (0..qp.soft.len()).any(|i| qp.slack(j, i) > 1e-6)).count()
    }

    #[test]
    fn constrained_solutions_equal_clarabels() {
        let mut active = 0;
        for seed in 0..12 {
            let states: &[usize] = if seed % 2 == 0 { &WITHOUT_POSITION } else { &ALL_STATES };
            let soft: &[usize] = if seed % 3 == 0 { &[] } else { &[3, 4, 5, 6][..] };
            let soft: Vec<usize> = soft.iter().map(|&c| c + states.len() - 7).collect();
            let rate = if seed % 4 == 1 { Some(0.25) } else { None };
            let n = [5, 13, 20, 8][seed % 4];
            let case = Case::new(100 * seed, n, states, &soft, rate, 0.4);
            active +=
                if states.len() == 7 { against_clarabel::<7>(&case, seed) } else { against_clarabel::<9>(&case, seed) };
        }
        assert!(active > 20, "the cases bind their bounds ({active} active)");
    }

    #[test]
    fn a_non_finite_model_ends_in_a_status_not_a_nan() {
        let case = Case::new(5, 6, &WITHOUT_POSITION, &[3], None, 0.4);
        let mut qp = case.riccati::<7>();
        qp.a[1][(3, 3)] = f64::NAN;
        let status = qp.solve(limits(1e-8));
        assert_eq!(status, SolverStatus::NumericalError);
    }

    #[test]
    fn empty_input_bounds_do_not_end_solved() {
        let case = Case::new(6, 6, &WITHOUT_POSITION, &[], Some(0.1), 0.4);
        let mut qp = case.riccati::<7>();
        qp.u_hi[1][1] = -1.0;
        qp.u_lo[1][1] = -1.0; // u <= -1 and u >= 1
        let status = qp.solve(limits(1e-8));
        assert!(status != SolverStatus::Solved, "{status:?}");
    }
}
