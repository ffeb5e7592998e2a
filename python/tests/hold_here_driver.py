"""Cockpit's "hold here" on the firmware, as an owner presses it: a router stand-in
(mavlink_hub.py, BlueOS's 127.0.0.1:5777) on the autopilot, a Cockpit stand-in on it (system 255:
heartbeats at 1 Hz, MANUAL_CONTROL at 25 Hz, its own truth from SIM_STATE and SIMSTATE), and
`pinc serve` on the router like the extension. The pilot arms, takes ALT_HOLD, waits for the
autopilot's position, dives to --depth on the stick and turns to --heading (ALT_HOLD's attitude
target), lets go for 3 s (the current carries the vehicle), then sends Cockpit's "hold here" action as Cockpit does (its URL, headers and
body from cockpit_extras.json, `Origin: file://` as Cockpit desktop's fetch) and, --hold seconds
later, "resume". Then it reads the autopilot back: its mode, armed, its ground station id.

Recorded in --record (JSON): the truth every SIM_STATE (host time, north and east of the first
position (m), depth (m), heading (deg)), the press's and resume's host times and answers, the
mode, armed flag and ground station id after resume, and pinc serve's log.

usage: hold_here_driver.py --record FILE --pinc PINC --data DIR [--depth D] [--heading H]
       [--hold S] [--run-arg ARG]...
"""

import argparse
import json
import math
import re
import subprocess
import threading
import time
import urllib.error
import urllib.request

from mavlink_hub import Hub
from pymavlink import mavutil

