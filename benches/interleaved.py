"""Cycle times of `mpc_track` binaries run interleaved on the same machine: one run of each
binary in turn, three rounds, per model and horizon; the median cycle time of each run's 750
cycles, then the median over the rounds. Ratios between binaries measured this way hold on
any machine; absolute times do not.

    python3 benches/interleaved.py --bin old=PATH --bin new=PATH:--qp,riccati [--rounds 3]
        [--horizons 20,40,80] [--out FILE.json]

Each `--bin NAME=PATH[:ARG,ARG...]` runs PATH with those extra arguments; the first binary is
the reference of the printed ratios.
"""

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODELS = {
    "analytic": ["--oracle", "--model", str(ROOT / "models" / "mpc_pinc_thrust.pinc")],
    "shipped": ["--model", str(ROOT / "models" / "mpc_pinc_thrust.pinc")],
    "paper": ["--model", str(ROOT / "models" / "paper_pinc.pinc")],
}


def run(path, extra, model, horizon, out_dir):
    args = [path, *MODELS[model], "--horizon", str(horizon), "--json", "--out-dir", out_dir, *extra]
    p = subprocess.run(args, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"{' '.join(args)} failed:\n{p.stderr}")
    s = json.loads(p.stdout)
    return {k: s[k] for k in ("cycle_ms_median", "solve_ms_median", "fallbacks", "rms_depth_m", "rms_heading_deg")}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", action="append", required=True, help="NAME=PATH[:ARG,ARG...]")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--horizons", default="20,40,80")
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    bins = []
    for b in a.bin:
        name, _, rest = b.partition("=")
        path, _, extra = rest.partition(":")
        bins.append((name, path, [x for x in extra.split(",") if x]))
    rows = []
    with tempfile.TemporaryDirectory() as out_dir:
        for model in a.models.split(","):
            for horizon in map(int, a.horizons.split(",")):
                runs = {name: [] for name, _, _ in bins}
                for _ in range(a.rounds):
                    for name, path, extra in bins:
                        runs[name].append(run(path, extra, model, horizon, out_dir))
                row = {"model": model, "horizon": horizon}
                for name, results in runs.items():
                    row[name] = {
                        "cycle_ms": statistics.median(r["cycle_ms_median"] for r in results),
                        "solve_ms": statistics.median(r["solve_ms_median"] for r in results),
                        "fallbacks": max(r["fallbacks"] for r in results),
                        "rms": [results[0]["rms_depth_m"], results[0]["rms_heading_deg"]],
                    }
                ref = row[bins[0][0]]["cycle_ms"]
                ratios = ", ".join(f"{n}/{bins[0][0]} {row[n]['cycle_ms'] / ref:.3f}" for n, _, _ in bins[1:])
                cycles = ", ".join(f"{n} {row[n]['cycle_ms']:.3f} ms" for n, _, _ in bins)
                print(f"{model:8} N = {horizon:3}: {cycles}; {ratios}", flush=True)
                rows.append(row)
    if a.out:
        a.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
