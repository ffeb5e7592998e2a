"""The Python bindings against the Rust command line, finite differences, single rollouts,
and their errors."""

import subprocess
from pathlib import Path

import numpy as np
import pytest

import pinc
from finite_differences import central_differences

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "models" / "mpc_pinc.pinc"
CLI = ROOT / "target" / "release" / "pinc"


def cli(*args):
    assert CLI.exists(), f"{CLI} is built by `cargo test --release` (the README's test command runs it first)"
    out = subprocess.run([str(CLI), *map(str, args)], capture_output=True, text=True, check=True)
    rows = [line.split(",") for line in out.stdout.splitlines()[1:]]
    return np.array(rows, dtype=float)


def inputs(n, phase=0.0):
    k = np.arange(n)
    return np.stack([4 * np.sin(0.3 * k + phase), 0.5 + 0 * k, 3 + 0.1 * k, 0.2 * np.cos(0.2 * k)], axis=1)


@pytest.fixture(scope="module")
def p():
    return pinc.Predictor(str(MODEL))


def to_network(s):
    return np.array([s[0], s[1], s[2], np.cos(s[3]), np.sin(s[3]), *s[4:]])


def test_rollout_equals_pinc_predict(p, tmp_path):
    u = inputs(30)
    csv = tmp_path / "u.csv"
    np.savetxt(csv, u, delimiter=",", header="X,Y,Z,Mz", comments="", fmt="%.17g")
    s0 = [0.1, -0.2, 1.0, 0.7, 0.3, 0.0, 0.05, 0.1]
    expected = cli("predict", "--model", MODEL, "--x0", ",".join(map(str, s0)), "--inputs", csv)
    got = p.rollout(to_network(s0), u)
    assert got.shape == (31, 9)
    # Positions and velocities are the same doubles; psi goes through atan2 on both sides.
    np.testing.assert_array_equal(got[:, [0, 1, 2, 5, 6, 7, 8]], expected[:, [1, 2, 3, 5, 6, 7, 8]])
    np.testing.assert_allclose(np.arctan2(got[:, 4], got[:, 3]), expected[:, 4], rtol=0, atol=1e-15)


def test_simulate_equals_pinc_simulate(tmp_path):
    u = inputs(25)
    csv = tmp_path / "u.csv"
    np.savetxt(csv, u, delimiter=",", header="X,Y,Z,Mz", comments="", fmt="%.17g")
    s0 = [0.0, 0.0, 0.5, -2.0, 0.2, 0.0, 0.0, 0.1]
    expected = cli("simulate", "--x0", ",".join(map(str, s0)), "--inputs", csv, "--dt", 0.1)
    np.testing.assert_array_equal(pinc.simulate(s0, u, dt=0.1), expected[:, 1:])


def test_simulate_takes_vehicle_overrides():
    u = np.zeros((20, 4))
    s0 = np.zeros(8)
    light = pinc.simulate(s0, u, vehicle={"m": 10.0})
    default = pinc.simulate(s0, u)
    # Lighter than the BlueROV2 and as buoyant: it rises faster (z decreases).
    assert light[-1, 2] < default[-1, 2] < 0
    with pytest.raises(ValueError, match="unknown parameter \"mass\""):
        pinc.simulate(s0, u, vehicle={"mass": 10.0})


def test_jacobians_match_central_differences(p):
    x0 = to_network([0.0, 0.0, 1.0, 0.5, 0.2, 0.05, 0.1, 0.1])
    u = inputs(10)
    X, A, B = p.linearise(x0, u)
    assert (X.shape, A.shape, B.shape) == ((11, 9), (10, 9, 9), (10, 9, 4))
    np.testing.assert_array_equal(X, p.rollout(x0, u))
    # The network computes in f32: central differences with h = 1e-3 are good to ~1e-4.
    for k in [0, 4, 9]:
        fa, fb = central_differences(p, X[k], u[k], h=1e-3)
        np.testing.assert_allclose(A[k], fa, atol=2e-3, err_msg=f"A_{k}")
        np.testing.assert_allclose(B[k], fb, atol=2e-3, err_msg=f"B_{k}")
    # Position-free model: x, y, z enter through the identity only.
    np.testing.assert_array_equal(A[:, :3, :3], np.broadcast_to(np.eye(3), (10, 3, 3)))


def test_batch_equals_single_rollouts(p):
    x0 = np.array([to_network([0, 0, 1.0, 0.3 * i, 0.1, 0, 0, 0.05 * i]) for i in range(40)])
    ub = np.stack([inputs(25, phase=0.1 * i) for i in range(40)])
    xb = p.rollout_batch(x0, ub)
    assert xb.shape == (40, 26, 9)
    for i in range(40):
        # Another summation order in f32: equal to rounding.
        np.testing.assert_allclose(xb[i], p.rollout(x0[i], ub[i]), rtol=0, atol=1e-5)


def test_step_takes_array_likes_and_dt(p):
    x = [0, 0, 1, 1, 0, 0.2, 0, 0, 0]
    u = (2, 0, 5, 0.1)
    assert p.step(x, u).shape == (9,)
    np.testing.assert_array_equal(p.step(x, u), p.step(np.array(x), np.array(u), dt=p.dt))
    assert not np.array_equal(p.step(x, u, dt=0.06), p.step(x, u))
    assert p.dt == 0.08


