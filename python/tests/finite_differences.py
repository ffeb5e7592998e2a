"""Central differences of a predictor's step, which the Jacobian tests compare with."""

import numpy as np


def central_differences(p, x, u, h=1e-3):
    """d step / d x (9 x 9) and d step / d u (9 x 4) of predictor `p` at (x, u)."""
    fa = np.stack([(p.step(x + h * e, u) - p.step(x - h * e, u)) / (2 * h) for e in np.eye(9)], axis=1)
    fb = np.stack([(p.step(x, u + h * e) - p.step(x, u - h * e)) / (2 * h) for e in np.eye(4)], axis=1)
    return fa, fb
