//! A primal-dual interior-point solver for exactly the MPC's QP, whose Newton step is a
//! Riccati recursion over the horizon (docs/MODEL.md section 11.4).
//!
//! The problem, in deviations from the nominal rollout over the kept state components
//! (`m` of them) and the four inputs:
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
//! recursion runs on the state augmented with the previous input, `xi_k = [x_k; u_{k-1}]`
//! (`m + 4` components). Each soft bound's slack is eliminated from its step's Newton system
//! (a 2 x 2 block with its state component), so the recursion never sees it.
//!
//! Each iteration factors the stage matrices once and solves twice (Mehrotra's predictor and
//! corrector): `O(N (m + 4)^3)` per iteration, all buffers allocated when the solver is built.

use crate::types::NU;
use clarabel::solver::SolverStatus;
use std::time::Instant;

/// What the solver was asked and what it did on its last solve.
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
    /// Relative tolerance on the residuals and the complementarity.
    pub(crate) tol: f64,
    /// Wall-clock limit (s).
    pub(crate) time_limit: f64,
}

/// Fraction of the distance to the boundary a step may go.
const STEP_TO_BOUNDARY: f64 = 0.995;
/// Steps shorter than this for three iterations in a row end the solve as stalled.
const STALL_STEP: f64 = 1e-8;

/// The stage data (written by the controller each cycle), the iterates and every work buffer.
pub(crate) struct RiccatiQp {
    /// Horizon and kept state components.
    pub(crate) n: usize,
    pub(crate) m: usize,
    /// `A_k` (`m x m`, column-major, at `k m^2`) and `B_k` (`m x 4`, at `k 4 m`), `k < N`.
    pub(crate) a: Vec<f64>,
    pub(crate) b: Vec<f64>,
    /// The disturbance every step carries.
    pub(crate) d: Vec<f64>,
    /// Diagonal state weight and linear cost of `x_k`, `k = 1..=N`, at `(k - 1) m`.
    pub(crate) wx: Vec<f64>,
    pub(crate) qx: Vec<f64>,
    /// Diagonal input weight `R` and input-change weight `D` (Hessian entries).
    pub(crate) ru: [f64; NU],
    pub(crate) rd: [f64; NU],
    /// Linear cost of `u_k` at `k 4`.
    pub(crate) qu: Vec<f64>,
    /// Input bounds `u_k <= u_hi`, `-u_k <= u_lo` at `k 4`.
    pub(crate) u_hi: Vec<f64>,
    pub(crate) u_lo: Vec<f64>,
    /// Rate limits `u_k - u_{k-1} <= r_hi`, `u_{k-1} - u_k <= r_lo` at `k 4` (when set).
    pub(crate) rate_limited: bool,
    pub(crate) r_hi: Vec<f64>,
    pub(crate) r_lo: Vec<f64>,
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
    /// (`pi_k` at `k m`, `k = 1..=N`), inequality multipliers and slacks of every row.
    pub(crate) x: Vec<f64>,
    pub(crate) u: Vec<f64>,
    s: Vec<f64>,
    pi: Vec<f64>,
    lam: Vec<f64>,
    t: Vec<f64>,

    /// Residuals: dynamics (`x_{k+1}` row at `k m`), rows, and the gradients of the
    /// Lagrangian without the dynamics' term (the recursion's linear costs).
    r_dyn: Vec<f64>,
    r_row: Vec<f64>,
    gx: Vec<f64>,
    gu: Vec<f64>,
    gs: Vec<f64>,
    /// Complementarity right-hand side, and `(lam r_row - r_mu) / t` per row.
    r_mu: Vec<f64>,
    rho: Vec<f64>,

    /// Newton step: directions, the new multipliers `pi+` of the dynamics.
    dx: Vec<f64>,
    du: Vec<f64>,
    ds: Vec<f64>,
    dlam: Vec<f64>,
    dt: Vec<f64>,
    pi_new: Vec<f64>,
    /// The affine (predictor) step's `dlam`, `dt`, kept for the corrector.
    dlam_aff: Vec<f64>,
    dt_aff: Vec<f64>,

