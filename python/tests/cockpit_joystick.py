"""Cockpit's joystick beside pinc, through a router: starts the router stand-in
(mavlink_hub.py: the autopilot on 5760 upstream, a TCP server on --port for its clients), then a
Cockpit stand-in on it (system 255, component 240, heartbeats at 1 Hz and MANUAL_CONTROL at
25 Hz from the start, as Cockpit sends with a joystick plugged in: x forward, y right, r a turn
right in -1000..1000, z 0..1000 with 500 centred and above 500 up), then CLIENT (pinc, connected
to the router too). Each --stick FROM,TO,SURGE,SWAY,HEAVE,YAW (s after the client says "control
starts", each axis -1..1) is held while it lasts, centred sticks between.

With --rest PORT, a mavlink2rest stand-in on it (mavlink2rest_stand_in.py) keeps each of
Cockpit's messages as Cockpit sends through mavlink2rest.

Cockpit's side notes, in --record (JSON): every SERVO_OUTPUT_RAW it sees (session time, outputs
1-4), and the autopilot's ground station id (MAV_GCS_SYSID) as it answers Cockpit's PARAM_REQUEST_READ 5 s after
control starts and again after the client ended. The client's stdout and status pass through.

usage: cockpit_joystick.py --record FILE [--port P] [--route broadcast|target] [--rest PORT] [--stick ...] -- CLIENT...
"""

import argparse
import json
import subprocess
import sys
import threading
import time

from mavlink2rest_stand_in import Mavlink2Rest
from mavlink_hub import Hub
from pymavlink import mavutil

# The autopilot's ground station id (this firmware's name; older firmware calls it SYSID_MYGCS).
PARAM = "MAV_GCS_SYSID"
PARAM_ID = PARAM.encode()  # pymavlink sends a parameter name as bytes


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--record", required=True)
    p.add_argument("--port", type=int, default=5777)
    p.add_argument("--route", default="broadcast")
    p.add_argument("--rest", type=int)
    p.add_argument("--stick", action="append", default=[])
    p.add_argument("client", nargs=argparse.REMAINDER)
    a = p.parse_args()
    client = a.client[1:] if a.client[:1] == ["--"] else a.client
    segments = [[float(x) for x in s.split(",")] for s in a.stick]

    Hub(("127.0.0.1", 5760), a.port, a.route)
    rest = Mavlink2Rest(a.rest) if a.rest else None
    cockpit = mavutil.mavlink_connection(f"tcp:127.0.0.1:{a.port}", source_system=255, source_component=240)
    cockpit.wait_heartbeat(timeout=60)
    target = cockpit.target_system
    state = {"t0": None, "outputs": [], "mygcs": [], "sent": 0}
    done = threading.Event()
    sending = threading.Lock()  # pymavlink's sender is shared by three threads

    def session_t():
        return None if state["t0"] is None else time.monotonic() - state["t0"]

    def listen():
        while not done.is_set():
            m = cockpit.recv_match(type=["SERVO_OUTPUT_RAW", "PARAM_VALUE"], blocking=True, timeout=0.2)
            if m is None or m.get_srcSystem() != target:
                continue
            if m.get_type() == "SERVO_OUTPUT_RAW":
                t = session_t()
                if t is not None:
                    state["outputs"].append([t, m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw])
            elif m.param_id == PARAM:
                state["mygcs"].append([session_t(), m.param_value])

    def beat():
        while not done.is_set():
            with sending:
                cockpit.mav.heartbeat_send(6, 8, 0, 0, 4)
            time.sleep(1.0)

    def joystick():
        k, start = 0, time.monotonic()
        while not done.is_set():
            t = session_t()
            axes = [0.0] * 4
            if t is not None:
                axes = next((s[2:] for s in segments if s[0] <= t < s[1]), axes)
            surge, sway, heave, yaw = axes
            x, y, z, r = round(1000 * surge), round(1000 * sway), round(500 - 500 * heave), round(1000 * yaw)
            if rest:
                rest.keep(target, x, y, z, r)
            with sending:
                cockpit.mav.manual_control_send(target, x, y, z, r, 0)
            state["sent"] += 1
            k += 1
            time.sleep(max(0.0, start + k * 0.04 - time.monotonic()))

    for f in (listen, beat, joystick):
        threading.Thread(target=f, daemon=True).start()

    child = subprocess.Popen(client, stderr=subprocess.PIPE, text=True, bufsize=1)

    def ask_later():
        time.sleep(5.0)
        with sending:
            cockpit.mav.param_request_read_send(target, 1, PARAM_ID, -1)

    def watch():
        for line in child.stderr:
            sys.stderr.write(line)
            if line.startswith("control starts") and state["t0"] is None:
                state["t0"] = time.monotonic()
                threading.Thread(target=ask_later, daemon=True).start()

    threading.Thread(target=watch, daemon=True).start()
    status = child.wait()
    ended = session_t()
    # The place given back: asked until answered after the client's end (3 s at most).
    before = len(state["mygcs"])
    until = time.monotonic() + 3.0
    while len(state["mygcs"]) == before and time.monotonic() < until:
        with sending:
            cockpit.mav.param_request_read_send(target, 1, PARAM_ID, -1)
        time.sleep(0.3)
    done.set()
    with open(a.record, "w") as f:
        json.dump({"ended_t": ended, "sent": state["sent"], "mygcs": state["mygcs"], "outputs": state["outputs"]}, f)
    sys.exit(status)


if __name__ == "__main__":
    main()