def test_step_into_writes_steps_result_into_the_callers_array(p):
    x = np.array([0, 0, 1, 1, 0, 0.2, 0, 0, 0], dtype=float)
    u = np.array([2, 0, 5, 0.1])
    out = np.full(9, np.nan)
    assert p.step_into(x, u, out) is None
    np.testing.assert_array_equal(out, p.step(x, u))
    p.step_into(x, u, out, dt=0.06)
    np.testing.assert_array_equal(out, p.step(x, u, dt=0.06))
    # A row of a 2-D buffer is a contiguous (9,) view: a rollout written in place.
    traj = np.zeros((4, 9))
    traj[0] = x
    for k in range(3):
        p.step_into(traj[k], u, traj[k + 1])
    np.testing.assert_allclose(traj, p.rollout(x, np.tile(u, (3, 1))), rtol=0, atol=1e-12)


def test_step_into_refuses_what_it_cannot_write_or_read(p):
    x, u = np.zeros(9), np.zeros(4)
    x[3] = 1.0
    with pytest.raises(ValueError, match=r"out: expected shape \(9\), got \(8\)"):
        p.step_into(x, u, np.zeros(8))
    with pytest.raises(ValueError, match=r"u: expected shape \(4\), got \(3\)"):
        p.step_into(x, np.zeros(3), np.zeros(9))
    with pytest.raises(ValueError, match=r"x\[2\] = NaN is not finite"):
        p.step_into(np.array([0, 0, np.nan, 1, 0, 0, 0, 0, 0]), u, np.zeros(9))
    with pytest.raises(TypeError, match="contiguous"):
        p.step_into(x, u, np.zeros(18)[::2])
    with pytest.raises(TypeError, match="out: expected a 1-D numpy array of float64"):
        p.step_into(x, u, np.zeros(9, dtype=np.float32))
    with pytest.raises(TypeError, match="x: expected a 1-D numpy array of float64"):
        p.step_into(x.astype(">f8"), u, np.zeros(9))
    with pytest.raises(TypeError, match="u: expected a 1-D numpy array of float64"):
        p.step_into(x, u.reshape(4, 1), np.zeros(9))
    with pytest.raises(TypeError):
        p.step_into(list(x), u, np.zeros(9))
    out = np.zeros(9)
    out.flags.writeable = False
    with pytest.raises(ValueError, match="out: the array is read-only"):
        p.step_into(x, u, out)
    # `out` may be `x` itself: the state steps in place.
    y = x.copy()
    p.step_into(y, u, y)
    np.testing.assert_array_equal(y, p.step(x, u))


def test_envelope_names_every_component(p):
    e = p.envelope
    assert list(e) == ["x", "y", "z", "cos_psi", "sin_psi", "u", "v", "w", "r", "X", "Y", "Z", "Mz"]
    assert e["X"] == (-10.0, 10.0)


def test_bad_arguments_are_value_errors_naming_them(p):
    with pytest.raises(ValueError, match=r"U: expected shape \(N, 4\), got \[5, 3\]"):
        p.rollout(np.zeros(9), np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"x\[2\] = NaN is not finite"):
        p.step([0, 0, np.nan, 1, 0, 0, 0, 0, 0], [0, 0, 0, 0])
    with pytest.raises(ValueError, match=r"Ub: expected shape \(3, N, 4\)"):
        p.rollout_batch(np.zeros((3, 9)), np.zeros((2, 5, 4)))
    with pytest.raises(ValueError, match="U: a horizon has at least one step"):
        p.linearise(np.zeros(9), np.zeros((0, 4)))


def test_bad_files_raise_pinc_error(tmp_path):
    with pytest.raises(pinc.PincError, match="no/such.pinc"):
        pinc.Predictor("no/such.pinc")
    corrupt = tmp_path / "corrupt.pinc"
    data = bytearray(MODEL.read_bytes())
    data[len(data) // 2] ^= 0x40
    corrupt.write_bytes(bytes(data))
    with pytest.raises(pinc.PincError, match="checksum"):
        pinc.Predictor(str(corrupt))
    assert issubclass(pinc.PincError, ValueError)


def test_meaningless_vehicle_overrides_are_refused():
    with pytest.raises(ValueError, match="x_ud = 20: the effective mass"):
        pinc.simulate(np.zeros(8), np.zeros((2, 4)), vehicle={"x_ud": 20.0})


def test_heading_vector_rescaled_by_default_bare_on_request_like_the_cli(tmp_path):
    # The full-thrust model under a hard turn: its raw (cos psi, sin psi) drifts off the circle.
    thrust = ROOT / "models" / "mpc_pinc_thrust.pinc"
    s0 = [0, 0, 1, 0, 0.3, 0, 0.1, 0.5]
    U = np.array([[60.0, 0.0, 30.0, 20.0 if k < 20 else -20.0] for k in range(40)])
    on = pinc.Predictor(str(thrust))
    X = on.rollout(to_network(s0), U)
    np.testing.assert_allclose(np.hypot(X[:, 3], X[:, 4]), 1.0, rtol=0, atol=1e-12)
    bare = pinc.Predictor(str(thrust), renormalise_yaw=False)
    Xb = bare.rollout(to_network(s0), U)
    assert bare.last_warnings["heading_off_circle"] > 0
    assert abs(np.hypot(Xb[-1, 3], Xb[-1, 4]) - 1.0) > 0.01
    csv = tmp_path / "u.csv"
    np.savetxt(csv, U, delimiter=",", header="X,Y,Z,Mz", comments="")
    for pred, flags in [(X, []), (Xb, ["--no-renormalise-yaw"])]:
        want = cli("predict", "--model", thrust, "--x0", ",".join(map(str, s0)), "--inputs", csv, *flags)
        np.testing.assert_array_equal(pred[:, [0, 1, 2, 5, 6, 7, 8]], want[:, [1, 2, 3, 5, 6, 7, 8]])
