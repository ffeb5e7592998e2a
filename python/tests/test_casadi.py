"""The CasADi Functions: values equal the predictor's, Jacobians equal its exact A, B (and,
for the rollout, finite differences), and IPOPT can optimise through them."""

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import pinc
import pinc.casadi

MODEL = Path(__file__).resolve().parents[2] / "models" / "mpc_pinc.pinc"


@pytest.fixture(scope="module")
def p():
    return pinc.Predictor(str(MODEL))


X0 = np.array([0.0, 0.0, 1.0, np.cos(0.4), np.sin(0.4), 0.2, 0.0, 0.05, 0.1])


def test_step_function_value_and_exact_jacobian(p):
    f = pinc.casadi.step_function(p)
    x, u = ca.MX.sym("x", 9), ca.MX.sym("u", 4)
    jac = ca.Function("jacobians", [x, u], [ca.jacobian(f(x, u), x), ca.jacobian(f(x, u), u)])
    u0 = np.array([3.0, 0.5, 4.0, 0.2])
    np.testing.assert_array_equal(np.asarray(f(X0, u0)).ravel(), p.step(X0, u0))
    a, b = (np.asarray(m) for m in jac(X0, u0))
    _, A, B = p.linearise(X0, u0[None, :])
    np.testing.assert_array_equal(a, A[0])
    np.testing.assert_array_equal(b, B[0])


def test_rollout_function_jacobian_matches_finite_differences(p):
    n = 8
    F = pinc.casadi.rollout_function(p, n)
    x0, U = ca.MX.sym("x0", 9), ca.MX.sym("U", 4, n)
    jac = ca.Function("jacobians", [x0, U], [ca.jacobian(F(x0, U), U)])
    u = np.stack([[2.0, 0.3, 4.0 + 0.1 * k, 0.1] for k in range(n)], axis=1)  # 4 x n
    np.testing.assert_array_equal(np.asarray(F(X0, u)), p.rollout(X0, u.T).T)
    j = np.asarray(jac(X0, u))
    h = 1e-3
    for k, c in [(0, 0), (3, 2), (7, 3)]:
        e = np.zeros_like(u)
        e[c, k] = h
        fd = (p.rollout(X0, (u + e).T).T - p.rollout(X0, (u - e).T).T) / (2 * h)
        col = j[:, k * 4 + c].reshape((9, n + 1), order="F")
        np.testing.assert_allclose(col, fd, atol=2e-3, err_msg=f"d X / d U[{c}, {k}]")
        assert np.all(col[:, : k + 1] == 0), "no effect before the input is applied"


def test_ipopt_finds_the_input_that_reaches_a_depth(p):
    f = pinc.casadi.step_function(p)
    u = ca.MX.sym("u", 4)
    x = X0
    for _ in range(5):
        x = f(x, u)
    target = 1.05
    nlp = {"x": u, "f": (x[2] - target) ** 2 + 1e-10 * ca.sumsqr(u)}
    solver = ca.nlpsol("s", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False,
                                           "ipopt.hessian_approximation": "limited-memory"})
    sol = solver(x0=np.zeros(4), lbx=[-10, -5, -5, -1], ubx=[10, 5, 20, 1])
    u_opt = np.asarray(sol["x"]).ravel()
    z = p.rollout(X0, np.tile(u_opt, (5, 1)))[-1, 2]
    assert abs(z - target) < 1e-3, (z, u_opt)
