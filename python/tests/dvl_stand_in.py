"""A DVL stand-in for ArduSub's simulator: the only position source of a flight with the GPS
off (tests/fixtures/ardusub/dvl_stand_in.parm). Like sitl_inject.py it runs a client command
and connects beside it as a second ground station (system 254, the simulator's third port,
SERIAL2, 5763), so it never shares the client's link. While the client runs it

- sets the EKF's global origin (SET_GPS_GLOBAL_ORIGIN, the site's known position: the home
  run_in_netns.sh gives the simulator) until the autopilot reports one, as a DVL
  integration's "set origin" does;
- streams the simulator's truth (SIM_STATE, 50 Hz in simulated time) and from it sends
  VISION_POSITION_DELTA at 10 Hz, what the Water Linked DVL integration sends: the body-frame
  distance moved over the ground in the last 0.1 s (the true NED velocity of each SIM_STATE
  turned into the body frame by the true attitude, summed over its 20 ms) and the change of
  roll, pitch and yaw over it. A DVL measures the motion over the bottom, current included,
  with a velocity noise of about 1 cm/s: each axis gets a seeded Gaussian error of --noise m/s
  (default 0.01) on the mean velocity of the 0.1 s;
- records every SIM_STATE to --record as JSON lines: the autopilot time it arrived at
  (`t`, s: the newest ATTITUDE's `time_boot_ms` plus the host time since it came, as pinc
  stamps its own truth), `lat_e7`, `lon_e7` (SIM_STATE's integer extension, 1e-7 deg),
  `depth_m` and `yaw_rad`; and its own events (`{"event": ...}`: origin sent and taken, armed,
  the first and the last delta sent, and each change of the autopilot's word on the DVL's
  health: SYS_STATUS's visual odometry bit, `vision_healthy`).

With `--usbl` it also stands in for a USBL, Water Linked's Underwater GPS G2 through its BlueOS
extension: GPS_INPUT at 4 Hz (in simulated time) carrying the true position of when it was
measured plus a seeded Gaussian error of --usbl-noise m (default 0.25) on north and east, sent
--usbl-latency s (default 0.5) after it was measured, `horiz_accuracy` the noise, no velocity
(a USBL measures none), the autopilot reading it as a MAVLink GPS (GPS1_TYPE 14). `--no-dvl`
leaves the deltas out (the USBL alone). Each fix sent is recorded (`{"event": "fix", ...}` only
for the first; the count at the end).

What a vehicle in water brings, each from the options (default: none of it):

- `--origin site|autopilot|N,E`: the EKF origin set at the site's exact home (the default), left
  to the autopilot (nothing sent: ArduSub's EKF takes it from the first USBL fix it uses), or
  set by hand N metres north and E east of the home (an owner's "set origin" on a map);
- `--first-fix-after S`: the USBL's first fix S s after arming (the acoustic lock found after
  the dive started); `--usbl-outage A,B`: no fixes from A to B s after arming;
- `--fix-wander STD,TAU`: the topside GPS's error in every fix, north and east each a
  first-order Gauss-Markov process of STD m and time constant TAU s (drawn at the start, so the
  fixes' frame is STD metres off the truth from the first);
- `--outliers P,M`: a share P of the fixes M metres off in a random direction (multipath);
- `--dvl-yaw-deg A`, `--dvl-scale K`: the DVL mounted A deg to starboard of the hull's axis and
  reading K times the velocity: it sends K (c u + s v, -s u + c v, w), `c s` of A.

`--stop-after S` stops the deltas S seconds after the autopilot first reports armed (the DVL's
messages lost: a DVL that lost bottom lock or its cable); the record goes on. With
`--resume-after R` (R > S) they come back R seconds after arming (bottom lock regained), the
first delta over a fresh interval. The sensor is
the only place the truth enters: nothing else from the simulator goes to the client.

usage: dvl_stand_in.py --record FILE [--port 5763] [--noise M_S] [--seed N] [--stop-after S]
                       [--resume-after R] [--usbl [--usbl-noise M] [--usbl-latency S]] [--no-dvl]
                       [--origin site|autopilot|N,E] [--first-fix-after S] [--usbl-outage A,B]
                       [--fix-wander STD,TAU] [--outliers P,M] [--dvl-yaw-deg A] [--dvl-scale K]
                       -- CLIENT [ARGS...]
Exits with the client's status.
"""

