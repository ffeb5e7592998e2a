//! The vehicle's right-hand side (docs/MODEL.md section 1, network form) in tensor ops, for the
//! physics losses.

use crate::types::NX;
use crate::vehicle::VehicleParams;
use burn::prelude::*;

/// `f(x, u)` for a batch.
///
/// # Shapes
/// - `x`: `[N, 9]`, `u`: `[N, 4]`; returns `[N, 9]`
pub fn rhs(p: &VehicleParams, x: Tensor<2>, u: Tensor<2>) -> Tensor<2> {
    let col = |t: &Tensor<2>, k: usize| t.clone().narrow(1, k, 1);
    let (cs, sn, su, sv, sw, sr) = (col(&x, 3), col(&x, 4), col(&x, 5), col(&x, 6), col(&x, 7), col(&x, 8));
    let (fx, fy, fz, mz) = (col(&u, 0), col(&u, 1), col(&u, 2), col(&u, 3));
    let (mu, mv, mw, mr) = (p.m - p.x_ud, p.m - p.y_vd, p.m - p.z_wd, p.izz - p.n_rd);
    let damp = |v: &Tensor<2>, lin: f64, quad: f64| (v.clone().abs() * quad + lin) * v.clone();
    let xd = cs.clone() * su.clone() - sn.clone() * sv.clone();
    let yd = sn.clone() * su.clone() + cs.clone() * sv.clone();
    let zd = sw.clone();
    let cd = sn.clone().neg() * sr.clone();
    let sd = cs * sr.clone();
    let ud = (fx + sv.clone() * sr.clone() * (p.m - p.y_vd) + damp(&su, p.x_u, p.x_uu)) / mu;
    let vd = (fy - su.clone() * sr.clone() * (p.m - p.x_ud) + damp(&sv, p.y_v, p.y_vv)) / mv;
    let wd = (fz + damp(&sw, p.z_w, p.z_ww) + p.net_buoyancy()) / mw;
    let rd = (mz - su * sv * (p.x_ud - p.y_vd) + damp(&sr, p.n_r, p.n_rr)) / mr;
    let out = Tensor::cat(vec![xd, yd, zd, cd, sd, ud, vd, wd, rd], 1);
    debug_assert_eq!(out.dims()[1], NX);
    out
}