    /// Stage Hessians after the barrier: the diagonal of `Q_xx` (per step `0..=N`, at `k m`),
    /// of `R`, of `Q_vv` and of the `u`-`v` coupling (at `k 4`); slack blocks per soft bound.
    qxx: Vec<f64>,
    rdiag: Vec<f64>,
    qvv: Vec<f64>,
    svu: Vec<f64>,
    hss: Vec<f64>,
    hxs: Vec<f64>,
    /// The recursion: `P_k` blocks (`xx` at `k m^2`, `xv` at `k 4m`, `vv` at `k 16`),
    /// `p_k` (`x` at `k m`, `v` at `k 4`), `L_k` (Cholesky factor of `R~_k`, at `k 16`),
    /// `Y_k = L_k^-1 S~_k` (`4 x (m + 4)`, at `k 4 (m + 4)`), `y_k = L_k^-1 r~_k`.
    pxx: Vec<f64>,
    pxv: Vec<f64>,
    pvv: Vec<f64>,
    px: Vec<f64>,
    pv: Vec<f64>,
    chol: Vec<f64>,
    yk: Vec<f64>,
    yv: Vec<f64>,
    /// Scratch: `P_xx A`, `G = P_xx B + P_xv`, `w = P [e; 0] + p`.
    pa: Vec<f64>,
    g: Vec<f64>,
    w: Vec<f64>,

    pub(crate) info: RiccatiInfo,
}

/// Rows of one step's input bounds (and rate limits).
fn rows_per_step(rate_limited: bool) -> usize {
    if rate_limited { 4 * NU } else { 2 * NU }
}

impl RiccatiQp {
    /// The solver for a horizon `n` over `m` kept states, with soft bounds at `soft_steps` on
    /// the kept components at positions `soft`.
    pub(crate) fn new(n: usize, m: usize, rate_limited: bool, soft_steps: &[usize], soft: &[usize]) -> Self {
        let ns = soft.len();
        let nb = soft_steps.len() * ns;
        let rows = n * rows_per_step(rate_limited) + 3 * nb;
        let v = |len: usize| vec![0.0; len];
        let xi = m + NU;
        Self {
            n,
            m,
            a: v(n * m * m),
            b: v(n * m * NU),
            d: v(m),
            wx: v(n * m),
            qx: v(n * m),
            ru: [0.0; NU],
            rd: [0.0; NU],
            qu: v(n * NU),
            u_hi: v(n * NU),
            u_lo: v(n * NU),
            rate_limited,
            r_hi: v(if rate_limited { n * NU } else { 0 }),
            r_lo: v(if rate_limited { n * NU } else { 0 }),
            soft_steps: soft_steps.to_vec(),
            soft: soft.to_vec(),
            h_hi: v(nb),
            h_lo: v(nb),
            slack_linear: 0.0,
            slack_quad: 0.0,
            x: v((n + 1) * m),
            u: v(n * NU),
            s: v(nb),
            pi: v((n + 1) * m),
            lam: v(rows),
            t: v(rows),
            r_dyn: v(n * m),
            r_row: v(rows),
            gx: v((n + 1) * m),
            gu: v(n * NU),
            gs: v(nb),
            r_mu: v(rows),
            rho: v(rows),
            dx: v((n + 1) * m),
            du: v(n * NU),
            ds: v(nb),
            dlam: v(rows),
            dt: v(rows),
            pi_new: v((n + 1) * m),
            dlam_aff: v(rows),
            dt_aff: v(rows),
            qxx: v((n + 1) * m),
            rdiag: v(n * NU),
            qvv: v(n * NU),
            svu: v(n * NU),
            hss: v(nb),
            hxs: v(nb),
            pxx: v((n + 1) * m * m),
            pxv: v((n + 1) * m * NU),
            pvv: v((n + 1) * NU * NU),
            px: v((n + 1) * m),
            pv: v((n + 1) * NU),
            chol: v(n * NU * NU),
            yk: v(n * NU * xi),
            yv: v(n * NU),
            pa: v(m * m),
            g: v(m * NU),
            w: v(m + NU),
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

    /// Solves the QP from the data written into the public fields, from a cold start (the
    /// nominal plan, unit multipliers). The solution is in `x`, `u` whatever the status; it is
    /// the optimum only when the status is `Solved`.
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
            let rows = self.rows() as f64;
            let mu_aff = (0..self.rows())
                .map(|i| (self.lam[i] + alpha_aff * self.dlam[i]) * (self.t[i] + alpha_aff * self.dt[i]))
                .sum::<f64>()
                / rows;
            let sigma = (mu_aff / mu).clamp(0.0, 1.0).powi(3);
            // Corrector: centred, with the affine step's second-order term.
            self.dlam_aff.copy_from_slice(&self.dlam);
            self.dt_aff.copy_from_slice(&self.dt);
            // Where the affine step was blocked early its second-order term is not a correction
            // but a different direction: the iterates then cycle between badly centred points
            // (seen on rate-limited cycles). Damp it by the step the affine direction could take.
            let second = alpha_aff.min(1.0);
            for i in 0..self.rows() {
                self.r_mu[i] = self.lam[i] * self.t[i] + second * self.dlam_aff[i] * self.dt_aff[i] - sigma * mu;
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
        let bounds = self.u_hi.iter().chain(&self.u_lo).chain(&self.r_hi).chain(&self.r_lo);
        bounds.chain(&self.h_hi).chain(&self.h_lo).chain(&self.d).fold(0.0, |a: f64, v| a.max(v.abs()))
    }

    /// Largest magnitude among the linear costs and the slack price.
    fn dual_scale(&self) -> f64 {
        let costs = self.qx.iter().chain(&self.qu).fold(0.0, |a: f64, v| a.max(v.abs()));
        costs.max(if self.s.is_empty() { 0.0 } else { self.slack_linear.abs() })
    }

    /// The nominal plan (zero deviations), slacks covering the soft bounds, and every row's
    /// slack at least 1 with a unit multiplier.
    fn initialise(&mut self) {
        self.x.fill(0.0);
        self.u.fill(0.0);
        self.pi.fill(0.0);
        for (i, s) in self.s.iter_mut().enumerate() {
            *s = (-self.h_hi[i]).max(-self.h_lo[i]).max(0.0) + 1.0;
        }
        self.lam.fill(1.0);
        self.row_values();
        for i in 0..self.rows() {
            // r_row holds C z - e here (no t yet).
            self.t[i] = (-self.r_row[i]).max(1.0);
        }
    }

    /// `r_row = C z - e` for every row (without `t`).
    fn row_values(&mut self) {
        let per = rows_per_step(self.rate_limited);
        for k in 0..self.n {
            let base = k * per;
            for j in 0..NU {
                let u = self.u[k * NU + j];
                self.r_row[base + j] = u - self.u_hi[k * NU + j];
                self.r_row[base + NU + j] = -u - self.u_lo[k * NU + j];
                if self.rate_limited {
                    let prev = if k > 0 { self.u[(k - 1) * NU + j] } else { 0.0 };
                    self.r_row[base + 2 * NU + j] = u - prev - self.r_hi[k * NU + j];
                    self.r_row[base + 3 * NU + j] = prev - u - self.r_lo[k * NU + j];
                }
            }
        }
        let (ns, base, m) = (self.soft.len(), self.soft_base(), self.m);
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                let (xc, s) = (self.x[k * m + c], self.s[b]);
                self.r_row[base + 3 * b] = xc - s - self.h_hi[b];
                self.r_row[base + 3 * b + 1] = -xc - s - self.h_lo[b];
                self.r_row[base + 3 * b + 2] = -s;
            }
        }
    }

