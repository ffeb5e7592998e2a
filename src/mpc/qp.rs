//! The QP of one real-time iteration in deviations from the nominal rollout, partially
//! condensed: `x_k = xbar_k + dx_k`, `u_k = ubar_k + du_k` (`dx_0 = 0`: the rollout starts
//! at the measured state), and the horizon cut into blocks of `M` steps whose inner states are
//! eliminated. `z = [dx_M, dx_2M, .., dx_N, du_0 .. du_{N-1}, slacks]`: the state at the end of
//! every block (and at `N`) stays a variable, every other state is an affine function of its
//! block's first state and inputs (docs/MODEL.md section 11.1). `M = 1` is the sparse form
//! with every state a variable.
//!
//! `dx_k` holds the kept state components only. The cost never weighs the horizontal
//! position, so a model whose dynamics do not depend on it (the analytic vehicle, a
//! position-free PINC) leaves `x, y` out: 7 states instead of 9.
//!
//! Clarabel's form is `min 1/2 z'Pz + q'z  s.t.  Az + s = b, s in K`. Rows of `A`:
//! - `m` equalities per block, `dx_e - E_e [dx_s; du_s..du_{e-1}] = c_e` for a block from step
//!   `s` to `e`, `E_e` the product of the block's `A_k`, `B_k` and `c_e` the disturbance carried
//!   through them (`M = 1`: `dx_{k+1} - A_k dx_k - B_k du_k = d`);
//! - `8N` input bounds `u_min <= ubar_k + du_k <= u_max`;
//! - with rate limits, `8N` more: `|u_k - u_{k-1}| <= rate` (`u_{-1}`: the applied input);
//! - with soft state bounds on `b` components, checked at every [`SOFT_STRIDE`]-th step and
//!   the last (`K` steps), `3bK` more: `lo <= xbar_k + dx_k + s_k`, `xbar_k + dx_k - s_k <=
//!   hi`, `s_k >= 0`, one slack per bound and step, priced by an exact (linear) penalty in `q`
//!   plus a small quadratic one in `P`. A bound on an inner state of a block is a row over
//!   that block's variables. Velocities change slowly over a step, so bounds at every 4th
//!   step cost a quarter of the rows; one slack per step keeps the KKT system free of dense
//!   columns.
//!
//! The inner states' costs become a dense block of `P` over each block's variables, rebuilt
//! every cycle ([`Qp::condense`]). The sparsity patterns of `A` and `P` hold every entry that
//! any cycle can fill, zeros included, so each sample only overwrites values.

use crate::types::{InputMatrix, NU, NX, StateMatrix};
use clarabel::algebra::CscMatrix;
use std::collections::BTreeMap;

/// All nine state components.
pub(crate) const ALL_STATES: [usize; NX] = [0, 1, 2, 3, 4, 5, 6, 7, 8];
/// Everything but the horizontal position `x, y`.
pub(crate) const WITHOUT_POSITION: [usize; NX - 2] = [2, 3, 4, 5, 6, 7, 8];

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

/// A sparse pattern collected entry by entry (duplicates add), then frozen into CSC with a
/// lookup of where each entry landed.
struct Pattern {
    rows: usize,
    cols: usize,
    entries: BTreeMap<(usize, usize), f64>,
}

impl Pattern {
    fn new(rows: usize, cols: usize) -> Self {
        Self { rows, cols, entries: BTreeMap::new() }
    }

    fn add(&mut self, row: usize, col: usize, value: f64) {
        *self.entries.entry((col, row)).or_insert(0.0) += value;
    }

    fn build(self) -> CscMatrix<f64> {
        let mut colptr = vec![0; self.cols + 1];
        for &(c, _) in self.entries.keys() {
            colptr[c + 1] += 1;
        }
        for c in 0..self.cols {
            colptr[c + 1] += colptr[c];
        }
        let (rowval, nzval) = self.entries.into_iter().map(|((_, r), v)| (r, v)).unzip();
        CscMatrix::new(self.rows, self.cols, colptr, rowval, nzval)
    }
}

