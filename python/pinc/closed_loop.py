"""One closed-loop run from Python, through the same Rust code path as `mpc_track`.

    import pinc.closed_loop as cl
    s = cl.settings(model="models/mpc_pinc_thrust.pinc", scenario="disturbed", duration=30)
    cl.run(s, seed=7)                  # run 7 of `mpc_track --monte-carlo` (PINC controller)
    cl.run(s, seed=7, controller="oracle")
    cl.run(s)                          # no perturbation: the summary of `mpc_track --json`
    cl.draw(s, seed=7)                 # the perturbed plant of seed 7

Settings are a plain dict (the flags of `mpc_track`), so they travel to other machines as
they are; file paths in them are read where the run happens.
"""

import json
import math
import os

from ._pinc import ClosedLoop

CONTROLLERS = ("pinc", "oracle")

_DEFAULTS = {
    "model": "models/mpc_pinc_thrust.pinc",
    "vehicle": None,
    "scenario": "default",
    "reference": None,
    "path": None,
    "path_frame": None,
    "survey": None,
    "path_heading": None,
    "current": None,
    "max_distance": None,
    "duration": None,
    "horizon": 20,
    "disturbance_gain": None,
    "envelope_constraints": True,
    "envelope_penalty": None,
    "envelope_margin": None,
    "input_rate": None,
    "solver_time_limit": None,
    "condensing_block": None,
    "sparse_qp": None,
    "qp": None,
}


def settings(**kw):
    """Closed-loop settings: `mpc_track`'s flags as keys (model, vehicle, scenario: "default",
    "disturbed", "station" or "survey"; reference; path: a waypoint CSV, path_frame: "start"
    or "origin"; survey: [width, length, spacing, speed, depth]; path_heading (deg, else along
    the track); current: [north, east] m/s; max_distance (m); duration, horizon, disturbance_gain, envelope_constraints, envelope_penalty,
    envelope_margin, input_rate, solver_time_limit, condensing_block, sparse_qp, qp: "riccati" (the
    default) or "clarabel"). Unset keys keep `mpc_track`'s defaults."""
    unknown = sorted(set(kw) - set(_DEFAULTS))
    if unknown:
        raise ValueError(f"settings: unknown key(s) {unknown} (known: {sorted(_DEFAULTS)})")
    s = {k: v for k, v in {**_DEFAULTS, **kw}.items() if v is not None}
    for k in ("model", "vehicle", "reference", "path"):
        if k in s:
            s[k] = os.fspath(s[k])
    for k in ("input_rate", "survey", "current"):
        if k in s:
            s[k] = [float(x) for x in s[k]]
    return s


def settings_json(s):
    """`s` as the JSON the Rust side reads (keys sorted, so equal settings give equal text)."""
    return json.dumps(settings(**s), sort_keys=True)


_cache = {}


def campaign(s):
    """The loaded campaign of settings `s` (cached per process: a Ray worker loads the model
    once for all its runs)."""
    key = settings_json(s)
    c = _cache.get(key)
    if c is None:
        c = _cache[key] = ClosedLoop(key)
    return c


def _outcome(text):
    o = json.loads(text)
    for k in ("rms_depth_m", "rms_heading_deg"):
        if o[k] is None:
            o[k] = math.inf
    return o


def run(s, seed=None, controller="pinc"):
    """One closed-loop run. With `seed`: the Monte-Carlo run of that seed (the plant drawn
    as `mpc_track --monte-carlo` draws it, sensor noise from the seed) -> dict with seed,
    success, failure, rms_depth_m, rms_heading_deg, solve_ms (per cycle). Without: the
    nominal run's summary dict (the figures of `mpc_track --json`)."""
    if controller not in CONTROLLERS:
        raise ValueError(f"controller: {controller!r} is neither of {CONTROLLERS}")
    c = campaign(s)
    if seed is None:
        return json.loads(c.nominal_run(controller))
    return _outcome(c.monte_carlo_run(int(seed), controller))


def draw(s, seed):
    """The perturbed plant of `seed`: {"seed", "vehicle": {coefficients}, "current": [x, y]}."""
    return json.loads(campaign(s).draw(int(seed)))