    /// Every residual at the current iterate; returns the largest primal and dual residual and
    /// the mean complementarity.
    fn residuals(&mut self) -> (f64, f64, f64) {
        let (n, m) = (self.n, self.m);
        self.row_values();
        let mut primal = 0.0f64;
        for i in 0..self.rows() {
            self.r_row[i] += self.t[i];
            primal = primal.max(self.r_row[i].abs());
        }
        for k in 0..n {
            let (a, b) = (&self.a[k * m * m..(k + 1) * m * m], &self.b[k * m * NU..(k + 1) * m * NU]);
            let r = &mut self.r_dyn[k * m..(k + 1) * m];
            for i in 0..m {
                r[i] = self.d[i] - self.x[(k + 1) * m + i];
            }
            mat_vec_add(r, a, &self.x[k * m..(k + 1) * m], m);
            mat_vec_add(r, b, &self.u[k * NU..(k + 1) * NU], m);
            primal = primal.max(r.iter().fold(0.0, |acc: f64, v| acc.max(v.abs())));
        }
        // Gradients of the cost plus C' lam.
        for k in 1..=n {
            for i in 0..m {
                let at = (k - 1) * m + i;
                self.gx[k * m + i] = self.wx[at] * self.x[k * m + i] + self.qx[at];
            }
        }
        let per = rows_per_step(self.rate_limited);
        for k in 0..n {
            for j in 0..NU {
                let at = k * NU + j;
                let u = self.u[at];
                let prev = if k > 0 { self.u[at - NU] } else { 0.0 };
                let mut g = self.ru[j] * u + self.qu[at] + self.rd[j] * (u - prev);
                if k + 1 < n {
                    g -= self.rd[j] * (self.u[at + NU] - u);
                }
                let base = k * per;
                g += self.lam[base + j] - self.lam[base + NU + j];
                if self.rate_limited {
                    g += self.lam[base + 2 * NU + j] - self.lam[base + 3 * NU + j];
                    if k + 1 < n {
                        g -= self.lam[base + per + 2 * NU + j] - self.lam[base + per + 3 * NU + j];
                    }
                }
                self.gu[at] = g;
            }
        }
        let (ns, base) = (self.soft.len(), self.soft_base());
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                let (l1, l2, l3) = (self.lam[base + 3 * b], self.lam[base + 3 * b + 1], self.lam[base + 3 * b + 2]);
                self.gx[k * m + c] += l1 - l2;
                self.gs[b] = self.slack_quad * self.s[b] + self.slack_linear - l1 - l2 - l3;
            }
        }
        // The dual residual adds the dynamics' multipliers: pi_k - A_k' pi_{k+1}, -B_k' pi_{k+1}.
        let mut dual = self.gs.iter().fold(0.0f64, |acc, v| acc.max(v.abs()));
        for k in 0..n {
            let next = &self.pi[(k + 1) * m..(k + 2) * m];
            let (a, b) = (&self.a[k * m * m..(k + 1) * m * m], &self.b[k * m * NU..(k + 1) * m * NU]);
            for j in 0..NU {
                let col = &b[j * m..(j + 1) * m];
                let bt_pi: f64 = (0..m).map(|i| col[i] * next[i]).sum();
                dual = dual.max((self.gu[k * NU + j] - bt_pi).abs());
            }
            if k > 0 {
                for c in 0..m {
                    let col = &a[c * m..(c + 1) * m];
                    let at_pi: f64 = (0..m).map(|i| col[i] * next[i]).sum();
                    dual = dual.max((self.gx[k * m + c] + self.pi[k * m + c] - at_pi).abs());
                }
            }
        }
        for c in 0..m {
            dual = dual.max((self.gx[n * m + c] + self.pi[n * m + c]).abs());
        }
        let gap: f64 = self.lam.iter().zip(&self.t).map(|(l, t)| l * t).sum();
        (primal, dual, gap / self.rows().max(1) as f64)
    }

    /// The stage Hessians with the barrier's terms, the slacks eliminated, and the matrix
    /// half of the Riccati recursion. `false` when a stage's `R~` is not positive definite.
    fn factor(&mut self) -> bool {
        let (n, m) = (self.n, self.m);
        let per = rows_per_step(self.rate_limited);
        let sigma = |s: &Self, row: usize| s.lam[row] / s.t[row];
        for k in 0..=n {
            for i in 0..m {
                self.qxx[k * m + i] = if k > 0 { self.wx[(k - 1) * m + i] } else { 0.0 };
            }
        }
        for k in 0..n {
            let base = k * per;
            for j in 0..NU {
                let at = k * NU + j;
                let mut r = self.ru[j] + self.rd[j] + sigma(self, base + j) + sigma(self, base + NU + j);
                let (mut vv, mut vu) = (if k > 0 { self.rd[j] } else { 0.0 }, -self.rd[j]);
                if self.rate_limited {
                    let s = sigma(self, base + 2 * NU + j) + sigma(self, base + 3 * NU + j);
                    r += s;
                    vv += s;
                    vu -= s;
                }
                self.rdiag[at] = r;
                self.qvv[at] = vv;
                self.svu[at] = if k > 0 { vu } else { 0.0 };
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
                self.qxx[k * m + c] += s1 + s2 - hxs * hxs / hss;
            }
        }

        // P_N: the terminal state's weight; the last input is free of a successor.
        let xi = m + NU;
        self.pxx[n * m * m..].fill(0.0);
        for i in 0..m {
            self.pxx[n * m * m + i * m + i] = self.qxx[n * m + i];
        }
        self.pxv[n * m * NU..].fill(0.0);
        self.pvv[n * NU * NU..].fill(0.0);
        for k in (0..n).rev() {
            let (a, b) = (&self.a[k * m * m..(k + 1) * m * m], &self.b[k * m * NU..(k + 1) * m * NU]);
            let (next_xx, next_xv, next_vv) = (
                &self.pxx[(k + 1) * m * m..(k + 2) * m * m],
                &self.pxv[(k + 1) * m * NU..(k + 2) * m * NU],
                &self.pvv[(k + 1) * NU * NU..(k + 2) * NU * NU],
            );
            // G = P_xx B + P_xv; R~ = R + B' G + P_xv' B + P_vv.
            mat_mul(&mut self.g, next_xx, b, m, m, NU);
            for (g, p) in self.g.iter_mut().zip(next_xv) {
                *g += p;
            }
            let l = &mut self.chol[k * NU * NU..(k + 1) * NU * NU];
            for c in 0..NU {
                for r in c..NU {
                    let bg: f64 = (0..m).map(|i| b[r * m + i] * self.g[c * m + i]).sum();
                    let pb: f64 = (0..m).map(|i| next_xv[r * m + i] * b[c * m + i]).sum();
                    l[c * NU + r] = bg + pb + next_vv[c * NU + r];
                }
                l[c * NU + c] += self.rdiag[k * NU + c];
            }
            if !cholesky4(l) {
                return false;
            }
            if k == 0 {
                break;
            }
            // S~ = [G' A, diag(svu)]; Y = L^-1 S~ (4 x (m + 4), column-major).
            let y = &mut self.yk[k * NU * xi..(k + 1) * NU * xi];
            for c in 0..m {
                for r in 0..NU {
                    y[c * NU + r] = (0..m).map(|i| self.g[r * m + i] * a[c * m + i]).sum();
                }
            }
            y[m * NU..].fill(0.0);
            for j in 0..NU {
                y[(m + j) * NU + j] = self.svu[k * NU + j];
            }
            for c in 0..xi {
                forward_sub4(l, &mut y[c * NU..(c + 1) * NU]);
            }
            // P_xx = Q_xx + A' P_xx+ A - Yx' Yx; P_xv = -Yx' Yv; P_vv = Q_vv - Yv' Yv.
            mat_mul(&mut self.pa, next_xx, a, m, m, m);
            let pxx = &mut self.pxx[k * m * m..(k + 1) * m * m];
            for c in 0..m {
                for r in c..m {
                    let apa: f64 = (0..m).map(|i| a[r * m + i] * self.pa[c * m + i]).sum();
                    let yy: f64 = (0..NU).map(|i| y[r * NU + i] * y[c * NU + i]).sum();
                    let v = apa - yy + if r == c { self.qxx[k * m + r] } else { 0.0 };
                    pxx[c * m + r] = v;
                    pxx[r * m + c] = v;
                }
            }
            let pxv = &mut self.pxv[k * m * NU..(k + 1) * m * NU];
            for c in 0..NU {
                for r in 0..m {
                    pxv[c * m + r] = -(0..NU).map(|i| y[r * NU + i] * y[(m + c) * NU + i]).sum::<f64>();
                }
            }
            let pvv = &mut self.pvv[k * NU * NU..(k + 1) * NU * NU];
            for c in 0..NU {
                for r in 0..NU {
                    let yy: f64 = (0..NU).map(|i| y[(m + r) * NU + i] * y[(m + c) * NU + i]).sum();
                    pvv[c * NU + r] = -yy + if r == c { self.qvv[k * NU + r] } else { 0.0 };
                }
            }
        }
        true
    }

    /// One Newton direction for the complementarity right-hand side in `r_mu`, from the
    /// factors of [`Self::factor`]: the vector half of the recursion, the forward pass, then
    /// the slacks', rows' and multipliers' directions.
    fn newton(&mut self) {
        let (n, m) = (self.n, self.m);
        let per = rows_per_step(self.rate_limited);
        for i in 0..self.rows() {
            self.rho[i] = (self.lam[i] * self.r_row[i] - self.r_mu[i]) / self.t[i];
        }
        // Linear costs of the reduced system: the gradients plus C' rho, slacks eliminated.
        // du's costs are in `du`, the soft slacks' in `ds`, x's in `px` before the recursion.
        for k in 0..n {
            let base = k * per;
            for j in 0..NU {
                let at = k * NU + j;
                let mut g = self.gu[at] + self.rho[base + j] - self.rho[base + NU + j];
                if self.rate_limited {
                    g += self.rho[base + 2 * NU + j] - self.rho[base + 3 * NU + j];
                    if k + 1 < n {
                        g -= self.rho[base + per + 2 * NU + j] - self.rho[base + per + 3 * NU + j];
                    }
                }
                self.du[at] = g;
            }
        }
        self.dx.copy_from_slice(&self.gx);
        let (ns, sbase) = (self.soft.len(), self.soft_base());
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                let (r1, r2, r3) = (self.rho[sbase + 3 * b], self.rho[sbase + 3 * b + 1], self.rho[sbase + 3 * b + 2]);
                let ls = self.gs[b] - r1 - r2 - r3;
                self.ds[b] = ls;
                self.dx[k * m + c] += r1 - r2 - self.hxs[b] * ls / self.hss[b];
            }
        }
        // Backward: p_N = lx_N; p_k = q~ - Y' y with y = L^-1 r~.
        self.px[n * m..].copy_from_slice(&self.dx[n * m..]);
        self.pv[n * NU..].fill(0.0);
        let xi = m + NU;
        for k in (0..n).rev() {
            let (a, b) = (&self.a[k * m * m..(k + 1) * m * m], &self.b[k * m * NU..(k + 1) * m * NU]);
            let e = &self.r_dyn[k * m..(k + 1) * m];
            // w = P_{k+1} [e; 0] + p_{k+1}.
            let (pxx, pxv) =
                (&self.pxx[(k + 1) * m * m..(k + 2) * m * m], &self.pxv[(k + 1) * m * NU..(k + 2) * m * NU]);
            let (wx, wv) = self.w.split_at_mut(m);
            wx.copy_from_slice(&self.px[(k + 1) * m..(k + 2) * m]);
            mat_vec_add(wx, pxx, e, m);
            for j in 0..NU {
                wv[j] = self.pv[(k + 1) * NU + j] + (0..m).map(|i| pxv[j * m + i] * e[i]).sum::<f64>();
            }
            let y = &mut self.yv[k * NU..(k + 1) * NU];
            for j in 0..NU {
                y[j] = self.du[k * NU + j] + wv[j] + (0..m).map(|i| b[j * m + i] * wx[i]).sum::<f64>();
            }
            forward_sub4(&self.chol[k * NU * NU..(k + 1) * NU * NU], y);
            if k == 0 {
                break;
            }
            let yk = &self.yk[k * NU * xi..(k + 1) * NU * xi];
            for c in 0..m {
                let at: f64 = (0..m).map(|i| a[c * m + i] * wx[i]).sum();
                let yy: f64 = (0..NU).map(|i| yk[c * NU + i] * y[i]).sum();
                self.px[k * m + c] = self.dx[k * m + c] + at - yy;
            }
            for j in 0..NU {
                self.pv[k * NU + j] = -(0..NU).map(|i| yk[(m + j) * NU + i] * y[i]).sum::<f64>();
            }
        }
        // Forward: du_k = -L^-T (Y xi_k + y_k); x_{k+1} = A x_k + B du_k + e_k; pi+ = -(P xi + p).
        self.dx[..m].fill(0.0);
        for k in 0..n {
            let l = &self.chol[k * NU * NU..(k + 1) * NU * NU];
            let mut v = [0.0; NU];
            v.copy_from_slice(&self.yv[k * NU..(k + 1) * NU]);
            if k > 0 {
                let yk = &self.yk[k * NU * xi..(k + 1) * NU * xi];
                for c in 0..m {
                    let d = self.dx[k * m + c];
                    for r in 0..NU {
                        v[r] += yk[c * NU + r] * d;
                    }
                }
                for c in 0..NU {
                    let d = self.du[(k - 1) * NU + c];
                    for r in 0..NU {
                        v[r] += yk[(m + c) * NU + r] * d;
                    }
                }
            }
            backward_sub4(l, &mut v);
            for j in 0..NU {
                self.du[k * NU + j] = -v[j];
            }
            let (a, b) = (&self.a[k * m * m..(k + 1) * m * m], &self.b[k * m * NU..(k + 1) * m * NU]);
            let (done, next) = self.dx.split_at_mut((k + 1) * m);
            let next = &mut next[..m];
            next.copy_from_slice(&self.r_dyn[k * m..(k + 1) * m]);
            mat_vec_add(next, a, &done[k * m..], m);
            mat_vec_add(next, b, &self.du[k * NU..(k + 1) * NU], m);
            let (pxx, pxv) =
                (&self.pxx[(k + 1) * m * m..(k + 2) * m * m], &self.pxv[(k + 1) * m * NU..(k + 2) * m * NU]);
            let pi = &mut self.pi_new[(k + 1) * m..(k + 2) * m];
            for i in 0..m {
                pi[i] = -self.px[(k + 1) * m + i];
            }
            for c in 0..m {
                let d = next[c];
                for r in 0..m {
                    pi[r] -= pxx[c * m + r] * d;
                }
            }
            for c in 0..NU {
                let d = self.du[k * NU + c];
                for r in 0..m {
                    pi[r] -= pxv[c * m + r] * d;
                }
            }
        }
        // The slacks, then every row's slack and multiplier direction.
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                self.ds[b] = -(self.ds[b] + self.hxs[b] * self.dx[k * m + c]) / self.hss[b];
            }
        }
        for k in 0..n {
            let base = k * per;
            for j in 0..NU {
                let du = self.du[k * NU + j];
                self.dt[base + j] = -du;
                self.dt[base + NU + j] = du;
                if self.rate_limited {
                    let prev = if k > 0 { self.du[(k - 1) * NU + j] } else { 0.0 };
                    self.dt[base + 2 * NU + j] = prev - du;
                    self.dt[base + 3 * NU + j] = du - prev;
                }
            }
        }
        for (j, &k) in self.soft_steps.iter().enumerate() {
            for (i, &c) in self.soft.iter().enumerate() {
                let b = j * ns + i;
                let (dxc, ds) = (self.dx[k * m + c], self.ds[b]);
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
        let (n, m) = (self.n, self.m);
        let mut f = 0.0;
        for k in 1..=n {
            for i in 0..m {
                let (at, x) = ((k - 1) * m + i, self.x[k * m + i]);
                f += 0.5 * self.wx[at] * x * x + self.qx[at] * x;
            }
        }
        for k in 0..n {
            for j in 0..NU {
                let at = k * NU + j;
                let (u, prev) = (self.u[at], if k > 0 { self.u[at - NU] } else { 0.0 });
                f += 0.5 * self.ru[j] * u * u + self.qu[at] * u + 0.5 * self.rd[j] * (u - prev) * (u - prev);
            }
        }
        f + self.s.iter().map(|s| self.slack_linear * s + 0.5 * self.slack_quad * s * s).sum::<f64>()
    }

    /// The slack of soft bound `i` at `soft_steps[j]` (for tests and reports).
    #[cfg(test)]
    pub(crate) fn slack(&self, j: usize, i: usize) -> f64 {
        self.s[j * self.soft.len() + i]
    }
}

