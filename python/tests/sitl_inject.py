"""A second ground station beside pinc on ArduSub's simulator: runs a client command and, while
it runs, sets simulator parameters (the faults ArduSub's SITL can inject) at given times after
the autopilot first reports armed. Each setting, the autopilot's echo (PARAM_VALUE) and the
autopilot's boot time then go to a JSON-lines log. Meant to run inside run_in_netns.sh's
namespace, on the simulator's third port (SERIAL2, 5763), so it never shares pinc's link.

usage: sitl_inject.py --log FILE [--port 5763] [--at SECONDS NAME VALUE]... -- CLIENT [ARGS...]
Exits with the client's status.
"""

import argparse
import json
import subprocess
import sys
import time

from ground_station import connect
from pymavlink import mavutil


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--log", required=True)
    p.add_argument("--port", type=int, default=5763)
    p.add_argument("--at", nargs=3, action="append", default=[], metavar=("SECONDS", "NAME", "VALUE"))
    p.add_argument("client", nargs=argparse.REMAINDER)
    a = p.parse_args()
    client = a.client[1:] if a.client and a.client[0] == "--" else a.client
    proc = subprocess.Popen(client)
    faults = sorted((float(s), n, float(v)) for s, n, v in a.at)
    log = open(a.log, "w")
    m = connect(a.port, proc)
    armed_at = None
    boot_s = None
    while proc.poll() is None and m is not None:
        msg = m.recv_match(blocking=True, timeout=0.05)
        if msg is not None:
            kind = msg.get_type()
            if kind in ("ATTITUDE", "SYSTEM_TIME") and getattr(msg, "time_boot_ms", 0):
                boot_s = msg.time_boot_ms / 1000.0
            if kind == "HEARTBEAT" and msg.get_srcSystem() == 1 and armed_at is None:
                if msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED:
                    armed_at = time.monotonic()
                    log.write(json.dumps({"event": "armed", "boot_s": boot_s}) + "\n")
                    log.flush()
            if kind == "PARAM_VALUE":
                log.write(json.dumps({"event": "param_value", "name": msg.param_id, "value": msg.param_value,
                                      "boot_s": boot_s}) + "\n")
                log.flush()
        if armed_at is not None and faults and time.monotonic() - armed_at >= faults[0][0]:
            _, name, value = faults.pop(0)
            m.mav.param_set_send(1, 1, name.encode(), value, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            log.write(json.dumps({"event": "param_set", "name": name, "value": value, "boot_s": boot_s,
                                  "after_arming_s": time.monotonic() - armed_at}) + "\n")
            log.flush()
    return proc.wait()


if __name__ == "__main__":
    sys.exit(main())
