"""The controller built for a 32-bit Raspberry Pi flies ArduSub's firmware as the x86 build does.

`dist/linux-arm-v7/mpc_track` (scripts/cross_build.sh, with the live link) runs under qemu's user
emulation against ArduSub's simulator (4.8.0-dev, ../shared/ardusub_sitl, in a private network
namespace), beside target/release/mpc_track flying the same way against a second simulator at the
same time (CI time: one flight's). Both fly 60 s of the default references on a stock vehicle (no
GPS, no DVL, the stock joystick gain: the fit tests' parameters) with the model `pinc fit` makes of
the stock recording fixture, as test_ardusub_fit.py does. Closed loops on the firmware are not
bit-repeatable (TCP timing, the simulator's noise): their figures must agree within 10 %. No cycle
may miss its deadline (the 80 ms sample period) under emulation either.

Why: test_cross_platform.py shows the ARM builds compute what x86 computes on the simulated plant;
this adds the link, the estimator and the fitted model on the real autopilot, in real time. The
cycle times under qemu are printed for the record; they are an emulator's on this machine, not a
Pi's (docs/BLUEOS.md).

Needs: $PINC_ARDUSUB_SITL, target/release/pinc and mpc_track (`--features vehicle`, pinc with
`train` for the fit), dist/linux-arm-v7/mpc_track, qemu-arm-static and the armhf C library
(/usr/arm-linux-gnueabihf). Skips, saying which, where one is missing: CI's clean clone has no
dist/ (the cross build is a separate step, docs/BLUEOS.md).
"""

import json
import re
import shutil
from concurrent.futures import ThreadPoolExecutor

from test_cross_platform import emulated
# test_ardusub_sitl skips the module where $PINC_ARDUSUB_SITL is not set.
from test_ardusub_sitl import run_on_firmware
from test_ardusub_fit import STOCK_GAIN, STOCK_RECORDING, pinc_fit
from test_vehicle_drive import mpc_track_binary

# The summaries' figures compared between the builds: (label, path in the JSON).
FIGURES = (
    ("RMS depth (truth), m", ("live", "truth_rms", "depth_m")),
    ("RMS heading (truth), deg", ("live", "truth_rms", "heading_deg")),
    ("RMS depth (estimate), m", ("rms_depth_m",)),
    ("RMS heading (autopilot's), deg", ("rms_heading_deg",)),
)
TOLERANCE = 0.10


def figure(summary, path):
    for key in path:
        summary = summary[key]
    return summary


def fly_build(command, out_dir, model):
    """`fly` of test_ardusub_live.py (the same client flags, a fitted model, no vehicle file, the
    stock parameters) with the controller's command given, under /usr/bin/time -v where there is
    one: the summary, the run and the largest resident set (MiB, or None)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    timing = out_dir / "time.txt"
    time_v = ["/usr/bin/time", "-v", "-o", str(timing)] if shutil.which("/usr/bin/time") else []
    client = [*time_v, *map(str, command), "--connect", "tcp:127.0.0.1:5760", "--arm", "--sim-truth", "--json",
              "--out-dir", str(out_dir), "--timeout", "30", "--model", str(model)]
    r = run_on_firmware(out_dir, STOCK_GAIN, client)
    assert r.stdout.strip(), f"mpc_track printed no summary (exit {r.returncode}): {r.stderr[-3000:]}"
    rss = None
    if timing.is_file():
        found = re.search(r"Maximum resident set size \(kbytes\): (\d+)", timing.read_text())
        rss = int(found.group(1)) / 1024 if found else None
    return json.loads(r.stdout), r, rss


def test_armv7_under_qemu_flies_the_fitted_model_on_the_firmware_like_x86(tmp_path_factory):
    arm_command = emulated("linux-arm-v7", "mpc_track")
    x86_command = [mpc_track_binary()]
    root = tmp_path_factory.mktemp("cross_firmware")
    pinc_fit(STOCK_RECORDING, root / "fitted")
    model = root / "fitted" / "model.pinc"
    with ThreadPoolExecutor(2) as pool:
        futures = {who: pool.submit(fly_build, command, root / who, model)
                   for who, command in (("x86", x86_command), ("armv7", arm_command))}
        runs = {who: f.result() for who, f in futures.items()}
    for who, (s, r, rss) in runs.items():
        assert s["stopped"] is None and r.returncode == 0, (who, r.stderr[-3000:])
        assert s["samples"] >= 740, (who, s["samples"])
        assert s["live"]["js_gain"] == 0.5, who
        latency = s["live"]["latency_ms"]
        print(f"\n{who:6s} " + ", ".join(f"{label} {figure(s, path):.4g}" for label, path in FIGURES))
        print(f"{who:6s} cycle median {s['cycle_ms_median']:.2f} ms, p99 {s['cycle_ms_p99']:.2f} ms; solve median "
              f"{s['solve_ms_median']:.2f}, p99 {s['solve_ms_p99']:.2f}, max {s['solve_ms_max']:.2f} ms; "
              f"arrival to send median {latency['median']:.2f}, p99 {latency['p99']:.2f}, max {latency['max']:.2f} ms; "
              f"deadline misses {s['deadline_misses']}, fallbacks {s['fallbacks']}; "
              f"max resident {'-' if rss is None else f'{rss:.1f} MiB'}"
              + (" (under qemu: an emulator's times, not a Pi's)" if who == "armv7" else ""))
    x86, arm = runs["x86"][0], runs["armv7"][0]
    for who, s in (("x86", x86), ("armv7", arm)):
        assert s["deadline_misses"] == 0, (who, s["deadline_misses"], s["cycle_ms_p99"])
    for label, path in FIGURES:
        a, b = figure(arm, path), figure(x86, path)
        assert abs(a - b) <= TOLERANCE * abs(b), f"{label}: armv7 {a} against x86 {b}"