/// `y += M v` for an `m x cols` column-major `M` (`cols = v.len()`).
#[inline]
fn mat_vec_add(y: &mut [f64], mat: &[f64], v: &[f64], m: usize) {
    for (c, &vc) in v.iter().enumerate() {
        let col = &mat[c * m..(c + 1) * m];
        for r in 0..m {
            y[r] += col[r] * vc;
        }
    }
}

/// `out = L R` for column-major `L` (`rows x inner`) and `R` (`inner x cols`).
#[inline]
fn mat_mul(out: &mut [f64], l: &[f64], r: &[f64], rows: usize, inner: usize, cols: usize) {
    for c in 0..cols {
        let o = &mut out[c * rows..(c + 1) * rows];
        o.fill(0.0);
        for i in 0..inner {
            let v = r[c * inner + i];
            let col = &l[i * rows..(i + 1) * rows];
            for (oo, &lv) in o.iter_mut().zip(col) {
                *oo += lv * v;
            }
        }
    }
}

/// In-place Cholesky factor (lower triangle, column-major) of a 4 x 4 matrix given by its
/// lower triangle; `false` unless positive definite.
fn cholesky4(l: &mut [f64]) -> bool {
    for c in 0..NU {
        let mut d = l[c * NU + c];
        for i in 0..c {
            d -= l[i * NU + c] * l[i * NU + c];
        }
        if !(d > 0.0 && d.is_finite()) {
            return false;
        }
        let d = d.sqrt();
        l[c * NU + c] = d;
        for r in c + 1..NU {
            let mut v = l[c * NU + r];
            for i in 0..c {
                v -= l[i * NU + r] * l[i * NU + c];
            }
            l[c * NU + r] = v / d;
        }
    }
    true
}

