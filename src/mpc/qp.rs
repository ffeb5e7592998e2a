//! The sparse QP of one real-time iteration, in deviations from the nominal rollout:
//! `z = [dx_1 .. dx_N, du_0 .. du_{N-1}]`, `x_k = xbar_k + dx_k`, `u_k = ubar_k + du_k`
//! (`dx_0 = 0`: the rollout starts at the measured state).
//!
//! `dx_k` holds the kept state components only. The cost never weighs the horizontal
//! position, so a model whose dynamics do not depend on it (the analytic vehicle, a
//! position-free PINC) leaves `x, y` out: 7 states instead of 9, a KKT system a sixth
//! smaller and a factorisation about 1.6x faster, with the same solution.
//!
//! Clarabel's form is `min 1/2 z'Pz + q'z  s.t.  Az + s = b, s in K`. Rows of `A`:
//! - `mN` equalities `dx_{k+1} - A_k dx_k - B_k du_k = 0` for `m` kept states (the nominal
//!   rollout has no defect);
//! - `8N` input bounds `u_min <= ubar_k + du_k <= u_max`;
//! - with rate limits, `8N` more: `|u_k - u_{k-1}| <= rate` (`u_{-1}`: the applied input);
//! - with soft state bounds on `b` components, checked at every [`SOFT_STRIDE`]-th step and
//!   the last (`K` steps), `3bK` more: `lo <= xbar_k + dx_k + s_k`, `xbar_k + dx_k - s_k <=
//!   hi`, `s_k >= 0`, one slack per bound and step, after the inputs in `z`, priced by an
//!   exact (linear) penalty in `q` plus a small quadratic one in `P`. Velocities change
//!   slowly over a step, so bounds at every 4th step cost a quarter of the rows; one slack per
//!   step (not one for the whole horizon) keeps the KKT system free of dense columns.
//!
//! The equality rows' right-hand side is the disturbance estimate, the same at every step
//! (zero without one: the nominal rollout itself has no defect).
//!
//! The sparsity pattern of `A` holds every entry of every `A_k` and `B_k`, zeros included,
//! so each sample only overwrites values (`update_A`); `P` never changes.

use crate::types::{InputMatrix, NU, NX, StateMatrix};

/// All nine state components.
pub(crate) const ALL_STATES: [usize; NX] = [0, 1, 2, 3, 4, 5, 6, 7, 8];
/// Everything but the horizontal position `x, y`.
pub(crate) const WITHOUT_POSITION: [usize; NX - 2] = [2, 3, 4, 5, 6, 7, 8];
use clarabel::algebra::CscMatrix;

/// Soft state bounds apply at every this many steps of the horizon (and at its end).
pub(crate) const SOFT_STRIDE: usize = 4;

/// The steps `k` of a horizon `n` with soft state bounds.
pub(crate) fn soft_steps(n: usize) -> Vec<usize> {
    let mut steps: Vec<usize> = (1..=n).filter(|k| k % SOFT_STRIDE == 0).collect();
    if steps.last() != Some(&n) {
        steps.push(n);
    }
    steps
}

/// Row of soft bound `i` of `ns` (see [`Qp::soft_row`]) in a block starting at `base`; `j`
/// indexes [`soft_steps`].
fn soft_row_of(base: usize, ns: usize, j: usize, i: usize, which: usize) -> usize {
    base + (j * ns + i) * 3 + which
}

/// Column-wise triplets, assembled into CSC with a record of where each entry landed.
struct CscBuilder {
    rows: usize,
    cols: Vec<Vec<(usize, f64)>>,
}

impl CscBuilder {
    fn new(rows: usize, cols: usize) -> Self {
        Self { rows, cols: vec![Vec::new(); cols] }
    }

    /// Adds an entry; rows within a column must come in increasing order.
    fn push(&mut self, row: usize, col: usize, value: f64) {
        debug_assert!(self.cols[col].last().is_none_or(|&(r, _)| r < row), "rows out of order");
        self.cols[col].push((row, value));
    }

