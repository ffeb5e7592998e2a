"""A flight on Cockpit's joystick killed before its stop leaves the autopilot's ground station
as the flight's id (254): `pinc serve` gives it back (255) on its link's start, while no flight
runs. The autopilot starts with MAV_GCS_SYSID 254 (the test's parameter file); a bystander on
5760 (it starts the simulation) reads the parameter before `pinc serve` starts on 5762 and until
it reads 255 (30 s at most). Prints JSON: what it read, when, and the server's output. Run inside
run_in_netns.sh.

usage: ground_station_left.py PINC VEHICLE DATA
"""
import json
import subprocess
import sys
import time

from pymavlink import mavutil

pinc, vehicle, data = sys.argv[1:4]
m = mavutil.mavlink_connection("tcp:127.0.0.1:5760", source_system=250, source_component=190)
m.wait_heartbeat(timeout=60)


def read(timeout=2.0):
    m.mav.param_request_read_send(m.target_system, 1, b"MAV_GCS_SYSID", -1)
    p = m.recv_match(type="PARAM_VALUE", blocking=True, timeout=timeout)
    while p is not None and p.param_id != "MAV_GCS_SYSID":
        p = m.recv_match(type="PARAM_VALUE", blocking=True, timeout=timeout)
    return None if p is None else p.param_value


before = read()
serve = subprocess.Popen([pinc, "serve", "--connect", "tcp:127.0.0.1:5762", "--data", data, "--port", "8781",
                          "--vehicle", vehicle], stderr=subprocess.PIPE, text=True)
start, after = time.monotonic(), None
while time.monotonic() - start < 30 and after != 255.0:
    after = read()
    time.sleep(0.5)
took = time.monotonic() - start
serve.terminate()
_, err = serve.communicate(timeout=10)
print(json.dumps({"before": before, "after": after, "took_s": took, "serve": err}))