/// The position in `nzval` of entry `(row, col)` of `m` (which must be in its pattern).
fn slot(m: &CscMatrix<f64>, row: usize, col: usize) -> usize {
    let (a, b) = (m.colptr[col], m.colptr[col + 1]);
    a + m.rowval[a..b].binary_search(&row).expect("entry in the pattern")
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

/// Steps `start .. end` of the horizon condensed into one: the states `start + 1 .. end - 1`
/// are eliminated, `dx_end` stays a variable.
struct Block {
    start: usize,
    end: usize,
    /// Local variables: `dx_start` (`m` of them, none for the first block: `dx_0 = 0`) and
    /// `du_start .. du_{end-1}`; their columns in `z`.
    cols: Vec<usize>,
    /// `E_k` for `k = start ..= end`, each `m x cols.len()` column-major: `dx_k = E_k z_b + c_k`.
    e: Vec<f64>,
    /// `c_k` for `k = start ..= end` (`m` each): the disturbance carried to step `k`.
    c: Vec<f64>,
    /// `nzval` slots of `-E_end` in the block's equality rows, `(local col, row)` column-major.
    eq_slots: Vec<usize>,
    /// `nzval` slots of `P` for local pairs `a <= b < inner`, at `b * (b + 1) / 2 + a`.
    p_slots: Vec<usize>,
    /// Local variables any inner state depends on (`dx_start`, `du_start .. du_{end-2}`).
    inner: usize,
}

impl Block {
    /// Local variables step `k`'s state depends on.
    fn support(&self, k: usize, m: usize) -> usize {
        let xs = if self.start > 0 { m } else { 0 };
        xs + NU * (k - self.start)
    }
}

/// A soft bound on an inner state: its rows' slots over the block's variables.
struct InnerBound {
    /// Index of the block, step, position in `states`, and the rows (upper, lower).
    block: usize,
    step: usize,
    state: usize,
    rows: (usize, usize),
    /// `nzval` slots of the upper and lower rows' entries for the block's first `support`
    /// local variables.
    upper: Vec<usize>,
    lower: Vec<usize>,
}

/// The QP's fixed structure, the stage data the controller writes every cycle, and the
/// condensed data handed to the solver.
pub(crate) struct Qp {
    pub(crate) horizon: usize,
    /// Steps per condensed block.
    pub(crate) block: usize,
    /// The 9-state components in the QP, in order (all nine, or `z ..` for a model whose
    /// dynamics do not depend on the horizontal position).
    pub(crate) states: Vec<usize>,
    pub(crate) p: CscMatrix<f64>,
    pub(crate) a: CscMatrix<f64>,
    /// Current values of `P`'s and `A`'s non-zeros (handed to `update_P`, `update_A`).
    pub(crate) p_values: Vec<f64>,
    pub(crate) a_values: Vec<f64>,
    pub(crate) q: Vec<f64>,
    pub(crate) b: Vec<f64>,
    /// Stage data, written by the controller before [`Qp::condense`]: the linear cost of
    /// `dx_k[states[s]]` at `(k - 1) * m + s`, of `du_k[j]` at `k * NU + j`; the disturbance
    /// per kept state; the soft rows' right-hand sides for `dx_k` itself (see [`Qp::soft_row`]).
    pub(crate) state_q: Vec<f64>,
    pub(crate) input_q: Vec<f64>,
    pub(crate) disturbance: Vec<f64>,
    /// Diagonal state weights of `P` (`2 f w`), at `(k - 1) * m + s`.
    state_weight: Vec<f64>,
    /// `P`'s values that do not depend on the cycle (kept states, inputs, slacks).
    p_base: Vec<f64>,
    blocks: Vec<Block>,
    inner_bounds: Vec<InnerBound>,
    /// The column of `dx_k` (kept steps only) per step `k = 0..=N`.
    kept_col: Vec<Option<usize>>,
    pub(crate) n_eq: usize,
    /// Positions in `states` of the softly bounded components.
    pub(crate) soft: Vec<usize>,
    /// The steps with soft bounds ([`soft_steps`]).
    pub(crate) soft_steps: Vec<usize>,
    /// First row of the soft-bound block.
    soft_base: usize,
    /// Scratch: the kept rows and columns of one `A_k` and `B_k`, a block's linear cost.
    ak: Vec<f64>,
    bk: Vec<f64>,
    local_q: Vec<f64>,
}

impl Qp {
    /// The structure for `horizon` steps in blocks of `block` over the 9-state components
    /// `states`, with soft bounds on the components at positions `soft` of `states` (slack
    /// weight `slack_quad` in `P`).
    pub(crate) fn new(
        horizon: usize,
        block: usize,
        w: &Weights,
        rate_limited: bool,
        states: &[usize],
        soft: &[usize],
        slack_quad: f64,
    ) -> Self {
        let n = horizon;
        let block = block.clamp(1, n);
        let m = states.len();
        let ns = soft.len();
        let ends: Vec<usize> = (1..=n).filter(|k| k % block == 0 || *k == n).collect();
        let n_kept = ends.len();
        let mut kept_col = vec![None; n + 1];
        for (i, &k) in ends.iter().enumerate() {
            kept_col[k] = Some(i * m);
        }
        let steps = soft_steps(n);
        let n_var = n_kept * m + n * NU + ns * steps.len();
        let col_u = |k: usize, j: usize| n_kept * m + k * NU + j;
        let col_s = |j: usize, i: usize| n_kept * m + n * NU + j * ns + i;
        let n_eq = n_kept * m;
        let soft_base = n_eq + 2 * NU * n + if rate_limited { 2 * NU * n } else { 0 };
        let soft_row = |j: usize, i: usize, which: usize| soft_row_of(soft_base, ns, j, i, which);
        let n_rows = soft_base + 3 * ns * steps.len();
        let bound_row = |k: usize, j: usize, upper: bool| n_eq + k * 2 * NU + j + if upper { 0 } else { NU };
        let rate_row =
            |k: usize, j: usize, upper: bool| n_eq + 2 * NU * n + k * 2 * NU + j + if upper { 0 } else { NU };

        let mut blocks: Vec<Block> = Vec::with_capacity(n_kept);
        let mut start = 0;
        for &end in &ends {
            let mut cols: Vec<usize> = match kept_col[start] {
                Some(c) if start > 0 => (c..c + m).collect(),
                _ => Vec::new(),
            };
            cols.extend((start..end).flat_map(|k| (0..NU).map(move |j| col_u(k, j))));
            let width = cols.len();
            let steps_in = end - start + 1;
            let mut b = Block {
                start,
                end,
                cols,
                e: vec![0.0; steps_in * m * width],
                c: vec![0.0; steps_in * m],
                eq_slots: Vec::new(),
                p_slots: Vec::new(),
                inner: 0,
            };
            b.inner = if end - start > 1 { b.support(end - 1, m) } else { 0 };
            blocks.push(b);
            start = end;
        }

        let mut a = Pattern::new(n_rows, n_var);
        for (bi, blk) in blocks.iter().enumerate() {
            let xe = kept_col[blk.end].expect("a block ends at a kept step");
            for r in 0..m {
                a.add(bi * m + r, xe + r, 1.0);
                for &c in &blk.cols {
                    a.add(bi * m + r, c, 0.0);
                }
            }
        }
        for k in 0..n {
            for j in 0..NU {
                let c = col_u(k, j);
                a.add(bound_row(k, j, true), c, 1.0);
                a.add(bound_row(k, j, false), c, -1.0);
                if rate_limited {
                    a.add(rate_row(k, j, true), c, 1.0);
                    a.add(rate_row(k, j, false), c, -1.0);
                    if k + 1 < n {
                        a.add(rate_row(k + 1, j, true), c, -1.0);
                        a.add(rate_row(k + 1, j, false), c, 1.0);
                    }
                }
            }
        }
        let mut inner_bounds = Vec::new();
        for (j, &k) in steps.iter().enumerate() {
            for (i, &s) in soft.iter().enumerate() {
                let (up, lo) = (soft_row(j, i, 0), soft_row(j, i, 1));
                for which in 0..3 {
                    a.add(soft_row(j, i, which), col_s(j, i), -1.0);
                }
                if let Some(c) = kept_col[k] {
                    a.add(up, c + s, 1.0);
                    a.add(lo, c + s, -1.0);
                } else {
                    let bi = blocks.iter().position(|b| b.start < k && k < b.end).expect("an inner step");
                    for &c in &blocks[bi].cols[..blocks[bi].support(k, m)] {
                        a.add(up, c, 0.0);
                        a.add(lo, c, 0.0);
                    }
                    inner_bounds.push(InnerBound {
                        block: bi,
                        step: k,
                        state: s,
                        rows: (up, lo),
                        upper: Vec::new(),
                        lower: Vec::new(),
                    });
                }
            }
        }
        let a = a.build();
        for (bi, blk) in blocks.iter_mut().enumerate() {
            blk.eq_slots = (0..blk.cols.len())
                .flat_map(|lc| (0..m).map(move |r| (lc, r)))
                .map(|(lc, r)| slot(&a, bi * m + r, blk.cols[lc]))
                .collect();
        }
        for ib in &mut inner_bounds {
            let blk = &blocks[ib.block];
            let cols = &blk.cols[..blk.support(ib.step, m)];
            ib.upper = cols.iter().map(|&c| slot(&a, ib.rows.0, c)).collect();
            ib.lower = cols.iter().map(|&c| slot(&a, ib.rows.1, c)).collect();
        }

        let mut state_weight = vec![0.0; n * m];
        for k in 1..=n {
            let f = if k == n { w.terminal } else { 1.0 };
            for (s, &i) in states.iter().enumerate() {
                state_weight[(k - 1) * m + s] = 2.0 * f * w.state[i];
            }
        }
        let mut p = Pattern::new(n_var, n_var);
        for (k, col) in kept_col.iter().enumerate() {
            if let Some(c) = col {
                for s in 0..m {
                    p.add(c + s, c + s, state_weight[(k - 1) * m + s]);
                }
            }
        }
        for k in 0..n {
            for j in 0..NU {
                let c = col_u(k, j);
                let next = if k + 1 < n { 2.0 * w.input_rate[j] } else { 0.0 };
                if k > 0 {
                    p.add(col_u(k - 1, j), c, -2.0 * w.input_rate[j]);
                }
                p.add(c, c, 2.0 * w.input[j] + 2.0 * w.input_rate[j] + next);
            }
        }
        for j in 0..steps.len() {
            for i in 0..ns {
                p.add(col_s(j, i), col_s(j, i), 2.0 * slack_quad);
            }
        }
        for blk in &blocks {
            for hi in 0..blk.inner {
                for lo in 0..=hi {
                    p.add(blk.cols[lo], blk.cols[hi], 0.0);
                }
            }
        }
        let p = p.build();
        for blk in &mut blocks {
            blk.p_slots = (0..blk.inner)
                .flat_map(|hi| (0..=hi).map(move |lo| (lo, hi)))
                .map(|(lo, hi)| slot(&p, blk.cols[lo], blk.cols[hi]))
                .collect();
        }
        let width = blocks.iter().map(|b| b.cols.len()).max().unwrap_or(0);
        Self {
            horizon,
            block,
            states: states.to_vec(),
            p_values: p.nzval.clone(),
            p_base: p.nzval.clone(),
            a_values: a.nzval.clone(),
            q: vec![0.0; n_var],
            b: vec![0.0; n_rows],
            state_q: vec![0.0; n * m],
            input_q: vec![0.0; n * NU],
            disturbance: vec![0.0; m],
            state_weight,
            p,
            a,
            blocks,
            inner_bounds,
            kept_col,
            n_eq,
            soft: soft.to_vec(),
            soft_steps: steps,
            soft_base,
            ak: vec![0.0; m * m],
            bk: vec![0.0; m * NU],
            local_q: vec![0.0; width],
        }
    }

    /// Condenses every block along the linearisation `a`, `b` (restricted to the kept
    /// states) and writes `A`'s values, `P`'s values, `q` and the right-hand sides of the
    /// equality and inner soft rows from the stage data. The input bound and rate rows, and
    /// the soft rows' right-hand sides on the states themselves, are the caller's.
    pub(crate) fn condense(&mut self, a: &[StateMatrix], b: &[InputMatrix]) {
        let m = self.states.len();
        self.p_values.copy_from_slice(&self.p_base);
        for (k, col) in self.kept_col.iter().enumerate() {
            if let &Some(c) = col {
                self.q[c..c + m].copy_from_slice(&self.state_q[(k - 1) * m..k * m]);
            }
        }
        let first_u = self.n_eq;
        self.q[first_u..first_u + self.input_q.len()].copy_from_slice(&self.input_q);
        for bi in 0..self.blocks.len() {
            self.propagate(bi, a, b);
            self.add_inner_costs(bi);
            let blk = &self.blocks[bi];
            let w = blk.cols.len();
            let last = (blk.end - blk.start) * m * w;
            for (i, &s) in blk.eq_slots.iter().enumerate() {
                self.a_values[s] = -blk.e[last + i];
            }
            let c_end = &blk.c[(blk.end - blk.start) * m..];
            self.b[bi * m..(bi + 1) * m].copy_from_slice(c_end);
        }
        for ib in &self.inner_bounds {
            let blk = &self.blocks[ib.block];
            let (w, i) = (blk.cols.len(), ib.step - blk.start);
            let e = &blk.e[i * m * w..(i + 1) * m * w];
            for (lc, (&up, &lo)) in ib.upper.iter().zip(&ib.lower).enumerate() {
                let v = e[lc * m + ib.state];
                self.a_values[up] = v;
                self.a_values[lo] = -v;
            }
            let c = blk.c[i * m + ib.state];
            self.b[ib.rows.0] -= c;
            self.b[ib.rows.1] += c;
        }
    }

    /// `E_k` and `c_k` through block `bi`: `E_{k+1} = A_k E_k + B_k S_k`, `c_{k+1} = A_k c_k + d`.
    fn propagate(&mut self, bi: usize, a: &[StateMatrix], b: &[InputMatrix]) {
        let m = self.states.len();
        let blk = &mut self.blocks[bi];
        let w = blk.cols.len();
        let xs = if blk.start > 0 { m } else { 0 };
        blk.e[..m * w].fill(0.0);
        blk.c[..m].fill(0.0);
        for r in 0..xs {
            blk.e[r * m + r] = 1.0;
        }
        for k in blk.start..blk.end {
            for (c, &ic) in self.states.iter().enumerate() {
                for (r, &ir) in self.states.iter().enumerate() {
                    self.ak[c * m + r] = a[k][(ir, ic)];
                }
            }
            for j in 0..NU {
                for (r, &ir) in self.states.iter().enumerate() {
                    self.bk[j * m + r] = b[k][(ir, j)];
                }
            }
            let i = k - blk.start;
            let support = blk.support(k, m);
            let (done, next) = blk.e.split_at_mut((i + 1) * m * w);
            let here = &done[i * m * w..];
            let next = &mut next[..m * w];
            next.fill(0.0);
            for lc in 0..support {
                let src = &here[lc * m..(lc + 1) * m];
                let dst = &mut next[lc * m..(lc + 1) * m];
                for (c, &v) in src.iter().enumerate() {
                    if v != 0.0 {
                        for r in 0..m {
                            dst[r] += self.ak[c * m + r] * v;
                        }
                    }
                }
            }
            next[support * m..(support + NU) * m].copy_from_slice(&self.bk);
            let (done, next) = blk.c.split_at_mut((i + 1) * m);
            let here = &done[i * m..];
            for r in 0..m {
                next[r] = self.disturbance[r] + (0..m).map(|c| self.ak[c * m + r] * here[c]).sum::<f64>();
            }
        }
    }

    /// The costs of block `bi`'s inner states in its variables: `P_b += E_k' W_k E_k`,
    /// `q_b += E_k' (W_k c_k + q_k)`.
    fn add_inner_costs(&mut self, bi: usize) {
        let m = self.states.len();
        let blk = &self.blocks[bi];
        let w = blk.cols.len();
        let local_q = &mut self.local_q[..w];
        local_q.fill(0.0);
        for k in blk.start + 1..blk.end {
            let i = k - blk.start;
            let e = &blk.e[i * m * w..(i + 1) * m * w];
            let c = &blk.c[i * m..(i + 1) * m];
            let weight = &self.state_weight[(k - 1) * m..k * m];
            let lin = &self.state_q[(k - 1) * m..k * m];
            let support = blk.support(k, m);
            for hi in 0..support {
                let col_hi = &e[hi * m..(hi + 1) * m];
                let base = hi * (hi + 1) / 2;
                for lo in 0..=hi {
                    let col_lo = &e[lo * m..(lo + 1) * m];
                    let v: f64 = (0..m).map(|r| col_lo[r] * weight[r] * col_hi[r]).sum();
                    self.p_values[blk.p_slots[base + lo]] += v;
                }
                local_q[hi] += (0..m).map(|r| col_hi[r] * (weight[r] * c[r] + lin[r])).sum::<f64>();
            }
        }
        for (lc, &col) in blk.cols.iter().enumerate() {
            self.q[col] += local_q[lc];
        }
    }

    /// Index of `du_k[j]` in `z`.
    pub(crate) fn u_index(&self, k: usize, j: usize) -> usize {
        self.n_eq + k * NU + j
    }

    /// Index of `dx_k[states[s]]` in `z` if step `k` is kept (the end of a block).
    pub(crate) fn x_index(&self, k: usize, s: usize) -> Option<usize> {
        self.kept_col[k].map(|c| c + s)
    }

    /// Row of the upper (`true`) or lower input bound of `u_k[j]`.
    pub(crate) fn bound_row(&self, k: usize, j: usize, upper: bool) -> usize {
        self.n_eq + k * 2 * NU + j + if upper { 0 } else { NU }
    }

    /// Index in `z` of the slack of soft bound `i` at step `soft_steps[j]`.
    pub(crate) fn slack_index(&self, j: usize, i: usize) -> usize {
        self.n_eq + self.horizon * NU + j * self.soft.len() + i
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

/// A deterministic value in [-1, 1) from three integers, for the QP tests' random problems
/// (no RNG crate needed here).
#[cfg(test)]
pub(crate) fn hash(a: usize, b: usize, c: usize) -> f64 {
    let x = (a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (c as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    let x = (x ^ (x >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    ((x >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

/// Clarabel on the condensed QP as it stands, to `tol`: the solution `z` (tests' reference).
#[cfg(test)]
pub(crate) fn solve_condensed(qp: &Qp, tol: f64) -> Vec<f64> {
    use clarabel::solver::{DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT};
    let cones = [SupportedConeT::ZeroConeT(qp.n_eq), SupportedConeT::NonnegativeConeT(qp.b.len() - qp.n_eq)];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .presolve_enable(false)
        .tol_gap_abs(tol)
        .tol_gap_rel(tol)
        .tol_feas(tol)
        .build()
        .unwrap();
    let p = CscMatrix::new(qp.p.m, qp.p.n, qp.p.colptr.clone(), qp.p.rowval.clone(), qp.p_values.clone());
    let am = CscMatrix::new(qp.a.m, qp.a.n, qp.a.colptr.clone(), qp.a.rowval.clone(), qp.a_values.clone());
    let mut solver = DefaultSolver::new(&p, &qp.q, &am, &qp.b, &cones, settings).unwrap();
    solver.solve();
    assert_eq!(solver.solution.status, SolverStatus::Solved);
    solver.solution.x
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

    /// Dense matrix from CSC values, to compare with the block structure.
    fn dense(m: &CscMatrix<f64>, values: &[f64]) -> Vec<Vec<f64>> {
        let mut d = vec![vec![0.0; m.n]; m.m];
        for c in 0..m.n {
            for i in m.colptr[c]..m.colptr[c + 1] {
                d[m.rowval[i]][c] = values[i];
            }
        }
        d
    }

    /// A stable-ish linearisation: near-identity `A_k`, dense small `B_k`.
    fn linearisation(n: usize) -> (Vec<StateMatrix>, Vec<InputMatrix>) {
        let a = (0..n)
            .map(|k| StateMatrix::from_fn(|r, c| if r == c { 0.97 } else { 0.0 } + 0.05 * hash(k, r, c)))
            .collect();
        let b = (0..n).map(|k| InputMatrix::from_fn(|r, j| 0.2 * hash(k + 100, r, j))).collect();
        (a, b)
    }

    /// Writes stage data (costs, bounds, soft bounds that bind, a disturbance), condenses and
    /// solves to 1e-10; returns `du` and every predicted `dx_k` (propagated from `du`).
    fn solve(qp: &mut Qp, a: &[StateMatrix], b: &[InputMatrix], rate: bool) -> (Vec<f64>, Vec<Vec<f64>>) {
        let (n, m) = (qp.horizon, qp.states.len());
        for (i, v) in qp.state_q.iter_mut().enumerate() {
            *v = hash(i, 1, 2);
        }
        for (i, v) in qp.input_q.iter_mut().enumerate() {
            *v = 0.5 * hash(i, 3, 4);
        }
        for (r, v) in qp.disturbance.iter_mut().enumerate() {
            *v = 0.01 * hash(r, 5, 6);
        }
        for k in 0..n {
            for j in 0..NU {
                let (ub, lb) = (qp.bound_row(k, j, true), qp.bound_row(k, j, false));
                (qp.b[ub], qp.b[lb]) = (0.4, 0.3);
                if rate {
                    let (ru, rl) = (qp.rate_row(k, j, true), qp.rate_row(k, j, false));
                    (qp.b[ru], qp.b[rl]) = (0.25, 0.25);
                }
            }
        }
        for j in 0..qp.soft_steps.len() {
            for i in 0..qp.soft.len() {
                let (up, lo, sign) = (qp.soft_row(j, i, 0), qp.soft_row(j, i, 1), qp.soft_row(j, i, 2));
                (qp.b[up], qp.b[lo], qp.b[sign]) = (0.02, 0.02, 0.0);
                let at = qp.slack_index(j, i);
                qp.q[at] = 3.0;
            }
        }
        qp.condense(a, b);
        let z = &solve_condensed(qp, 1e-10);
        let du: Vec<f64> =
            (0..n).flat_map(|k| (0..NU).map(move |j| (k, j))).map(|(k, j)| z[qp.u_index(k, j)]).collect();
        let mut dx = vec![vec![0.0; m]];
        for k in 0..n {
            let next: Vec<f64> = (0..m)
                .map(|r| {
                    let (ir, states) = (qp.states[r], &qp.states);
                    qp.disturbance[r]
                        + (0..m).map(|c| a[k][(ir, states[c])] * dx[k][c]).sum::<f64>()
                        + (0..NU).map(|j| b[k][(ir, j)] * du[k * NU + j]).sum::<f64>()
                })
                .collect();
            if let Some(at) = qp.x_index(k + 1, 0) {
                for (r, v) in next.iter().enumerate() {
                    assert!((z[at + r] - v).abs() < 1e-7, "kept dx_{} differs from its propagation", k + 1);
                }
            }
            dx.push(next);
        }
        (du, dx)
    }

    #[test]
    fn every_block_size_solves_the_sparse_qp() {
        let n = 13;
        let (a, b) = linearisation(n);
        for (states, soft, rate) in
            [(&WITHOUT_POSITION[..], &[3usize, 6][..], false), (&ALL_STATES[..], &[5usize, 8][..], true)]
        {
            let mut sparse = Qp::new(n, 1, &weights(), rate, states, soft, 2.0);
            let (du_ref, dx_ref) = solve(&mut sparse, &a, &b, rate);
            assert!(du_ref.iter().any(|v| v.abs() > 0.05), "the test problem moves the inputs");
            for block in [2, 3, 4, 5, 10, 13] {
                let mut qp = Qp::new(n, block, &weights(), rate, states, soft, 2.0);
                assert!(qp.n_eq < sparse.n_eq, "block {block}: fewer equality rows");
                let (du, dx) = solve(&mut qp, &a, &b, rate);
                let worst = du.iter().zip(&du_ref).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
                assert!(worst < 1e-6, "block {block}: inputs differ by {worst:e}");
                for (k, (x, y)) in dx.iter().zip(&dx_ref).enumerate() {
                    for (u, v) in x.iter().zip(y) {
                        assert!((u - v).abs() < 1e-6, "block {block}: dx_{k} differs");
                    }
                }
            }
        }
    }

    #[test]
    fn sparse_form_puts_each_step_dynamics_in_its_own_rows() {
        let n = 3;
        for states in [&ALL_STATES[..], &WITHOUT_POSITION[..]] {
            let m = states.len();
            let mut qp = Qp::new(n, 1, &weights(), true, states, &[], 0.0);
            let a: Vec<StateMatrix> =
                (0..n).map(|k| StateMatrix::from_fn(|r, c| (100 * k + 10 * r + c) as f64 + 0.5)).collect();
            let b: Vec<InputMatrix> =
                (0..n).map(|k| InputMatrix::from_fn(|r, j| -((100 * k + 10 * r + j) as f64) - 0.25)).collect();
            qp.condense(&a, &b);
            let d = dense(&qp.a, &qp.a_values);
            for k in 0..n {
                for (r, &ir) in states.iter().enumerate() {
                    let row = m * k + r;
                    for (c, &ic) in states.iter().enumerate() {
                        assert_eq!(d[row][qp.x_index(k + 1, c).unwrap()], if r == c { 1.0 } else { 0.0 });
                        if k >= 1 {
                            assert_eq!(d[row][qp.x_index(k, c).unwrap()], -a[k][(ir, ic)]);
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
    fn condensed_blocks_keep_one_state_per_block_and_an_upper_triangular_cost() {
        let n = 10;
        let soft = [3usize, 5];
        let mut qp = Qp::new(n, 4, &weights(), false, &WITHOUT_POSITION, &soft, 7.0);
        assert_eq!(qp.soft_steps, [4, 8, 10]);
        let kept: Vec<usize> = (1..=n).filter(|&k| qp.x_index(k, 0).is_some()).collect();
        assert_eq!(kept, [4, 8, 10]);
        assert_eq!(qp.n_eq, 3 * 7);
        let (a, b) = linearisation(n);
        qp.condense(&a, &b);
        let p = dense(&qp.p, &qp.p_values);
        for (r, row) in p.iter().enumerate() {
            for (c, v) in row.iter().enumerate().take(r) {
                assert_eq!(*v, 0.0, "lower triangle at ({r}, {c})");
            }
        }
        // The inner states' cost couples the block's first state with its inputs.
        assert!(p[qp.x_index(4, 0).unwrap()][qp.u_index(5, 0)] != 0.0);
        assert!(p[qp.u_index(4, 1)][qp.u_index(6, 2)] != 0.0);
        assert_eq!(p[qp.u_index(3, 1)][qp.u_index(5, 1)], 0.0, "no coupling across blocks");
        let slack = qp.slack_index(0, 0);
        assert_eq!(p[slack][slack], 14.0);
        qp.a.check_format().unwrap();
        qp.p.check_format().unwrap();
    }
}