import argparse
import json
import math
import random
import subprocess
import sys
import time

from ground_station import connect
from pymavlink import mavutil

SIM_STATE = 108
ATTITUDE = 30
SYS_STATUS = 1
GPS_GLOBAL_ORIGIN = 49
TRUTH_HZ = 50  # SIM_STATE's stream, exact in simulated time (the simulator's README)
DELTA_EVERY = 5  # SIM_STATEs per VISION_POSITION_DELTA: 10 Hz
HOME = (33.810313, -118.393867)  # run_in_netns.sh's --home
FIX_EVERY_S = 0.25  # the USBL's 4 Hz
METRES_PER_E7_DEG = 0.011131884502145034  # ArduPilot's spherical earth
# GPS_INPUT's fields left out: velocity (horizontal 8, vertical 16), its accuracy (32), the
# vertical accuracy (128).
USBL_IGNORE = 8 | 16 | 32 | 128
GPS_EPOCH_UNIX_S = 315964800  # 1980-01-06, GPS time's start (leap seconds left out)


def body_velocity(s):
    """SIM_STATE's true NED velocity in the body frame (Z-Y-X Euler angles)."""
    cr, sr = math.cos(s.roll), math.sin(s.roll)
    cp, sp = math.cos(s.pitch), math.sin(s.pitch)
    cy, sy = math.cos(s.yaw), math.sin(s.yaw)
    n, e, d = s.vn, s.ve, s.vd
    # R (body to NED) = Rz(yaw) Ry(pitch) Rx(roll); the body velocity is R^T v.
    u = cp * cy * n + cp * sy * e - sp * d
    v = (sr * sp * cy - cr * sy) * n + (sr * sp * sy + cr * cy) * e + sr * cp * d
    w = (cr * sp * cy + sr * sy) * n + (cr * sp * sy - sr * cy) * e + cr * cp * d
    return u, v, w


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--record", required=True)
    p.add_argument("--port", type=int, default=5763)
    p.add_argument("--noise", type=float, default=0.01, help="velocity noise per axis, m/s (1 sigma)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--stop-after", type=float, default=None, help="stop the deltas this long after arming (s)")
    p.add_argument("--resume-after", type=float, default=None, help="send the deltas again this long after arming (s)")
    p.add_argument("--usbl", action="store_true", help="also send a USBL's fixes as GPS_INPUT")
    p.add_argument("--usbl-noise", type=float, default=0.25, help="USBL position noise, m (1 sigma, per axis)")
    p.add_argument("--usbl-latency", type=float, default=0.5, help="how late each USBL fix is sent, s")
    p.add_argument("--no-dvl", action="store_true", help="send no deltas (the USBL alone)")
    p.add_argument("--origin", default="site", help="site, autopilot, or N,E metres off the site by hand")
    p.add_argument("--first-fix-after", type=float, default=None, help="the USBL's first fix, s after arming")
    p.add_argument("--usbl-outage", default=None, help="A,B: no fixes from A to B s after arming")
    p.add_argument("--fix-wander", default=None, help="STD,TAU: the topside GPS's error (m, s) in the fixes")
    p.add_argument("--outliers", default=None, help="P,M: a share P of the fixes M metres off")
    p.add_argument("--dvl-yaw-deg", type=float, default=0.0, help="the DVL turned this far to starboard (deg)")
    p.add_argument("--dvl-scale", type=float, default=1.0, help="the DVL reads this times the velocity")
    p.add_argument("client", nargs=argparse.REMAINDER)
    a = p.parse_args()
    client = a.client[1:] if a.client and a.client[0] == "--" else a.client
    pair = lambda text: tuple(float(x) for x in text.split(",")) if text else None  # noqa: E731
    if a.origin == "site":
        origin_at = (0.0, 0.0)
    elif a.origin == "autopilot":
        origin_at = None
    else:
        origin_at = pair(a.origin)
    outage, wander, outliers = pair(a.usbl_outage), pair(a.fix_wander), pair(a.outliers)
    mount_c, mount_s = math.cos(math.radians(a.dvl_yaw_deg)), math.sin(math.radians(a.dvl_yaw_deg))
    proc = subprocess.Popen(client)
    rng = random.Random(a.seed)
    record = open(a.record, "w")

    def note(**fields):
        record.write(json.dumps(fields) + "\n")
        record.flush()

    m = connect(a.port, proc)
    boot = None  # (autopilot time of the newest ATTITUDE, host time it came)
    asked_streams = asked_origin = 0.0
    truth_flowing = False
    origin_set = False
    armed_at = None
    stopped = False
    acc = [0.0, 0.0, 0.0]
    n_acc = 0
    last_att = None  # roll, pitch, yaw at the start of the interval
    sent = 0
    vision_healthy = None
    usbl_rng = random.Random(a.seed + 1000)
    next_fix_sim = 0.0  # simulated time of the next fix (s)
    sim_time = 0.0
    fixes_due = []  # (host time to send, lat_e7, lon_e7, depth m), oldest first
    fixes_sent = 0
    wander_rng = random.Random(a.seed + 2000)
    # The topside GPS's error now (north, east; m), drawn at its stationary spread.
    drift = [wander_rng.gauss(0.0, wander[0]) for _ in range(2)] if wander else [0.0, 0.0]
    outliers_sent = 0
    while proc.poll() is None and m is not None:
        now = time.monotonic()
        while fixes_due and fixes_due[0][0] <= now:
            _, lat, lon, depth = fixes_due.pop(0)
            gps_s = time.time() - GPS_EPOCH_UNIX_S
            week, week_ms = int(gps_s // 604800), int((gps_s % 604800) * 1000)
            m.mav.gps_input_send(int(time.time() * 1e6), 0, USBL_IGNORE, week_ms, week, 3, lat, lon, -depth,
                                 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, a.usbl_noise, 0.0, 10)
            if fixes_sent == 0:
                note(event="first_fix", t=boot[0] + (now - boot[1]) if boot else None)
            fixes_sent += 1
        if not truth_flowing and now - asked_streams > 2.0:  # asked again until SIM_STATE flows
            asked_streams = now
            for msg_id, hz in ((SIM_STATE, TRUTH_HZ), (ATTITUDE, TRUTH_HZ), (SYS_STATUS, 10)):
                m.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                        msg_id, 1e6 / hz, 0, 0, 0, 0, 0)
        if origin_at is not None and not origin_set and boot is not None and now - asked_origin > 1.0:
            asked_origin = now
            lat = HOME[0] * 1e7 + origin_at[0] / METRES_PER_E7_DEG
            lon = HOME[1] * 1e7 + origin_at[1] / (METRES_PER_E7_DEG * math.cos(math.radians(HOME[0])))
            m.mav.set_gps_global_origin_send(1, round(lat), round(lon), 0, int(boot[0] * 1e6))
            m.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                    GPS_GLOBAL_ORIGIN, 0, 0, 0, 0, 0, 0)
            note(event="origin_sent", t=boot[0])
        msg = m.recv_match(blocking=True, timeout=0.05)
        if msg is None:
            continue
        kind = msg.get_type()
        if msg.get_srcSystem() != 1:
            continue
        if kind == "ATTITUDE":
            boot = (msg.time_boot_ms / 1000.0, time.monotonic())
        elif kind == "SYS_STATUS":
            healthy = bool(msg.onboard_control_sensors_health & mavutil.mavlink.MAV_SYS_STATUS_SENSOR_VISION_POSITION)
            if healthy != vision_healthy:
                vision_healthy = healthy
                note(event="vision_healthy", healthy=healthy, t=boot[0] if boot else None)
        elif kind == "GPS_GLOBAL_ORIGIN" and not origin_set:
            origin_set = True
            note(event="origin", t=boot[0] if boot else None, lat_e7=msg.latitude, lon_e7=msg.longitude)
        elif kind == "HEARTBEAT" and armed_at is None and msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED:
            armed_at = time.monotonic()
            note(event="armed", t=boot[0] if boot else None)
        elif kind == "SIM_STATE" and boot is not None:
            truth_flowing = True
            t = boot[0] + (time.monotonic() - boot[1])
            note(t=round(t, 4), lat_e7=msg.lat_int, lon_e7=msg.lon_int, depth_m=-msg.alt, yaw_rad=msg.yaw)
            sim_time += 1.0 / TRUTH_HZ
            since_arming = None if armed_at is None else time.monotonic() - armed_at
            if a.usbl and sim_time >= next_fix_sim:
                next_fix_sim += FIX_EVERY_S
                north, east = usbl_rng.gauss(0.0, a.usbl_noise), usbl_rng.gauss(0.0, a.usbl_noise)
                if wander:
                    keep = math.exp(-FIX_EVERY_S / wander[1])
                    drift = [d * keep + wander_rng.gauss(0.0, wander[0] * math.sqrt(1.0 - keep * keep))
                             for d in drift]
                    north, east = north + drift[0], east + drift[1]
                if outliers and wander_rng.random() < outliers[0]:
                    bearing = wander_rng.uniform(0.0, 2.0 * math.pi)
                    north, east = north + outliers[1] * math.cos(bearing), east + outliers[1] * math.sin(bearing)
                    outliers_sent += 1
                # No acoustic lock yet, or an outage: nothing sent.
                locked = a.first_fix_after is None or (since_arming is not None and since_arming >= a.first_fix_after)
                out = outage is not None and since_arming is not None and outage[0] <= since_arming < outage[1]
                if locked and not out:
                    scale = math.cos(math.radians(msg.lat_int * 1e-7))
                    lat = msg.lat_int + round(north / METRES_PER_E7_DEG)
                    lon = msg.lon_int + round(east / (METRES_PER_E7_DEG * scale))
                    fixes_due.append((time.monotonic() + a.usbl_latency, lat, lon, -msg.alt))
            if a.no_dvl:
                continue
            if stopped:
                if a.resume_after is None or since_arming < a.resume_after:
                    continue
                stopped = False
                acc, n_acc, last_att = [0.0, 0.0, 0.0], 0, None
                note(event="deltas_resumed", t=t, sent=sent, after_arming_s=since_arming)
            elif since_arming is not None and a.stop_after is not None and since_arming >= a.stop_after \
                    and (a.resume_after is None or since_arming < a.resume_after):
                stopped = True
                note(event="deltas_stopped", t=t, sent=sent, after_arming_s=since_arming)
                continue
            att = (msg.roll, msg.pitch, msg.yaw)
            if last_att is None:
                last_att = att
                continue
            u, v, w = body_velocity(msg)
            # As the DVL is mounted: turned to starboard, scaled.
            read = (a.dvl_scale * (mount_c * u + mount_s * v), a.dvl_scale * (-mount_s * u + mount_c * v),
                    a.dvl_scale * w)
            for i, vel in enumerate(read):
                acc[i] += vel / TRUTH_HZ
            n_acc += 1
            if n_acc < DELTA_EVERY:
                continue
            dt = n_acc / TRUTH_HZ
            delta = [acc[i] + rng.gauss(0.0, a.noise) * dt for i in range(3)]
            angles = [wrap(att[i] - last_att[i]) for i in range(3)]
            m.mav.vision_position_delta_send(int(t * 1e6), int(dt * 1e6), angles, delta, 100.0)
            if sent == 0:
                note(event="first_delta", t=t)
            sent += 1
            acc, n_acc, last_att = [0.0, 0.0, 0.0], 0, att
    if m is not None and not stopped:
        note(event="deltas_end", sent=sent)
    if a.usbl:
        note(event="fixes_end", sent=fixes_sent, outliers=outliers_sent)
    return proc.wait()


if __name__ == "__main__":
    sys.exit(main())