PARAM = "MAV_GCS_SYSID"  # this firmware's name for the ground station id
ALT_HOLD, MANUAL = 2, 19
ROUTER_PORT = 5777


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--record", required=True)
    p.add_argument("--pinc", required=True)
    p.add_argument("--data", required=True)
    p.add_argument("--depth", type=float, default=2.5)
    p.add_argument("--heading", type=float, default=120.0)
    p.add_argument("--hold", type=float, default=45.0)
    p.add_argument("--run-arg", action="append", default=[])
    a = p.parse_args()

    Hub(("127.0.0.1", 5760), ROUTER_PORT)
    gcs = mavutil.mavlink_connection(f"tcp:127.0.0.1:{ROUTER_PORT}", source_system=255, source_component=240)
    gcs.wait_heartbeat(timeout=60)
    target = gcs.target_system
    sending = threading.Lock()
    done = threading.Event()
    st = {"sticks": (0, 0, 500, 0), "truth": [], "mode": None, "armed": None, "gcs_id": [], "origin": None,
          "ekf_flags": 0, "texts": []}

    def send(f, *args):
        with sending:
            f(*args)

    for msg_id in (108, 164, 24):  # SIM_STATE, SIMSTATE, GPS_RAW_INT
        send(gcs.mav.command_long_send, target, 1, 511, 0, msg_id, 50000, 0, 0, 0, 0, 0)
    send(gcs.mav.command_long_send, target, 1, 511, 0, 193, 500000, 0, 0, 0, 0, 0)  # EKF_STATUS_REPORT

    def listen():
        lat_lon = None
        while not done.is_set():
            m = gcs.recv_match(blocking=True, timeout=0.2)
            if m is None or m.get_srcSystem() != target:
                continue
            kind = m.get_type()
            if kind == "HEARTBEAT" and m.type == 12:
                st["mode"], st["armed"] = m.custom_mode, bool(m.base_mode & 128)
            elif kind == "SIMSTATE":
                lat_lon = (m.lat * 1e-7, m.lng * 1e-7)
            elif kind == "SIM_STATE" and lat_lon is not None:
                if st["origin"] is None:
                    st["origin"] = lat_lon
                north = math.radians(lat_lon[0] - st["origin"][0]) * 6378137.0
                east = math.radians(lat_lon[1] - st["origin"][1]) * 6378137.0 * math.cos(math.radians(lat_lon[0]))
                st["truth"].append([time.monotonic(), north, east, -m.alt, math.degrees(m.yaw) % 360.0])
            elif kind == "PARAM_VALUE" and m.param_id == PARAM:
                st["gcs_id"].append([time.monotonic(), m.param_value])
            elif kind == "EKF_STATUS_REPORT":
                st["ekf_flags"] = m.flags
            elif kind == "STATUSTEXT":
                st["texts"].append(m.text)

    def beat():
        while not done.is_set():
            send(gcs.mav.heartbeat_send, 6, 8, 0, 0, 4)
            time.sleep(1.0)

    def joystick():
        k, start = 0, time.monotonic()
        while not done.is_set():
            send(gcs.mav.manual_control_send, target, *st["sticks"], 0)
            k += 1
            time.sleep(max(0.0, start + k * 0.04 - time.monotonic()))

    for f in (listen, beat, joystick):
        threading.Thread(target=f, daemon=True).start()

    serve = subprocess.Popen([a.pinc, "serve", "--connect", f"tcp:127.0.0.1:{ROUTER_PORT}", "--data", a.data,
                              "--port", "0", *[f"--run-arg={x}" for x in a.run_arg]],
                             stderr=subprocess.PIPE, text=True, bufsize=1)
    base = "http://" + re.search(r"http://(127\.0\.0\.1:\d+)", serve.stderr.readline()).group(1)
    log = []
    threading.Thread(target=lambda: log.extend(serve.stderr), daemon=True).start()
    extras = json.loads(urllib.request.urlopen(base + "/cockpit_extras.json").read())
    actions = {x["id"]: x["config"] for x in extras["actions"]}

    def press(action_id):
        c = actions[action_id]
        url = base + c["url"].split("/extensionv2/pinc", 1)[1]
        req = urllib.request.Request(url, data=c["body"].encode(), method=c["method"],
                                     headers={**c["headers"], "Origin": "file://"})
        try:
            with urllib.request.urlopen(req, timeout=20) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read())

    def wait(what, cond, timeout):
        until = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > until:
                raise SystemExit(f"timed out waiting for {what}; texts {st['texts'][-5:]}")
            time.sleep(0.1)

    def depth():
        return st["truth"][-1][3] if st["truth"] else 0.0

    def heading_error():
        return ((st["truth"][-1][4] - a.heading + 180.0) % 360.0) - 180.0 if st["truth"] else 180.0

    out = {"press": None, "resume": None}
    try:
        wait("the simulator's truth", lambda: st["truth"], 30)
        # Arm (retried while the autopilot refuses in its first seconds), then ALT_HOLD.
        until = time.monotonic() + 40
        while not st["armed"]:
            send(gcs.mav.command_long_send, target, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            time.sleep(1.0)
            if time.monotonic() > until:
                raise SystemExit(f"not armed: {st['texts'][-5:]}")
        send(gcs.mav.set_mode_send, target, 1, ALT_HOLD)
        wait("ALT_HOLD", lambda: st["mode"] == ALT_HOLD, 10)
        # The autopilot's position (its GPS, fused about 20 s after arming): EKF_STATUS's
        # horizontal absolute position flag.
        wait("the autopilot's position", lambda: st["ekf_flags"] & 16, 60)
        # To the depth on the heave stick (in ALT_HOLD below 500 is down), slower near it, and to
        # the heading by ALT_HOLD's attitude target (SET_ATTITUDE_TARGET, type_mask 71: the
        # quaternion alone; its yaw stick's dead band and rate made a hand-flown turn hunt), until
        # both have been within 8 cm and 2 deg for 2 s.
        half = math.radians(a.heading) / 2.0
        settled_since, next_target = None, 0.0
        until = time.monotonic() + 90
        while settled_since is None or time.monotonic() - settled_since < 2.0:
            dz, dh = depth() - a.depth, heading_error()
            st["sticks"] = (0, 0, 500 + max(-250, min(250, round(1500 * dz))), 0)
            if time.monotonic() >= next_target:
                send(gcs.mav.set_attitude_target_send, 0, target, 1, 71, [math.cos(half), 0, 0, math.sin(half)],
                     0, 0, 0, 0.5)
                next_target = time.monotonic() + 0.5
            if abs(dz) <= 0.08 and abs(dh) <= 2.0:
                settled_since = settled_since or time.monotonic()
            else:
                settled_since = None
            if time.monotonic() > until:
                raise SystemExit(f"not at {a.depth} m and {a.heading} deg: {st['truth'][-1]}")
            time.sleep(0.04)
        st["sticks"] = (0, 0, 500, 0)
        time.sleep(3.0)  # let go: drifting with the current at the press
        out["press"] = {"t": time.monotonic(), "answer": press("pinc-hold-here")}
        time.sleep(a.hold)
        out["resume"] = {"t": time.monotonic(), "answer": press("pinc-resume")}
        time.sleep(2.0)
        send(gcs.mav.param_request_read_send, target, 1, PARAM.encode(), -1)
        wait("the ground station id", lambda: st["gcs_id"], 5)
        out["after"] = {"mode": st["mode"], "armed": st["armed"], "gcs_id": st["gcs_id"][-1][1]}
    finally:
        done.set()
        serve.terminate()
        serve.wait(10)
        out.update(truth=st["truth"], serve_log=log, texts=st["texts"])
        with open(a.record, "w") as f:
            json.dump(out, f)


if __name__ == "__main__":
    main()
