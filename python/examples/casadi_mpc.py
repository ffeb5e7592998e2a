"""Depth-and-heading MPC in CasADi (IPOPT, single shooting) on the shipped PINC, against
the analytic vehicle as the plant.

    pip install "./python[casadi]" matplotlib
    python3 python/examples/casadi_mpc.py [--duration 30] [--json] [--plot out/casadi_mpc.png]

The model enters the NLP as `pinc.casadi.rollout_function`: one runtime call per horizon,
its Jacobian assembled from the runtime's exact A_k, B_k. IPOPT approximates the
Hessian (L-BFGS), since the model provides first derivatives only.
"""

import argparse
import collections
import json
import time
from pathlib import Path

import casadi as ca
import numpy as np

import pinc
import pinc.casadi

# --- parameters -----------------------------------------------------------------------
ROOT = Path(__file__).resolve().parents[2]
HORIZON = 20
W_DEPTH, W_HEADING = 20.0, 10.0
W_VELOCITY = np.array([0.05, 0.05, 0.5, 0.2])
W_INPUT = np.array([5e-2, 5e-2, 1e-3, 1e-2])
W_RATE = np.array([5e-2, 5e-2, 5e-3, 5e-1])


def reference(t):
    """Depth 0 -> 1 m at 2 s -> 0.5 m at 20 s; heading 0 -> 45 deg at 10 s."""
    depth = 0.0 if t < 2 else (1.0 if t < 20 else 0.5)
    heading = 0.0 if t < 10 else np.radians(45.0)
    return depth, heading


def build(p):
    """Single shooting: the inputs are the only variables and the horizon's states are the
    rollout `F(x0, U)`, whose Jacobian with respect to U comes from the runtime's A_k, B_k."""
    n = HORIZON
    F = pinc.casadi.rollout_function(p, n)
    U = ca.MX.sym("U", 4, n)
    x0, u_prev = ca.MX.sym("x0", 9), ca.MX.sym("u_prev", 4)
    refs = ca.MX.sym("refs", 3, n)  # depth, cos, sin per predicted state
    X = F(x0, U)
    cost = 0
    for k in range(n):
        xk = X[:, k + 1]
        cost += W_DEPTH * (xk[2] - refs[0, k]) ** 2
        cost += W_HEADING * ((xk[3] - refs[1, k]) ** 2 + (xk[4] - refs[2, k]) ** 2)
        cost += ca.dot(W_VELOCITY, xk[5:] ** 2) + ca.dot(W_INPUT, U[:, k] ** 2)
        du = U[:, k] - (u_prev if k == 0 else U[:, k - 1])
        cost += ca.dot(W_RATE, du**2)
    nlp = {"x": ca.vec(U), "p": ca.veccat(x0, u_prev, refs), "f": cost}
    opts = {
        "ipopt.print_level": 0,
        "print_time": False,
        "ipopt.hessian_approximation": "limited-memory",
        "ipopt.max_iter": 100,
        "ipopt.tol": 1e-5,
        "ipopt.acceptable_tol": 1e-3,
        "ipopt.acceptable_iter": 3,
        "ipopt.warm_start_init_point": "yes",
        "ipopt.mu_init": 1e-3,
    }
    return ca.nlpsol("mpc", "ipopt", nlp, opts), F


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=str(ROOT / "models" / "mpc_pinc_thrust.pinc"))
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--plot", default=None, help="PNG path (needs matplotlib)")
    a = ap.parse_args()

    p = pinc.Predictor(a.model)
    env = p.envelope
    lo = np.array([env[c][0] for c in ("X", "Y", "Z", "Mz")])
    hi = np.array([env[c][1] for c in ("X", "Y", "Z", "Mz")])
    solver, _f = build(p)
    n, dt = HORIZON, p.dt
    lbx, ubx = np.tile(lo, n), np.tile(hi, n)
    steps = int(round(a.duration / dt))
    s = np.zeros(8)  # plant state, simulator form
    u_prev = np.zeros(4)
    guess = np.zeros(4 * n)
    lam_x = np.zeros(4 * n)
    log = {"t": [], "depth": [], "heading": [], "depth_ref": [], "heading_ref": [], "u": [], "solve_ms": [], "status": []}
    for k in range(steps):
        t = k * dt
        x = np.array([s[0], s[1], s[2], np.cos(s[3]), np.sin(s[3]), *s[4:]])
        refs = np.array([[reference(t + (j + 1) * dt)[0], np.cos(reference(t + (j + 1) * dt)[1]),
                          np.sin(reference(t + (j + 1) * dt)[1])] for j in range(n)]).T
        start = time.perf_counter()
        params = np.concatenate([x, u_prev, refs.ravel(order="F")])
        sol = solver(x0=guess, lam_x0=lam_x, p=params, lbx=lbx, ubx=ubx)
        lam_x = np.asarray(sol["lam_x"]).ravel()
        log["solve_ms"].append(1e3 * (time.perf_counter() - start))
        log["status"].append(solver.stats()["return_status"])
        us = np.asarray(sol["x"]).reshape(n, 4)
        u = np.clip(us[0], lo, hi)
        # Warm start: the solution shifted by one sample.
        guess = np.vstack([us[1:], us[-1:]]).ravel()
        d_ref, h_ref = reference(t)
        log["t"].append(t)
        log["depth"].append(s[2])
        log["heading"].append(np.degrees(s[3]))
        log["depth_ref"].append(d_ref)
        log["heading_ref"].append(np.degrees(h_ref))
        log["u"].append(u.tolist())
        s = pinc.simulate(s, u[None, :], dt=dt)[-1]
        u_prev = u

    depth_err = np.array(log["depth"]) - np.array(log["depth_ref"])
    head_err = (np.array(log["heading"]) - np.array(log["heading_ref"]) + 180) % 360 - 180
    solve = np.array(log["solve_ms"])
    summary = {
        "samples": steps,
        "rms_depth_m": float(np.sqrt(np.mean(depth_err**2))),
        "rms_heading_deg": float(np.sqrt(np.mean(head_err**2))),
        "solve_ms_median": float(np.median(solve)),
        "solve_ms_p99": float(np.percentile(solve, 99)),
        "ipopt_status": dict(collections.Counter(log["status"])),
        "casadi": ca.__version__,
    }
    if a.json:
        print(json.dumps(summary, indent=2))
    else:
        for key, v in summary.items():
            print(f"{key:<18} {v:.4f}" if isinstance(v, float) else f"{key:<18} {v}")
    if a.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
        ax[0].plot(log["t"], log["depth"], label="depth")
        ax[0].plot(log["t"], log["depth_ref"], "--", label="reference")
        ax[0].set_ylabel("depth (m, down)")
        ax[0].invert_yaxis()
        ax[0].legend()
        ax[1].plot(log["t"], log["heading"], label="heading")
        ax[1].plot(log["t"], log["heading_ref"], "--", label="reference")
        ax[1].set_ylabel("heading (deg)")
        ax[1].legend()
        ax[2].plot(log["t"], np.array(log["u"]), label=["X (N)", "Y (N)", "Z (N)", "Mz (N m)"])
        ax[2].set_ylabel("input")
        ax[2].set_xlabel("time (s)")
        ax[2].legend(ncol=4)
        fig.suptitle(f"CasADi/IPOPT MPC on the PINC (casadi {ca.__version__}): "
                     f"RMS depth {summary['rms_depth_m']:.3f} m, heading {summary['rms_heading_deg']:.2f} deg")
        fig.tight_layout()
        Path(a.plot).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(a.plot, dpi=100)
        print(f"plot: {a.plot}")


if __name__ == "__main__":
    main()
