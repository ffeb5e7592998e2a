"""Speed-up of a two-node loopback Ray cluster over one node, and the per-task overhead Ray
adds to a closed-loop run (docs/DISTRIBUTED.md). Run from the repository root:
python3 python/examples/ray_speedup.py [runs]"""

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

from pinc import closed_loop, distributed

RUNS = int(sys.argv[1]) if len(sys.argv) > 1 else 40
S = closed_loop.settings(scenario="disturbed", duration=16.0, solver_time_limit=5.0)
RAY = os.path.join(os.path.dirname(sys.executable), "ray")
PORT = "26380"
common = ["--num-cpus=1", "--node-ip-address=127.0.0.1", "--disable-usage-stats"]


def ray(*a):
    subprocess.run([RAY, *a], check=True, capture_output=True, timeout=120)


def campaign():
    d = tempfile.mkdtemp()
    t = time.perf_counter()
    r = distributed.monte_carlo(S, RUNS, address=f"127.0.0.1:{PORT}", out_dir=d, progress=False, quiet=True)
    wall = time.perf_counter() - t
    lines = [json.loads(x) for x in open(os.path.join(d, "mpc_disturbed_monte_carlo.jsonl")).read().splitlines()[1:]]
    shutil.rmtree(d)
    return wall, sum(x["run_s"] for x in lines), r


# In this process, no Ray: the runs' own time.
closed_loop.run(S, seed=0)  # load once
t = time.perf_counter()
for k in range(RUNS):
    closed_loop.run(S, seed=k, controller="pinc")
    closed_loop.run(S, seed=k, controller="oracle")
plain = time.perf_counter() - t
ray("start", "--head", f"--port={PORT}", "--include-dashboard=false", *common)
try:
    one, one_runs, _ = campaign()
    ray("start", f"--address=127.0.0.1:{PORT}", *common)
    time.sleep(3)
    two, two_runs, _ = campaign()
finally:
    ray("stop", "--force")
print(f"{RUNS} run pairs: plain loop {plain:.1f} s; one node {one:.1f} s (tasks' own time {one_runs:.1f} s); "
      f"two nodes {two:.1f} s (tasks' own time {two_runs:.1f} s)")
print(f"speed-up two nodes / one node: {one / two:.2f}x")
print(f"per-task overhead on one node: (wall - plain loop) / runs = {(one - plain) / RUNS * 1e3:.0f} ms; "
      f"(wall - tasks' own time) / runs = {(one - one_runs) / RUNS * 1e3:.0f} ms")
