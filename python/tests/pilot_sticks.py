"""A scripted pilot for `mpc_track --connect --pilot -`: runs the client with its stdin a pipe,
watches its stderr for the moment control starts ("control starts ..."), and from then writes
the sticks as a gamepad page would, one JSON object per line at --rate Hz: each --stick
FROM,TO,SURGE,SWAY,HEAVE,YAW (s after control starts, each axis -1..1) while it lasts, centred
sticks between them. With --burst each reading goes twice, 1 ms apart (a browser polling its
gamepad under load, a burst passed on at once). Every line it wrote goes to --record with the
host time it went (JSON lines), so a test knows when each stick was let go. The client's stderr
is passed on.

usage: pilot_sticks.py --record FILE [--rate HZ] [--burst] [--stick F,T,U,V,W,R]... -- CLIENT [ARGS...]
Exits with the client's status.
"""

import argparse
import json
import subprocess
import sys
import threading
import time


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--record", required=True)
    p.add_argument("--rate", type=float, default=10.0)
    p.add_argument("--stick", action="append", default=[])
    p.add_argument("--burst", action="store_true")
    p.add_argument("client", nargs=argparse.REMAINDER)
    a = p.parse_args()
    client = a.client[1:] if a.client[:1] == ["--"] else a.client
    segments = [[float(x) for x in s.split(",")] for s in a.stick]
    child = subprocess.Popen(client, stdin=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1)
    started = threading.Event()

    def watch():
        for line in child.stderr:
            sys.stderr.write(line)
            if line.startswith("control starts"):
                started.set()

    threading.Thread(target=watch, daemon=True).start()
    with open(a.record, "w") as record:
        while not started.is_set() and child.poll() is None:
            time.sleep(0.02)
        t0 = time.monotonic()
        k = 0
        while child.poll() is None:
            t = time.monotonic() - t0
            axes = next((s[2:] for s in segments if s[0] <= t < s[1]), [0.0, 0.0, 0.0, 0.0])
            line = json.dumps(dict(zip(("surge", "sway", "heave", "yaw"), axes)))
            try:
                for _ in range(2 if a.burst else 1):
                    child.stdin.write(line + "\n")
                    child.stdin.flush()
                    time.sleep(0.001)
            except (BrokenPipeError, ValueError):
                break
            record.write(json.dumps({"t": t, "sticks": axes}) + "\n")
            k += 1
            time.sleep(max(0.0, t0 + k / a.rate - time.monotonic()))
    sys.exit(child.wait())


if __name__ == "__main__":
    main()
