"""pinc: the PINC predictor of an underwater vehicle, from Python.

    import pinc
    p = pinc.Predictor("models/mpc_pinc_thrust.pinc")
    X, A, B = p.linearise(x0, U)        # exact Jacobians of the horizon

States are the network form [x, y, z, cos psi, sin psi, u, v, w, r], inputs [X, Y, Z, Mz];
`simulate` is the analytic vehicle in the 8-state form [x, y, z, psi, u, v, w, r].
`pinc.closed_loop` runs one closed loop (as `mpc_track` does); `pinc.distributed` runs
Monte-Carlo campaigns and training sweeps on a Ray cluster (`pip install "./python[ray]"`).
"""

from . import closed_loop
from ._pinc import PincError, Predictor, simulate

__all__ = ["PincError", "Predictor", "closed_loop", "simulate"]
