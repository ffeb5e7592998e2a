"""Two ground stations drive the firmware's thrusters at once, as Cockpit's joystick and pinc
would: A (system 255, the autopilot's SYSID_MYGCS, on 5760) arms and sends MANUAL_CONTROL forward
600 at 10 Hz, B (system SYSTEM, on 5762) sends neutral at 10 Hz, 50 ms after each of A's. Prints
(JSON) the share of SERVO_OUTPUT_RAW samples (20 Hz, after the first second of 8) that show A's
forward command, and the first few outputs. Run inside run_in_netns.sh.

usage: two_ground_stations.py SYSTEM
"""
import json
import sys
import threading
import time

from pymavlink import mavutil
sys_b = int(sys.argv[1])
a = mavutil.mavlink_connection("tcp:127.0.0.1:5760", source_system=255, source_component=190)
a.wait_heartbeat(timeout=30)
b = mavutil.mavlink_connection("tcp:127.0.0.1:5762", source_system=sys_b, source_component=190)
b.wait_heartbeat(timeout=30)
tgt = a.target_system
a.mav.command_long_send(tgt, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 36, 50000, 0, 0, 0, 0, 0)
stop = False
def beat():
    while not stop:
        for c in (a, b):
            c.mav.heartbeat_send(6, 8, 0, 0, 0)
        time.sleep(0.5)
threading.Thread(target=beat, daemon=True).start()
armed = False
t0 = time.time()
while time.time() - t0 < 30 and not armed:
    a.mav.command_long_send(tgt, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    a.mav.manual_control_send(tgt, 0, 0, 500, 0, 0)
    m = a.recv_match(type="HEARTBEAT", blocking=True, timeout=1)
    armed = bool(m and m.get_srcSystem() == tgt and m.base_mode & 128)
print("armed", armed, round(time.time() - t0, 1), flush=True)
outs = []
def read():
    while not stop:
        m = a.recv_match(type="SERVO_OUTPUT_RAW", blocking=True, timeout=0.5)
        if m:
            outs.append((time.time(), m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw))
threading.Thread(target=read, daemon=True).start()
start = time.time()
k = 0
while time.time() - start < 8:
    a.mav.manual_control_send(tgt, 600, 0, 500, 0, 0)
    time.sleep(0.05)
    b.mav.manual_control_send(tgt, 0, 0, 500, 0, 0)
    k += 1
    time.sleep(max(0, start + k * 0.1 - time.time()))
stop = True
time.sleep(0.3)
late = [o for o in outs if o[0] - start > 1.0]
forward = sum(1 for o in late if abs(o[1] - 1500) > 30)
print(json.dumps({"b_system": sys_b, "samples": len(late), "forward_share": forward / max(1, len(late)),
                  "first": late[:12]}), flush=True)
