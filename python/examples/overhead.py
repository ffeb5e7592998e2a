"""Per-call time of the Python bindings, to set beside `cargo bench --bench runtime`.

That bench's `step_shipped` is the Rust call `step_into` makes, on the same model, state and input.

    python3 python/examples/overhead.py [--json]
"""

import argparse
import json
import timeit
from pathlib import Path

import numpy as np

import pinc

ROOT = Path(__file__).resolve().parents[2]


def best_us(stmt, names, number):
    """The fastest of 7 repeats, per call, in microseconds (the least disturbed run).

    `stmt` is source text run in timeit's own loop, so what is timed is the call alone (a
    lambda around it would add its own call, 25 ns here)."""
    return min(timeit.repeat(stmt, globals=names, number=number, repeat=7)) / number * 1e6


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    p = pinc.Predictor(str(ROOT / "models" / "mpc_pinc_thrust.pinc"))
    x = np.array([0.0, 0.0, 1.0, 1.0, 0.0, 0.2, 0.0, 0.05, 0.0])
    u = np.array([2.0, 0.1, 5.0, 0.05])
    out = np.empty(9)
    U20 = np.tile(u, (20, 1))
    U65 = np.tile(u, (65, 1))
    xb, ub = np.tile(x, (1000, 1)), np.tile(U65, (1000, 1, 1))
    names = dict(p=p, x=x, u=u, out=out, U20=U20, U65=U65, xb=xb, ub=ub)
    times = {
        "step_us": best_us("p.step(x, u)", names, 20000),
        "step_into_us": best_us("p.step_into(x, u, out)", names, 20000),
        "rollout_65_us": best_us("p.rollout(x, U65)", names, 2000),
        "linearise_h20_us": best_us("p.linearise(x, U20)", names, 2000),
        "rollout_batch_1000x65_ms": best_us("p.rollout_batch(xb, ub)", names, 5) / 1e3,
    }
    if a.json:
        print(json.dumps(times, indent=2))
    else:
        for k, v in times.items():
            print(f"{k:<26} {v:.2f}")


if __name__ == "__main__":
    main()