    /// The position in `nzval` of the `i`-th entry pushed to `col`.
    fn offsets(&self) -> Vec<usize> {
        let mut start = vec![0; self.cols.len() + 1];
        for (c, entries) in self.cols.iter().enumerate() {
            start[c + 1] = start[c] + entries.len();
        }
        start
    }

    fn build(self) -> CscMatrix<f64> {
        let colptr = self.offsets();
        let (rowval, nzval) = self.cols.into_iter().flatten().unzip();
        CscMatrix::new(self.rows, colptr.len() - 1, colptr, rowval, nzval)
    }
}

/// Stage weights of the cost, all diagonal.
#[derive(Debug, Clone, PartialEq)]
pub struct Weights {
    /// State weights over the 9-state (the tracked components and the velocities).
    pub state: [f64; NX],
    /// Factor on the state weights at `k = N`.
    pub terminal: f64,
    /// Input weights.
    pub input: [f64; NU],
    /// Input-change weights.
    pub input_rate: [f64; NU],
}

/// The QP's fixed structure and its per-sample data.
pub(crate) struct Qp {
    pub(crate) horizon: usize,
    /// The 9-state components in the QP, in order (all nine, or `z ..` for a model whose
    /// dynamics do not depend on the horizontal position).
    pub(crate) states: Vec<usize>,
    pub(crate) p: CscMatrix<f64>,
    pub(crate) a: CscMatrix<f64>,
    /// Current values of `A`'s non-zeros (handed to `update_A`).
    pub(crate) a_values: Vec<f64>,
    pub(crate) q: Vec<f64>,
    pub(crate) b: Vec<f64>,
    /// `nzval` index of `A_k[(r, c)]` (positions in `states`), `k = 1..N-1`, at
    /// `((k - 1) * m + c) * m + r` for `m` kept states.
    idx_a: Vec<usize>,
    /// `nzval` index of `B_k[(r, j)]` at `(k * 4 + j) * m + r`.
    idx_b: Vec<usize>,
    pub(crate) n_eq: usize,
    /// Positions in `states` of the softly bounded components.
    pub(crate) soft: Vec<usize>,
    /// The steps with soft bounds ([`soft_steps`]).
    pub(crate) soft_steps: Vec<usize>,
    /// First row of the soft-bound block.
    soft_base: usize,
}

