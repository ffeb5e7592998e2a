//! What the network's raw output means: the next state is the current one plus the output
//! (residual), with the planar increments rotated by the predicted yaw, optionally with
//! `(cos psi, sin psi)` renormalised (docs/MODEL.md section 3); and the exact Jacobians of
//! that map.

use super::kernels::{NetOut, NetScratch, Network, Real, packs};
use crate::types::{InputMatrix, NU, NX, State, StateMatrix};

/// The output map of a network, from its architecture flags.
#[derive(Debug, Clone, Copy)]
pub(crate) struct OutputMap {
    /// `x_next = x + out` rather than `x_next = out`.
    pub residual: bool,
    /// The planar increments `out[0..2]` are body-frame and rotated by the predicted yaw.
    pub rotate: bool,
    /// `(cos psi, sin psi)` rescaled to unit length after every step.
    pub renormalise_yaw: bool,
}

impl OutputMap {
    /// `x_next` from the base state (the current state, or a hybrid's physics step) and the
    /// raw output: residual, rotation of the planar increments
    /// by the predicted yaw, optional renormalisation; and how far the raw predicted
    /// `(cos psi, sin psi)` was off unit length (`|v| - 1`, before the renormalisation).
    #[inline(always)]
    pub(crate) fn apply(&self, base: &State, o: &NetOut) -> (State, f64) {
        let mut lanes: [[f64; 1]; NX] = std::array::from_fn(|c| [base[c]]);
        let [deviation] = self.apply_lanes(&mut lanes, &std::array::from_fn(|c| [o[c]]));
        (State::from_fn(|c, _| lanes[c][0]), deviation)
    }

    /// [`OutputMap::apply`] for `L` lanes at once, component-major, in place: the batch
    /// rollout's arithmetic is the single step's, lane by lane, and vectorises. Returns each
    /// lane's heading-vector deviation from unit length.
    #[inline(always)]
    pub(crate) fn apply_lanes<const L: usize>(&self, x: &mut [[f64; L]; NX], o: &[[f64; L]; NX]) -> [f64; L] {
        for b in 0..L {
            let before: [f64; NX] = std::array::from_fn(|c| x[c][b]);
            let base = |c: usize| if self.residual { before[c] } else { 0.0 };
            let (c, s) = (base(3) + o[3][b], base(4) + o[4][b]);
            let (dx, dy) =
                if self.rotate { (c * o[0][b] - s * o[1][b], s * o[0][b] + c * o[1][b]) } else { (o[0][b], o[1][b]) };
            x[0][b] = base(0) + dx;
            x[1][b] = base(1) + dy;
            for k in 2..NX {
                x[k][b] = base(k) + o[k][b];
            }
        }
        let norm: [f64; L] = std::array::from_fn(|b| (x[3][b] * x[3][b] + x[4][b] * x[4][b]).sqrt());
        if self.renormalise_yaw {
            for b in 0..L {
                x[3][b] /= norm[b];
                x[4][b] /= norm[b];
            }
        }
        norm.map(|n| n - 1.0)
    }

    /// Jacobians of [`OutputMap::apply`] given the network's `d out / d input` rows in
    /// `ws.rows` (after [`Network::reverse`]), the base state and, for a hybrid, the base's
    /// own Jacobians (`None`: the base is the current state, or zero without a residual).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // the network's and the base's parts, and the outputs
    pub(crate) fn jacobians<T: Real>(
        &self,
        net: &Network<T>,
        ws: &NetScratch<T>,
        base: &State,
        base_jacobians: Option<(&StateMatrix, &InputMatrix)>,
        o: &NetOut,
        a: &mut StateMatrix,
        b: &mut InputMatrix,
    ) {
        let q = packs(net.n_in);
        let ns = net.seen.len();
        // D = d out / d (x, u).
        let mut dx = StateMatrix::zeros();
        let mut du = InputMatrix::zeros();
        for k in 0..NX {
            let row = ws.rows[k * q..(k + 1) * q].as_flattened();
            for (m, &i) in net.seen.iter().enumerate() {
                dx[(k, i)] = row[m].to_f64();
            }
            for c in 0..NU {
                du[(k, c)] = row[ns + c].to_f64();
            }
        }
        // d base / d x and d base / d u.
        match base_jacobians {
            Some((ba, bb)) => {
                *a = *ba;
                *b = *bb;
            }
            None => {
                *a = if self.residual { StateMatrix::identity() } else { StateMatrix::zeros() };
                *b = InputMatrix::zeros();
            }
        }
        let base = if self.residual { *base } else { State::zeros() };
        let (c, s) = (base[3] + o[3], base[4] + o[4]);
        for k in 2..NX {
            for j in 0..NX {
                a[(k, j)] += dx[(k, j)];
            }
            for j in 0..NU {
                b[(k, j)] += du[(k, j)];
            }
        }
        if self.rotate {
            for j in 0..NX {
                // d c / d x_j and d s / d x_j (rows 3 and 4 already hold base plus output).
                let (cj, sj) = (a[(3, j)], a[(4, j)]);
                a[(0, j)] += c * dx[(0, j)] - s * dx[(1, j)] + o[0] * cj - o[1] * sj;
                a[(1, j)] += s * dx[(0, j)] + c * dx[(1, j)] + o[0] * sj + o[1] * cj;
            }
            for j in 0..NU {
                let (cj, sj) = (b[(3, j)], b[(4, j)]);
                b[(0, j)] += c * du[(0, j)] - s * du[(1, j)] + o[0] * cj - o[1] * sj;
                b[(1, j)] += s * du[(0, j)] + c * du[(1, j)] + o[0] * sj + o[1] * cj;
            }
        } else {
            for j in 0..NX {
                a[(0, j)] += dx[(0, j)];
                a[(1, j)] += dx[(1, j)];
            }
            for j in 0..NU {
                b[(0, j)] += du[(0, j)];
                b[(1, j)] += du[(1, j)];
            }
        }
        if self.renormalise_yaw {
            // d (v / |v|) / d v = (I - n n^T) / |v| on the (cos, sin) rows.
            let (vc, vs) = (base[3] + o[3], base[4] + o[4]);
            let norm = vc.hypot(vs);
            let (nc, ns) = (vc / norm, vs / norm);
            let p = [[(1.0 - nc * nc) / norm, -nc * ns / norm], [-nc * ns / norm, (1.0 - ns * ns) / norm]];
            for j in 0..NX {
                let (r3, r4) = (a[(3, j)], a[(4, j)]);
                a[(3, j)] = p[0][0] * r3 + p[0][1] * r4;
                a[(4, j)] = p[1][0] * r3 + p[1][1] * r4;
            }
            for j in 0..NU {
                let (r3, r4) = (b[(3, j)], b[(4, j)]);
                b[(3, j)] = p[0][0] * r3 + p[0][1] * r4;
                b[(4, j)] = p[1][0] * r3 + p[1][1] * r4;
            }
        }
    }
}
