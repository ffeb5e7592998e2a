"""The predictor as CasADi Functions with exact Jacobians.

    import casadi as ca, pinc, pinc.casadi
    p = pinc.Predictor("models/mpc_pinc_thrust.pinc")
    f = pinc.casadi.step_function(p)            # f(x[9], u[4]) -> x_next[9]
    F = pinc.casadi.rollout_function(p, 20)     # F(x0[9], U[4 x 20]) -> X[9 x 21]

Both are `casadi.Callback`s whose Jacobians come from the runtime's exact A_k, B_k (no
finite differences, no automatic differentiation through Python). Keep the returned object
alive while CasADi functions built from it are in use.
"""

import casadi as ca
import numpy as np

NX, NU = 9, 4


class _Callback(ca.Callback):
    """A CasADi callback with dense inputs and outputs of fixed shapes, whose values come
    from `evaluate(*numpy arrays)`; `jacobian`, when given, builds its Jacobian callback."""

    def __init__(self, name, inputs, outputs, evaluate, jacobian=None, opts=None):
        ca.Callback.__init__(self)
        self._inputs, self._outputs = inputs, outputs
        self._evaluate, self._make_jacobian = evaluate, jacobian
        self._jac = None  # CasADi does not own it: kept alive here
        self.construct(name, opts or {})

    def get_n_in(self):
        return len(self._inputs)

    def get_n_out(self):
        return len(self._outputs)

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(*self._inputs[i])

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(*self._outputs[i])

    def eval(self, arg):
        return [ca.DM(v) for v in self._evaluate(*(np.asarray(a) for a in arg))]

    def has_jacobian(self):
        return self._make_jacobian is not None

    def get_jacobian(self, name, inames, onames, opts):
        self._jac = self._make_jacobian(name, opts)
        return self._jac


def _inputs(u, n):
    """CasADi's 4 x n input matrix as numpy's (n, 4) rows."""
    return np.asarray(u).reshape((NU, n), order="F").T


def _rollout_jacobian(predictor, x0, u, n):
    """d X / d x0 and d X / d U of the n-step rollout, with X (9 x (n+1)) and U (4 x n)
    vectorised column-major as CasADi does, from the runtime's A_k, B_k."""
    _, a, b = predictor.linearise(np.asarray(x0).ravel(), _inputs(u, n))
    dx0 = np.zeros((NX * (n + 1), NX))
    du = np.zeros((NX * (n + 1), NU * n))
    dx0[:NX] = np.eye(NX)
    for k in range(n):
        rows, prev = slice(NX * (k + 1), NX * (k + 2)), slice(NX * k, NX * (k + 1))
        dx0[rows] = a[k] @ dx0[prev]
        du[rows] = a[k] @ du[prev]
        du[rows, NU * k : NU * (k + 1)] = b[k]
    return dx0, du


def step_function(predictor, name="pinc_step"):
    """One step of `predictor` as a CasADi Function f(x[9], u[4]) -> x_next[9]."""

    def jacobian(jname, opts):
        # CasADi's Jacobian function takes (x, u, f) and returns [df/dx, df/du].
        def evaluate(x, u, _f):
            _, a, b = predictor.linearise(x.ravel(), u.reshape(1, NU))
            return a[0], b[0]

        return _Callback(jname, [(NX, 1), (NU, 1), (NX, 1)], [(NX, NX), (NX, NU)], evaluate, opts=opts)

    return _Callback(
        name,
        [(NX, 1), (NU, 1)],
        [(NX, 1)],
        lambda x, u: [predictor.step(x.ravel(), u.ravel())],
        jacobian,
    )


def rollout_function(predictor, n, name="pinc_rollout"):
    """The n-step rollout as a CasADi Function F(x0[9], U[4 x n]) -> X[9 x (n+1)]."""

    def jacobian(jname, opts):
        shapes_in = [(NX, 1), (NU, n), (NX, n + 1)]
        shapes_out = [(NX * (n + 1), NX), (NX * (n + 1), NU * n)]
        evaluate = lambda x0, u, _x: _rollout_jacobian(predictor, x0, u, n)  # noqa: E731
        return _Callback(jname, shapes_in, shapes_out, evaluate, opts=opts)

    return _Callback(
        name,
        [(NX, 1), (NU, n)],
        [(NX, n + 1)],
        lambda x0, u: [predictor.rollout(x0.ravel(), _inputs(u, n)).T],
        jacobian,
    )
