"""pinc: the PINC predictor of an underwater vehicle, from Python.

    import pinc
    p = pinc.Predictor("models/mpc_pinc_thrust.pinc")
    X, A, B = p.linearise(x0, U)        # exact Jacobians of the horizon

States are the network form [x, y, z, cos psi, sin psi, u, v, w, r], inputs [X, Y, Z, Mz];
`simulate` is the analytic vehicle in the 8-state form [x, y, z, psi, u, v, w, r].
`evaluate` scores models on a dataset folder (`pinc dataset import`) from the recorded or the
estimated start of each window, as `pinc eval --data` does.
`pinc.closed_loop` runs one closed loop (as `mpc_track` does); `pinc.distributed` runs
Monte-Carlo campaigns and training sweeps on a Ray cluster (`pip install "./python[ray]"`).
"""

from . import closed_loop
from ._pinc import PincError, Predictor, evaluate, simulate

__all__ = ["PincError", "Predictor", "closed_loop", "evaluate", "simulate"]