impl Qp {
    /// The structure for `horizon` steps over the 9-state components `states`, with soft
    /// bounds on the components at positions `soft` of `states` (slack weight `slack_quad` in
    /// `P`).
    pub(crate) fn new(
        horizon: usize,
        w: &Weights,
        rate_limited: bool,
        states: &[usize],
        soft: &[usize],
        slack_quad: f64,
    ) -> Self {
        let n = horizon;
        let m = states.len();
        let ns = soft.len();
        let col_x = |k: usize, s: usize| (k - 1) * m + s;
        let steps = soft_steps(n);
        let n_var = n * (m + NU) + ns * steps.len();
        let col_u = |k: usize, j: usize| n * m + k * NU + j;
        let col_s = |j: usize, i: usize| n * (m + NU) + j * ns + i;
        let n_eq = n * m;
        let soft_base = n_eq + 2 * NU * n + if rate_limited { 2 * NU * n } else { 0 };
        let soft_row = |j: usize, i: usize, which: usize| soft_row_of(soft_base, ns, j, i, which);
        let n_rows = soft_base + 3 * ns * steps.len();
        let bound_row = |k: usize, j: usize, upper: bool| n_eq + k * 2 * NU + j + if upper { 0 } else { NU };
        let rate_row =
            |k: usize, j: usize, upper: bool| n_eq + 2 * NU * n + k * 2 * NU + j + if upper { 0 } else { NU };

        let mut a = CscBuilder::new(n_rows, n_var);
        let mut a_slot = vec![(0usize, 0usize); 0];
        let mut b_slot = Vec::new();
        for k in 1..=n {
            for c in 0..m {
                a.push(m * (k - 1) + c, col_x(k, c), 1.0);
                if k < n {
                    for r in 0..m {
                        a_slot.push(((k - 1) * m * m + c * m + r, col_x(k, c)));
                        a.push(m * k + r, col_x(k, c), 0.0);
                    }
                }
                if let (Some(i), Some(j)) = (soft.iter().position(|&s| s == c), steps.iter().position(|&s| s == k)) {
                    a.push(soft_row(j, i, 0), col_x(k, c), 1.0);
                    a.push(soft_row(j, i, 1), col_x(k, c), -1.0);
                }
            }
        }
        for k in 0..n {
            for j in 0..NU {
                let c = col_u(k, j);
                for r in 0..m {
                    b_slot.push(((k * NU + j) * m + r, c));
                    a.push(m * k + r, c, 0.0);
                }
                a.push(bound_row(k, j, true), c, 1.0);
                a.push(bound_row(k, j, false), c, -1.0);
                if rate_limited {
                    a.push(rate_row(k, j, true), c, 1.0);
                    a.push(rate_row(k, j, false), c, -1.0);
                    if k + 1 < n {
                        a.push(rate_row(k + 1, j, true), c, -1.0);
                        a.push(rate_row(k + 1, j, false), c, 1.0);
                    }
                }
            }
        }
        for j in 0..steps.len() {
            for i in 0..ns {
                for which in 0..3 {
                    a.push(soft_row(j, i, which), col_s(j, i), -1.0);
                }
            }
        }
        // Where each A_k / B_k entry landed: the dynamics entries come right after the
        // identity entry in a state column, first in an input column.
        let start = a.offsets();
        let mut idx_a = vec![0; a_slot.len()];
        for (slot, col) in a_slot {
            idx_a[slot] = start[col] + 1 + slot % m;
        }
        let mut idx_b = vec![0; b_slot.len()];
        for (slot, col) in b_slot {
            idx_b[slot] = start[col] + slot % m;
        }
        let a = a.build();

        let mut p = CscBuilder::new(n_var, n_var);
        for k in 1..=n {
            let f = if k == n { w.terminal } else { 1.0 };
            for (s, &i) in states.iter().enumerate() {
                p.push(col_x(k, s), col_x(k, s), 2.0 * f * w.state[i]);
            }
        }
        for k in 0..n {
            for j in 0..NU {
                let c = col_u(k, j);
                let next = if k + 1 < n { 2.0 * w.input_rate[j] } else { 0.0 };
                if k > 0 {
                    p.push(col_u(k - 1, j), c, -2.0 * w.input_rate[j]);
                }
                p.push(c, c, 2.0 * w.input[j] + 2.0 * w.input_rate[j] + next);
            }
        }
        for j in 0..steps.len() {
            for i in 0..ns {
                p.push(col_s(j, i), col_s(j, i), 2.0 * slack_quad);
            }
        }
        let p = p.build();
        Self {
            horizon,
            states: states.to_vec(),
            a_values: a.nzval.clone(),
            q: vec![0.0; n_var],
            b: vec![0.0; n_rows],
            p,
            a,
            idx_a,
            idx_b,
            n_eq,
            soft: soft.to_vec(),
            soft_steps: steps,
            soft_base,
        }
    }

    /// Number of decision variables.
    #[cfg(test)]
    fn n_var(&self) -> usize {
        self.q.len()
    }

