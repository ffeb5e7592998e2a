"""The predictor as CasADi Functions with exact Jacobians.

    import casadi as ca, pinc, pinc.casadi
    p = pinc.Predictor("models/mpc_pinc.pinc")
    f = pinc.casadi.step_function(p)            # f(x[9], u[4]) -> x_next[9]
    F = pinc.casadi.rollout_function(p, 20)     # F(x0[9], U[4 x 20]) -> X[9 x 21]

Both are `casadi.Callback`s whose Jacobians come from the runtime's exact A_k, B_k (no
finite differences, no automatic differentiation through Python). Keep the returned object
alive while CasADi functions built from it are in use.
"""

import casadi as ca
import numpy as np

NX, NU = 9, 4


class _StepJacobian(ca.Callback):
    """[df/dx, df/du] of one step, as CasADi asks for it: inputs (x, u, f), outputs the two
    dense blocks."""

    def __init__(self, name, predictor, opts=None):
        ca.Callback.__init__(self)
        self.p = predictor
        self.construct(name, opts or {})

    def get_n_in(self):
        return 3

    def get_n_out(self):
        return 2

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(NX if i in (0, 2) else NU, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(NX, NX if i == 0 else NU)

    def eval(self, arg):
        x, u = np.asarray(arg[0]).ravel(), np.asarray(arg[1]).ravel()
        _, a, b = self.p.linearise(x, u[None, :])
        return [ca.DM(a[0]), ca.DM(b[0])]


class StepFunction(ca.Callback):
    """x_next = f(x, u) over the model's sample period."""

    def __init__(self, name, predictor, opts=None):
        ca.Callback.__init__(self)
        self.p = predictor
        self._jac = None
        self.construct(name, opts or {})

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(NX if i == 0 else NU, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(NX, 1)

    def eval(self, arg):
        x, u = np.asarray(arg[0]).ravel(), np.asarray(arg[1]).ravel()
        return [ca.DM(self.p.step(x, u))]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self._jac = _StepJacobian(name, self.p, opts)
        return self._jac


class _RolloutJacobian(ca.Callback):
    def __init__(self, name, predictor, n, opts=None):
        ca.Callback.__init__(self)
        self.p, self.n = predictor, n
        self.construct(name, opts or {})

    def get_n_in(self):
        return 3

    def get_n_out(self):
        return 2

    def get_sparsity_in(self, i):
        return [ca.Sparsity.dense(NX, 1), ca.Sparsity.dense(NU, self.n), ca.Sparsity.dense(NX, self.n + 1)][i]

    def get_sparsity_out(self, i):
        cols = NX if i == 0 else NU * self.n
        return ca.Sparsity.dense(NX * (self.n + 1), cols)

    def eval(self, arg):
        x0 = np.asarray(arg[0]).ravel()
        u = np.asarray(arg[1]).reshape((NU, self.n), order="F").T
        _, a, b = self.p.linearise(x0, u)
        n = self.n
        # CasADi vectorises matrices column-major: X[9 x (n+1)] -> entry (i, k) at k*9 + i,
        # U[4 x n] -> entry (j, k) at k*4 + j.
        dx0 = np.zeros((NX * (n + 1), NX))
        du = np.zeros((NX * (n + 1), NU * n))
        dx0[:NX] = np.eye(NX)
        for k in range(n):
            dx0[NX * (k + 1) : NX * (k + 2)] = a[k] @ dx0[NX * k : NX * (k + 1)]
            du[NX * (k + 1) : NX * (k + 2)] = a[k] @ du[NX * k : NX * (k + 1)]
            du[NX * (k + 1) : NX * (k + 2), NU * k : NU * (k + 1)] = b[k]
        return [ca.DM(dx0), ca.DM(du)]


class RolloutFunction(ca.Callback):
    """X = F(x0, U): the N-step rollout, X[:, 0] = x0, U with one column per step."""

    def __init__(self, name, predictor, n, opts=None):
        ca.Callback.__init__(self)
        self.p, self.n = predictor, n
        self._jac = None
        self.construct(name, opts or {})

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(NX, 1) if i == 0 else ca.Sparsity.dense(NU, self.n)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(NX, self.n + 1)

    def eval(self, arg):
        x0 = np.asarray(arg[0]).ravel()
        u = np.asarray(arg[1]).reshape((NU, self.n), order="F").T
        return [ca.DM(self.p.rollout(x0, u).T)]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self._jac = _RolloutJacobian(name, self.p, self.n, opts)
        return self._jac


def step_function(predictor, name="pinc_step"):
    """One step of `predictor` as a CasADi Function f(x[9], u[4]) -> x_next[9]."""
    return StepFunction(name, predictor)


def rollout_function(predictor, n, name="pinc_rollout"):
    """The n-step rollout as a CasADi Function F(x0[9], U[4 x n]) -> X[9 x (n+1)]."""
    return RolloutFunction(name, predictor, n)
