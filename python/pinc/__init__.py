"""pinc: the PINC predictor of an underwater vehicle, from Python.

    import pinc
    p = pinc.Predictor("models/mpc_pinc_thrust.pinc")
    X, A, B = p.linearise(x0, U)        # exact Jacobians of the horizon

States are the network form [x, y, z, cos psi, sin psi, u, v, w, r], inputs [X, Y, Z, Mz];
`simulate` is the analytic vehicle in the 8-state form [x, y, z, psi, u, v, w, r].
"""

from ._pinc import PincError, Predictor, simulate

__all__ = ["PincError", "Predictor", "simulate"]