    /// Writes `-A_k` (k >= 1) and `-B_k`, restricted to the kept states, into the constraint values.
    pub(crate) fn set_dynamics(&mut self, a: &[StateMatrix], b: &[InputMatrix]) {
        let m = self.states.len();
        for k in 1..self.horizon {
            for (c, &ic) in self.states.iter().enumerate() {
                for (r, &ir) in self.states.iter().enumerate() {
                    self.a_values[self.idx_a[((k - 1) * m + c) * m + r]] = -a[k][(ir, ic)];
                }
            }
        }
        for k in 0..self.horizon {
            for j in 0..NU {
                for (r, &ir) in self.states.iter().enumerate() {
                    self.a_values[self.idx_b[(k * NU + j) * m + r]] = -b[k][(ir, j)];
                }
            }
        }
    }

    /// Index of `du_k[j]` in `z`.
    pub(crate) fn u_index(&self, k: usize, j: usize) -> usize {
        self.horizon * self.states.len() + k * NU + j
    }

    /// Index of `dx_k[states[s]]` in `z`, `k = 1..=N`.
    pub(crate) fn x_index(&self, k: usize, s: usize) -> usize {
        (k - 1) * self.states.len() + s
    }

    /// Row of the upper (`true`) or lower input bound of `u_k[j]`.
    pub(crate) fn bound_row(&self, k: usize, j: usize, upper: bool) -> usize {
        self.n_eq + k * 2 * NU + j + if upper { 0 } else { NU }
    }

    /// Index in `z` of the slack of soft bound `i` at step `soft_steps[j]`.
    pub(crate) fn slack_index(&self, j: usize, i: usize) -> usize {
        self.horizon * (self.states.len() + NU) + j * self.soft.len() + i
    }

    /// Row of soft bound `i` at step `soft_steps[j]`: the upper (`which = 0`) or lower (`1`)
    /// bound, or the slack's sign (`2`).
    pub(crate) fn soft_row(&self, j: usize, i: usize, which: usize) -> usize {
        soft_row_of(self.soft_base, self.soft.len(), j, i, which)
    }