/// `v <- L^-1 v` for the lower-triangular factor of [`cholesky4`].
#[inline]
fn forward_sub4(l: &[f64], v: &mut [f64]) {
    for r in 0..NU {
        let mut s = v[r];
        for i in 0..r {
            s -= l[i * NU + r] * v[i];
        }
        v[r] = s / l[r * NU + r];
    }
}

/// `v <- L^-T v`.
#[inline]
fn backward_sub4(l: &[f64], v: &mut [f64]) {
    for r in (0..NU).rev() {
        let mut s = v[r];
        for i in r + 1..NU {
            s -= l[r * NU + i] * v[i];
        }
        v[r] = s / l[r * NU + r];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mpc::qp::{ALL_STATES, Qp, WITHOUT_POSITION, Weights, soft_steps};
    use crate::types::{InputMatrix, StateMatrix};
    use clarabel::algebra::CscMatrix;
    use clarabel::solver::{DefaultSettingsBuilder, DefaultSolver, IPSolver, SupportedConeT};
    use nalgebra::{DMatrix, DVector};

    /// A deterministic value in [-1, 1) from three integers.
    fn hash(a: usize, b: usize, c: usize) -> f64 {
        let x = (a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ (c as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
        let x = (x ^ (x >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        ((x >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

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
        fn riccati(&self) -> RiccatiQp {
            let (n, m) = (self.n, self.states.len());
            let mut qp = RiccatiQp::new(n, m, self.rate.is_some(), &soft_steps(n), &self.soft);
            crate::mpc::controller::write_stages(&mut qp, &self.states, &self.a, &self.b);
            for k in 1..=n {
                let f = if k == n { self.w.terminal } else { 1.0 };
                for (s, &i) in self.states.iter().enumerate() {
                    qp.wx[(k - 1) * m + s] = 2.0 * f * self.w.state[i];
                }
            }
            qp.qx.copy_from_slice(&self.state_q);
            qp.qu.copy_from_slice(&self.input_q);
            qp.d.copy_from_slice(&self.d);
            for j in 0..NU {
                qp.ru[j] = 2.0 * self.w.input[j];
                qp.rd[j] = 2.0 * self.w.input_rate[j];
            }
            qp.u_hi.fill(self.bound);
            qp.u_lo.fill(0.75 * self.bound);
            if let Some(r) = self.rate {
                qp.r_hi.fill(r);
                qp.r_lo.fill(r);
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
            let cones = [SupportedConeT::ZeroConeT(qp.n_eq), SupportedConeT::NonnegativeConeT(qp.b.len() - qp.n_eq)];
            let settings = DefaultSettingsBuilder::default()
                .verbose(false)
                .presolve_enable(false)
                .tol_gap_abs(1e-11)
                .tol_gap_rel(1e-11)
                .tol_feas(1e-11)
                .build()
                .unwrap();
            let p = CscMatrix::new(qp.p.m, qp.p.n, qp.p.colptr.clone(), qp.p.rowval.clone(), qp.p_values.clone());
            let am = CscMatrix::new(qp.a.m, qp.a.n, qp.a.colptr.clone(), qp.a.rowval.clone(), qp.a_values.clone());
            let mut solver = DefaultSolver::new(&p, &qp.q, &am, &qp.b, &cones, settings).unwrap();
            solver.solve();
            assert_eq!(solver.solution.status, SolverStatus::Solved);
            (0..n)
                .flat_map(|k| (0..NU).map(move |j| (k, j)))
                .map(|(k, j)| solver.solution.x[qp.u_index(k, j)])
                .collect()
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

    #[test]
    fn unconstrained_solution_equals_the_dense_kkt_solve() {
        for (seed, states) in [(1, &WITHOUT_POSITION[..]), (2, &ALL_STATES[..])] {
            let mut case = Case::new(seed, 9, states, &[], None, 1e6);
            case.soft_width = 1e6;
            let mut qp = case.riccati();
            assert_eq!(qp.solve(limits(1e-12)), SolverStatus::Solved);
            let (du, dx) = case.dense_kkt();
            let m = states.len();
            assert!(worst(&qp.u, &du) < 1e-8, "inputs differ by {:e}", worst(&qp.u, &du));
            assert!(worst(&qp.x[m..], &dx) < 1e-8, "states differ by {:e}", worst(&qp.x[m..], &dx));
            assert!(du.iter().any(|v| v.abs() > 0.05), "the problem moves the inputs");
        }
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
            let mut qp = case.riccati();
            assert_eq!(qp.solve(limits(1e-10)), SolverStatus::Solved, "seed {seed}");
            let du = case.clarabel();
            assert!(worst(&qp.u, &du) < 1e-6, "seed {seed}: inputs differ from Clarabel's by {:e}", worst(&qp.u, &du));
            active += qp.u.iter().filter(|&&u| u >= 0.4 - 1e-6 || u <= -0.3 + 1e-6).count();
            active += (0..qp.soft_steps.len()).filter(|&j| (0..qp.soft.len()).any(|i| qp.slack(j, i) > 1e-6)).count();
        }
        assert!(active > 20, "the cases bind their bounds ({active} active)");
    }

    #[test]
    fn a_non_finite_model_ends_in_a_status_not_a_nan() {
        let case = Case::new(5, 6, &WITHOUT_POSITION, &[3], None, 0.4);
        let mut qp = case.riccati();
        qp.a[10] = f64::NAN;
        let status = qp.solve(limits(1e-8));
        assert_eq!(status, SolverStatus::NumericalError);
    }

    #[test]
    fn empty_input_bounds_do_not_end_solved() {
        let case = Case::new(6, 6, &WITHOUT_POSITION, &[], Some(0.1), 0.4);
        let mut qp = case.riccati();
        qp.u_hi[5] = -1.0;
        qp.u_lo[5] = -1.0; // u <= -1 and u >= 1
        let status = qp.solve(limits(1e-8));
        assert!(status != SolverStatus::Solved, "{status:?}");
    }
}
