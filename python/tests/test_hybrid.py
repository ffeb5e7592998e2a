"""A hybrid model (its vehicle's RK4 step plus a learned correction) through the same Python
and CasADi calls as a PINC: against the command line, its own physics, finite differences and
its exact Jacobians."""

import json
import subprocess
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import pinc
import pinc.casadi
from finite_differences import central_differences

ROOT = Path(__file__).resolve().parents[2]
HYBRID = ROOT / "models" / "hybrid_plant_a.pinc"
CLI = ROOT / "target" / "release" / "pinc"


@pytest.fixture(scope="module")
def p():
    return pinc.Predictor(str(HYBRID))


def run(*args):
    assert CLI.exists(), f"{CLI} is built by `cargo test --release` (the README's test command runs it first)"
    return subprocess.run([str(CLI), *map(str, args)], capture_output=True, text=True, check=True).stdout


def inputs(n):
    k = np.arange(n)
    return np.stack([5 * np.sin(0.3 * k), 1.0 + 0 * k, 4 + 0.2 * k, 0.5 * np.cos(0.2 * k)], axis=1)


S0 = [0.2, -0.3, 1.2, 0.9, 0.3, -0.1, 0.05, 0.2]
X0 = np.array([S0[0], S0[1], S0[2], np.cos(S0[3]), np.sin(S0[3]), *S0[4:]])


def test_it_says_what_it_is(p):
    assert p.is_hybrid
    assert not pinc.Predictor(str(ROOT / "models" / "mpc_pinc.pinc")).is_hybrid
    text = run("inspect", HYBRID)
    assert "hybrid: the vehicle below (RK4, 16 sub-steps per step)" in text, text


def test_rollout_equals_pinc_predict(p, tmp_path):
    u = inputs(30)
    csv = tmp_path / "u.csv"
    np.savetxt(csv, u, delimiter=",", header="X,Y,Z,Mz", comments="", fmt="%.17g")
    out = run("predict", "--model", HYBRID, "--x0", ",".join(map(str, S0)), "--inputs", csv)
    expected = np.array([line.split(",") for line in out.splitlines()[1:]], dtype=float)
    got = p.rollout(X0, u)
    np.testing.assert_array_equal(got[:, [0, 1, 2, 5, 6, 7, 8]], expected[:, [1, 2, 3, 5, 6, 7, 8]])


def test_a_step_is_its_physics_plus_a_small_correction(p):
    # The vehicle the file carries, integrated by pinc.simulate (16 RK4 sub-steps per 0.08 s).
    vehicle = json.loads(run("inspect", "--json", HYBRID))["vehicle"]
    u = inputs(1)
    physics = pinc.simulate(S0, u, dt=p.dt, vehicle=vehicle)[1]
    physics = np.array([*physics[:3], np.cos(physics[3]), np.sin(physics[3]), *physics[4:]])
    correction = p.step(X0, u[0]) - physics
    assert 0 < np.abs(correction).max() < 0.05, correction


def test_jacobians_match_central_differences_and_casadi(p):
    u = inputs(10)
    X, A, B = p.linearise(X0, u)
    np.testing.assert_array_equal(X, p.rollout(X0, u))
    for k in [0, 5, 9]:
        fa, fb = central_differences(p, X[k], u[k], h=1e-3)
        np.testing.assert_allclose(A[k], fa, atol=2e-3, err_msg=f"A_{k}")
        np.testing.assert_allclose(B[k], fb, atol=2e-3, err_msg=f"B_{k}")
    f = pinc.casadi.step_function(p)
    x, v = ca.MX.sym("x", 9), ca.MX.sym("u", 4)
    jac = ca.Function("jacobians", [x, v], [ca.jacobian(f(x, v), x), ca.jacobian(f(x, v), v)])
    a, b = (np.asarray(m) for m in jac(X[3], u[3]))
    _, A3, B3 = p.linearise(X[3], u[3][None, :])
    np.testing.assert_array_equal(a, A3[0])
    np.testing.assert_array_equal(b, B3[0])
    np.testing.assert_array_equal(np.asarray(f(X[3], u[3])).ravel(), p.step(X[3], u[3]))