    /// Row of the upper or lower rate bound of `u_k[j] - u_{k-1}[j]`.
    pub(crate) fn rate_row(&self, k: usize, j: usize, upper: bool) -> usize {
        self.n_eq + 2 * NU * self.horizon + k * 2 * NU + j + if upper { 0 } else { NU }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn weights() -> Weights {
        Weights {
            state: [0.0, 0.0, 5.0, 2.0, 2.0, 0.1, 0.1, 0.1, 0.1],
            terminal: 3.0,
            input: [0.01; 4],
            input_rate: [0.1; 4],
        }
    }

    /// Dense `A` from the CSC values, to compare with the block structure.
    fn dense(m: &CscMatrix<f64>, values: &[f64]) -> Vec<Vec<f64>> {
        let mut d = vec![vec![0.0; m.n]; m.m];
        for c in 0..m.n {
            for i in m.colptr[c]..m.colptr[c + 1] {
                d[m.rowval[i]][c] = values[i];
            }
        }
        d
    }

    #[test]
    fn dynamics_blocks_land_where_the_equalities_need_them() {
        let n = 3;
        for states in [&ALL_STATES[..], &WITHOUT_POSITION[..]] {
            let m = states.len();
            let mut qp = Qp::new(n, &weights(), true, states, &[], 0.0);
            let a: Vec<StateMatrix> =
                (0..n).map(|k| StateMatrix::from_fn(|r, c| (100 * k + 10 * r + c) as f64 + 0.5)).collect();
            let b: Vec<InputMatrix> =
                (0..n).map(|k| InputMatrix::from_fn(|r, j| -((100 * k + 10 * r + j) as f64) - 0.25)).collect();
            qp.set_dynamics(&a, &b);
            let d = dense(&qp.a, &qp.a_values);
            for k in 0..n {
                for (r, &ir) in states.iter().enumerate() {
                    let row = m * k + r;
                    for (c, &ic) in states.iter().enumerate() {
                        assert_eq!(d[row][qp.x_index(k + 1, c)], if r == c { 1.0 } else { 0.0 });
                        if k >= 1 {
                            assert_eq!(d[row][qp.x_index(k, c)], -a[k][(ir, ic)]);
                        }
                    }
                    for j in 0..NU {
                        assert_eq!(d[row][qp.u_index(k, j)], -b[k][(ir, j)]);
                    }
                }
                for j in 0..NU {
                    assert_eq!(d[qp.bound_row(k, j, true)][qp.u_index(k, j)], 1.0);
                    assert_eq!(d[qp.bound_row(k, j, false)][qp.u_index(k, j)], -1.0);
                    assert_eq!(d[qp.rate_row(k, j, true)][qp.u_index(k, j)], 1.0);
                    if k > 0 {
                        assert_eq!(d[qp.rate_row(k, j, true)][qp.u_index(k - 1, j)], -1.0);
                    }
                }
            }
            // Every A_k and B_k entry has a slot, zeros included: the pattern never changes.
            assert_eq!(qp.a.nzval.len(), n * m + (n - 1) * m * m + n * NU * m + (3 * n - 1) * NU * 2);
            qp.a.check_format().unwrap();
            qp.p.check_format().unwrap();
        }
    }

    #[test]
    fn soft_bounds_tie_each_bounded_state_to_its_own_slack_at_every_fourth_step() {
        let n = 10;
        let soft = [3usize, 5]; // positions in WITHOUT_POSITION: u and w
        let qp = Qp::new(n, &weights(), false, &WITHOUT_POSITION, &soft, 7.0);
        assert_eq!(qp.soft_steps, [4, 8, 10]);
        let d = dense(&qp.a, &qp.a.nzval);
        let p = dense(&qp.p, &qp.p.nzval);
        for (j, &k) in qp.soft_steps.iter().enumerate() {
            for (i, &s) in soft.iter().enumerate() {
                let (up, lo, sign) = (qp.soft_row(j, i, 0), qp.soft_row(j, i, 1), qp.soft_row(j, i, 2));
                let slack = qp.slack_index(j, i);
                let nonzero = |row: usize| (0..qp.n_var()).filter(|&c| d[row][c] != 0.0).collect::<Vec<_>>();
                assert_eq!(nonzero(up), [qp.x_index(k, s), slack]);
                assert_eq!((d[up][qp.x_index(k, s)], d[up][slack]), (1.0, -1.0));
                assert_eq!((d[lo][qp.x_index(k, s)], d[lo][slack]), (-1.0, -1.0));
                assert_eq!(nonzero(sign), [slack]);
                assert_eq!(p[slack][slack], 14.0);
            }
        }
        assert_eq!(qp.b.len(), qp.n_eq + 2 * NU * n + 3 * soft.len() * 3);
        qp.a.check_format().unwrap();
    }

    #[test]
    fn cost_matrix_is_upper_triangular_and_couples_consecutive_inputs() {
        let w = weights();
        let qp = Qp::new(4, &w, false, &ALL_STATES, &[], 0.0);
        let d = dense(&qp.p, &qp.p.nzval);
        for r in 0..qp.n_var() {
            for c in 0..r {
                assert_eq!(d[r][c], 0.0, "lower triangle at ({r}, {c})");
            }
        }
        assert_eq!(d[qp.x_index(2, 2)][qp.x_index(2, 2)], 2.0 * w.state[2]);
        assert_eq!(d[qp.x_index(4, 2)][qp.x_index(4, 2)], 2.0 * w.terminal * w.state[2]);
        let (u0, u1) = (qp.u_index(0, 1), qp.u_index(1, 1));
        assert_eq!(d[u0][u1], -2.0 * w.input_rate[1]);
        assert_eq!(d[u0][u0], 2.0 * w.input[1] + 4.0 * w.input_rate[1]);
        assert_eq!(d[qp.u_index(3, 1)][qp.u_index(3, 1)], 2.0 * w.input[1] + 2.0 * w.input_rate[1]);
    }
}
