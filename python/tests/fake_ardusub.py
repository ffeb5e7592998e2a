"""A fake ArduSub autopilot for tests: speaks MAVLink 2 over UDP on loopback the way ArduSub
does, and moves pinc's own simulated vehicle (``pinc.simulate``) with the thrust that its
thruster outputs would give.

What it does, and where the numbers come from (shared/fixtures/ardusub/README.md, which
describes ArduSub's simulator and its logs):

- HEARTBEAT at 1 Hz: type SUBMARINE, autopilot ARDUPILOTMEGA, ArduSub's custom mode numbers,
  the armed flag in base_mode;
- COMMAND_LONG from the ground station's system id only (``--gcs-sysid``, 255 by default, as
  ArduSub's SYSID_MYGCS): arm/disarm, DO_SET_MODE, SET_MESSAGE_INTERVAL, REQUEST_MESSAGE
  (AUTOPILOT_VERSION), each answered with COMMAND_ACK; SET_MODE too;
- ATTITUDE, LOCAL_POSITION_NED, SCALED_PRESSURE2 (with ``--pressure-noise``, 0.2 hPa: a real
  sensor's reading never repeats for long, and pinc takes one that does as frozen) and
  SERVO_OUTPUT_RAW at the requested intervals (all in the same 50 Hz tick share one time stamp); LOCAL_POSITION_NED only from
  ``--position-delay`` seconds after arming (the real EKF's first position came about 20 s after
  arming in the simulator logs);
- MANUAL_CONTROL in MANUAL mode through ArduSub's mixer for the vectored (BlueROV2) frame:
  axis s = g x / 1000 for x, y, r and g (z - 500) / 500 for z (g = JS_GAIN_DEFAULT), output
  per thruster o = sum of the frame's factors times the axes, clipped to +-1, PWM = 1500 + 400 o;
  (the factors agree within 0.1 with a least-squares fit of RCOU on RCIN in the simulator's
  own log sitl_excite_1.BIN: docs/VEHICLE.md);
- RC_CHANNELS_OVERRIDE as per-thruster commands (outputs set to RC pass-through): channel i is
  thruster i's PWM (0 or 65535 releases it);
- PARAM_REQUEST_READ by name, answered by PARAM_VALUE for the parameters pinc reads:
  SERVO1..8_FUNCTION (``--outputs motors``, the default: 33-38, the autopilot's own motors as
  on a stock BlueROV2; ``passthrough``: 51-56, RCIN1-6), JS_GAIN_DEFAULT, COMPASS_DEC (0),
  COMPASS_AUTODEC (1), EK3_SRC1_POSXY and EK3_SRC1_VELXY (3, GPS); other names, and those
  given to ``--unanswered``, get no answer, as ArduPilot gives none;
- EKF_STATUS_REPORT at its requested interval: attitude, velocity and vertical position good,
  and the horizontal position (absolute and relative) while LOCAL_POSITION_NED is sent;
- the thruster model of ArduSub's simulator: s = (PWM - 1500) / 400, zero within +-25 us of
  1500, thrust 51.48 s|s| N along the factors' directions (forward, lateral, -throttle), the yaw
  moment 0.25 m times the yaw-factor sum (the README's 51.5 N m at full yaw);
- failsafes: disarms when the ground station's heartbeat stops for 5 s or pilot input
  (MANUAL_CONTROL or RC_CHANNELS_OVERRIDE) for 3 s while armed, with a STATUSTEXT;
- time base: time_boot_ms from the fake's start, which is also its simulation time.

Fault injection for the safety tests: ``--fault KIND --fault-after S`` (seconds after the first
pilot command received), KIND one of ``heartbeat-stop`` (no more HEARTBEAT), ``state-freeze``
(the state messages repeat the last ATTITUDE's time stamp and values), ``drop-reorder`` (10 % of
outgoing packets: half dropped, half sent after the next twelve packets, behind the next
state message of their kind), ``self-disarm`` (disarms
with a STATUSTEXT and an immediate heartbeat), ``malformed`` (one frame with a valid checksum
around a HEARTBEAT whose vehicle type is no MAV_TYPE). ``--commands FILE`` writes one JSON
line per command received (boot time of its arrival, its kind and values) and one per fault
injected; ``--hold-until-armed`` keeps the vehicle at ``--x0`` until it is armed (at rest,
as a closed loop's simulation starts).

``--truth FILE`` writes one JSON line per physics step: boot_ms, the true state
(x y z psi u v w r), the body wrench and the PWM, so that tests can compare what pinc rebuilt
with what the fake simulated.

Run: python fake_ardusub.py --listen 127.0.0.1:PORT (pinc connects with udpout:127.0.0.1:PORT)
or --target 127.0.0.1:PORT (pinc listens with udpin:127.0.0.1:PORT).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import random
import sys
import threading
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

import numpy as np  # noqa: E402

# ArduSub's custom modes (pymavlink's mode_mapping_sub).
MODES = {"STABILIZE": 0, "ACRO": 1, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "CIRCLE": 7,
         "SURFACE": 9, "POSHOLD": 16, "MANUAL": 19}

# Vectored frame (ArduSub's AP_Motors6DOF, SUB_FRAME_VECTORED): per thruster the factors
# (yaw, throttle, forward, lateral); roll and pitch are unused in MANUAL mode.
VECTORED = [
    (1.0, 0.0, -1.0, 1.0),
    (-1.0, 0.0, -1.0, -1.0),
    (-1.0, 0.0, 1.0, 1.0),
    (1.0, 0.0, 1.0, -1.0),
    (0.0, -1.0, 0.0, 0.0),
    (0.0, -1.0, 0.0, 0.0),
]
THRUST_N = 51.48          # per thruster at full output (ArduSub's simulator)
DEADBAND_US = 25.0
YAW_ARM_M = 0.25          # 206 N of yaw-factor thrust -> 51.5 N m (fixtures README)
SURFACE_HPA = 1013.25
GRAVITY = 9.80665

STATE_IDS = {
    mav.MAVLINK_MSG_ID_ATTITUDE: "ATTITUDE",
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: "LOCAL_POSITION_NED",
    mav.MAVLINK_MSG_ID_SCALED_PRESSURE2: "SCALED_PRESSURE2",
    mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: "SERVO_OUTPUT_RAW",
    mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT: "EKF_STATUS_REPORT",
}


def mix_manual(x: int, y: int, z: int, r: int, gain: float) -> list[int]:
    """Thruster PWM of a MANUAL_CONTROL in MANUAL mode (ArduSub's mixer, vectored frame)."""
    fwd, lat, yaw = gain * x / 1000.0, gain * y / 1000.0, gain * r / 1000.0
    thr = gain * (z - 500) / 500.0
    out = []
    for f_yaw, f_thr, f_fwd, f_lat in VECTORED:
        o = max(-1.0, min(1.0, f_yaw * yaw + f_thr * thr + f_fwd * fwd + f_lat * lat))
        out.append(int(round(1500 + 400 * o)))
    return out


def thrust(pwm: float) -> float:
    """Thrust (N) of one thruster at `pwm` (ArduSub simulator's model)."""
    if abs(pwm - 1500.0) <= DEADBAND_US:
        return 0.0
    s = max(-1.0, min(1.0, (pwm - 1500.0) / 400.0))
    return THRUST_N * s * abs(s)


def wrench(pwms: list[float]) -> list[float]:
    """Body wrench X, Y, Z (N, z down) and Mz (N m) of the thrusters' PWM."""
    X = Y = Z = M = 0.0
    for (f_yaw, f_thr, f_fwd, f_lat), p in zip(VECTORED, pwms):
        t = thrust(p)
        X += f_fwd * t
        Y += f_lat * t
        Z += -f_thr * t
        M += YAW_ARM_M * f_yaw * t
    return [X, Y, Z, M]


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class FakeArduSub:
    def __init__(self, args):
        import pinc  # the Python bindings: pip install ./python

        self.pinc = pinc
        self.args = args
        device = f"udpin:{args.listen}" if args.listen else f"udpout:{args.target}"
        self.conn = mavutil.mavlink_connection(device, source_system=args.sysid, source_component=1,
                                               dialect="ardupilotmega")
        self.mav = self.conn.mav
        print(f"fake ArduSub on {device}", flush=True)  # tests wait for this line
        self.start = time.monotonic()
        self.t = 0.0  # simulation time = boot time (s)
        self.state = np.array(args.x0, dtype=float)
        self.armed = False
        self.armed_at = None
        self.mode = MODES[args.mode]
        self.last_gcs_heartbeat = None
        self.last_pilot = None
        self.manual = (0, 0, 500, 0)
        self.rc = None  # per-thruster PWM from RC_CHANNELS_OVERRIDE
        self.intervals = {mid: 1.0 / args.default_rate for mid in STATE_IDS}
        self.due = {mid: 0.0 for mid in STATE_IDS}
        self.next_heartbeat = 0.0
        self.pwm = [1500] * 6
        self.wrench = [0.0] * 4
        self.rng = random.Random(args.seed)
        self.pilot_until = 0.0
        self.truth = open(args.truth, "w") if args.truth else None
        self.commands = open(args.commands, "w") if args.commands else None
        self.params = None  # the BlueROV2 of pinc.simulate, or a vehicle file's coefficients
        if args.vehicle_params:
            import tomllib

            with open(args.vehicle_params, "rb") as f:
                table = tomllib.load(f)
            self.params = {k: float(v) for k, v in table.items() if isinstance(v, (int, float))}
        self.first_pilot = None  # boot time of the first pilot command received
        self.fault_on = False
        self.frozen = None  # (boot_ms, state) the state messages repeat under state-freeze
        self.last_sent = (0, self.state.copy())  # the newest state message's stamp and state
        self.held = []  # packets held back by drop-reorder: [packets still to pass, bytes]
        self.fault_rng = random.Random(args.seed + 1)
        self.noise_rng = random.Random(args.seed + 2)
        raw_write = self.conn.write

        def write(buf):
            if self.fault_on and self.args.fault == "drop-reorder":
                for h in self.held:
                    h[0] -= 1
                due = [h for h in self.held if h[0] <= 0]
                self.held = [h for h in self.held if h[0] > 0]
                u = self.fault_rng.random()
                if u < 0.05:
                    buf = None  # dropped
                elif u < 0.10:
                    self.held.append([12, buf])
                    buf = None
                if buf is not None:
                    raw_write(buf)
                for _, b in due:
                    raw_write(b)
                return
            raw_write(buf)

        self.conn.write = write
        # Messages are read on their own thread and handled at the next physics step.
        self.arrival = None
        self.inbox = queue.Queue()
        threading.Thread(target=self.receive, daemon=True).start()
        if args.armed:
            self.arm(True, "armed at start")

    # ---- time -------------------------------------------------------------------------
    def boot_ms(self) -> int:
        return int(round(self.t * 1000.0))

    # ---- outgoing -------------------------------------------------------------------------
    def statustext(self, text: str):
        self.mav.statustext_send(mav.MAV_SEVERITY_WARNING, text.encode()[:50])

    def heartbeat(self):
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED \
            | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.armed:
            base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        status = mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY
        self.mav.heartbeat_send(mav.MAV_TYPE_SUBMARINE, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base, self.mode, status)

    def autopilot_version(self):
        major, minor, patch = (int(p) for p in self.args.firmware.split("."))
        version = (major << 24) | (minor << 16) | (patch << 8) | 255  # 255: official release
        self.mav.autopilot_version_send(
            mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mav.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET,
            version, 0, 0, 0, list(b"fakesub\0"), [0] * 8, [0] * 8, 0, 0, 0)

    def position_available(self) -> bool:
        return self.armed_at is not None and self.t - self.armed_at >= self.args.position_delay

    def send_state(self, mid: int):
        x, y, z, psi, u, v, w, r = (float(s) for s in self.state)
        ms = self.boot_ms()
        if self.frozen is not None:
            ms = self.frozen[0]
            x, y, z, psi, u, v, w, r = (float(s) for s in self.frozen[1])
        elif mid == mav.MAVLINK_MSG_ID_ATTITUDE:
            self.last_sent = (ms, self.state.copy())
        if mid == mav.MAVLINK_MSG_ID_ATTITUDE:
            self.mav.attitude_send(ms, 0.0, 0.0, wrap(psi), 0.0, 0.0, r)
        elif mid == mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            if self.position_available():
                c, s = math.cos(psi), math.sin(psi)
                self.mav.local_position_ned_send(ms, x, y, z, c * u - s * v, s * u + c * v, w)
        elif mid == mav.MAVLINK_MSG_ID_SCALED_PRESSURE2:
            hpa = SURFACE_HPA + max(z, 0.0) * self.args.water_density * GRAVITY / 100.0
            if self.frozen is None:
                hpa += self.noise_rng.gauss(0.0, self.args.pressure_noise)
            self.mav.scaled_pressure2_send(ms, hpa, 0.0, 1500)
        elif mid == mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:
            p = self.pwm
            self.mav.servo_output_raw_send((ms * 1000) % (1 << 32), 0, *p, 0, 0)
        elif mid == mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT:
            flags = mav.EKF_ATTITUDE | mav.EKF_VELOCITY_HORIZ | mav.EKF_VELOCITY_VERT | mav.EKF_POS_VERT_ABS
            if self.position_available():
                flags |= mav.EKF_POS_HORIZ_REL | mav.EKF_POS_HORIZ_ABS
            else:
                flags |= mav.EKF_CONST_POS_MODE
            self.mav.ekf_status_report_send(flags, 0.05, 0.02, 0.01, 0.05, 0.0)

    def param(self, name: str):
        """The value of a parameter pinc reads, or None (no answer)."""
        if name.startswith("SERVO") and name.endswith("_FUNCTION"):
            n = int(name[5:-9])
            if 1 <= n <= 6:
                return float((50 if self.args.outputs == "passthrough" else 32) + n)
            return 0.0
        if name in self.args.unanswered:
            return None
        return {"JS_GAIN_DEFAULT": self.args.gain, "COMPASS_DEC": 0.0, "COMPASS_AUTODEC": 1.0,
                "EK3_SRC1_POSXY": 3.0, "EK3_SRC1_VELXY": 3.0}.get(name)

    # ---- incoming -------------------------------------------------------------------------
    def ack(self, command: int, result: int = mav.MAV_RESULT_ACCEPTED):
        self.mav.command_ack_send(command, result)

    def arm(self, on: bool, why: str):
        if on and not self.armed:
            self.armed, self.armed_at = True, self.t
            self.last_pilot = self.t
        elif not on and self.armed:
            self.armed = False
            self.statustext(f"Disarming: {why}")

    def now_boot(self) -> float:
        """Boot time (s) of this instant: the wall clock since the start, which the
        simulation follows."""
        return time.monotonic() - self.start

    def receive(self):
        """The receive thread: every message with its arrival time (boot time, s), so that
        the command log's times are the arrivals', not the next physics step's."""
        while True:
            m = self.conn.recv_match(blocking=True, timeout=0.05)
            if m is not None:
                self.inbox.put((self.now_boot(), m))

    def log_command(self, kind: str, **values):
        if self.commands is not None:
            at = self.arrival if self.arrival is not None else self.now_boot()
            self.commands.write(json.dumps({"t": round(at, 5), "sim_t": self.t, "kind": kind,
                                            **values}) + "\n")
            self.commands.flush()

    def pilot_input(self):
        self.last_pilot = self.t
        if self.first_pilot is None:
            self.first_pilot = self.t

    def handle(self, m):
        kind = m.get_type()
        src = m.get_srcSystem()
        if kind == "HEARTBEAT":
            if src == self.args.gcs_sysid and m.type == mav.MAV_TYPE_GCS:
                self.last_gcs_heartbeat = self.t
            return
        if src != self.args.gcs_sysid:
            return  # ArduSub takes commands from SYSID_MYGCS only
        if kind == "COMMAND_LONG":
            if m.target_system not in (0, self.args.sysid):
                return
            cmd = m.command
            if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
                self.log_command("ARM" if m.param1 >= 0.5 else "DISARM")
                self.arm(m.param1 >= 0.5, "commanded")
                self.ack(cmd)
            elif cmd == mav.MAV_CMD_DO_SET_MODE:
                self.mode = int(m.param2)
                self.ack(cmd)
            elif cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
                mid, us = int(m.param1), m.param2
                if mid in STATE_IDS:
                    if us < 0:
                        self.intervals[mid] = None
                    elif us == 0:
                        self.intervals[mid] = 1.0 / self.args.default_rate
                    else:
                        self.intervals[mid] = max(us * 1e-6, self.args.dt)
                    self.due[mid] = self.t
                    self.ack(cmd)
                else:
                    self.ack(cmd, mav.MAV_RESULT_UNSUPPORTED)
            elif cmd == mav.MAV_CMD_REQUEST_MESSAGE:
                if int(m.param1) == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                    self.autopilot_version()
                    self.ack(cmd)
                else:
                    self.ack(cmd, mav.MAV_RESULT_UNSUPPORTED)
            else:
                self.ack(cmd, mav.MAV_RESULT_UNSUPPORTED)
        elif kind == "PARAM_REQUEST_READ":
            name = m.param_id if isinstance(m.param_id, str) else m.param_id.decode()
            value = self.param(name.rstrip("\x00"))
            if value is not None:
                self.mav.param_value_send(name.encode(), value, mav.MAV_PARAM_TYPE_REAL32, 0, 65535)
        elif kind == "SET_MODE":
            self.mode = int(m.custom_mode)
        elif kind == "MANUAL_CONTROL":
            self.manual = (m.x, m.y, m.z, m.r)
            self.rc = None
            self.log_command("MANUAL_CONTROL", x=m.x, y=m.y, z=m.z, r=m.r)
            self.pilot_input()
        elif kind == "RC_CHANNELS_OVERRIDE":
            raw = [m.chan1_raw, m.chan2_raw, m.chan3_raw, m.chan4_raw, m.chan5_raw, m.chan6_raw]
            self.rc = [1500 if c in (0, 65535) else c for c in raw]
            self.log_command("RC_CHANNELS_OVERRIDE", pwm=raw)
            self.pilot_input()

    # ---- the vehicle ----------------------------------------------------------------------
    def own_pilot(self):
        """Random held steps on all four axes, as the simulator logs' ground-station script."""
        if self.t >= self.pilot_until:
            amp = self.rng.choice([200, 400, 700])
            self.manual = tuple(self.rng.randint(-amp, amp) for _ in range(2)) + \
                (500 + self.rng.randint(-amp, amp) // 2, self.rng.randint(-amp, amp))
            self.pilot_until = self.t + self.rng.uniform(1.0, 4.0)
        self.last_pilot = self.t

    def outputs(self) -> list[int]:
        if not self.armed:
            return [1500] * 6
        if self.rc is not None:
            return list(self.rc)
        if self.mode == MODES["MANUAL"]:
            return mix_manual(*self.manual, gain=self.args.gain)
        return [1500] * 6

    def failsafes(self):
        if not self.armed:
            return
        if self.args.gcs_timeout > 0 and (self.last_gcs_heartbeat is None or
                                          self.t - self.last_gcs_heartbeat > self.args.gcs_timeout):
            if self.last_gcs_heartbeat is not None or self.t - self.armed_at > self.args.gcs_timeout:
                self.arm(False, "GCS failsafe")
        if self.armed and self.args.pilot_timeout > 0 and self.t - self.last_pilot > self.args.pilot_timeout:
            self.arm(False, "pilot input failsafe")

    def command_outputs(self):
        """The outputs held from now until the next step."""
        if self.args.pilot and self.armed:
            self.own_pilot()
        self.failsafes()
        self.pwm = self.outputs()
        self.wrench = wrench(self.pwm)

    def inject_fault(self):
        a = self.args
        if a.fault is None or self.fault_on or self.first_pilot is None:
            return
        if self.t < self.first_pilot + a.fault_after:
            return
        self.fault_on = True
        self.log_command("FAULT", fault=a.fault)
        if a.fault == "state-freeze":
            # The last state sent is repeated from now on: nothing fresh after the fault.
            self.frozen = self.last_sent
        elif a.fault == "self-disarm":
            self.arm(False, "fault injected")
            self.heartbeat()
        elif a.fault == "malformed":
            # A HEARTBEAT whose vehicle type (250) is no MAV_TYPE: the checksum is right, the
            # content is not.
            msg = mav.MAVLink_heartbeat_message(250, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, self.mode,
                                                mav.MAV_STATE_ACTIVE, 3)
            self.conn.write(msg.pack(self.mav))

    def step(self):
        if self.args.hold_until_armed and self.armed_at is None:
            self.t = round(self.t + self.args.dt, 9)
            return
        traj = self.pinc.simulate(self.state, np.array([self.wrench]), dt=self.args.dt, vehicle=self.params)
        self.state = np.asarray(traj[1], dtype=float)
        self.t = round(self.t + self.args.dt, 9)

    def write_truth(self):
        if self.truth is not None:
            self.truth.write(json.dumps({"boot_ms": self.boot_ms(), "state": [float(s) for s in self.state],
                                         "wrench": self.wrench, "pwm": self.pwm, "armed": self.armed}) + "\n")

    def tick(self):
        """Takes the messages received, sets the outputs, sends what is due at the current
        time (the state at this time, the outputs from it on), then steps the physics once."""
        while True:
            try:
                self.arrival, m = self.inbox.get_nowait()
            except queue.Empty:
                break
            if m.get_type() != "BAD_DATA":
                self.handle(m)
            elif self.commands is not None:
                self.log_command("BAD_DATA", data=repr(m))
        self.arrival = None
        self.command_outputs()
        self.inject_fault()
        if self.t >= self.next_heartbeat:
            if not (self.fault_on and self.args.fault == "heartbeat-stop"):
                self.heartbeat()
            self.next_heartbeat += 1.0
        self.write_truth()
        for mid in STATE_IDS:  # in this order within a tick, as ArduSub's stream loop
            iv = self.intervals[mid]
            if iv is not None and self.t + 1e-9 >= self.due[mid]:
                self.send_state(mid)
                self.due[mid] += iv
                if self.due[mid] < self.t:
                    self.due[mid] = self.t + iv
        self.step()

    def run(self):
        end = self.args.duration
        while end is None or self.t < end:
            # Real time: the simulation never runs ahead of the wall clock.
            wait = self.start + self.t - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            self.tick()
            if self.truth is not None:
                self.truth.flush()


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--listen", help="HOST:PORT to listen on (pinc: udpout:HOST:PORT)")
    where.add_argument("--target", help="HOST:PORT to send to (pinc: udpin:HOST:PORT)")
    p.add_argument("--sysid", type=int, default=1)
    p.add_argument("--gcs-sysid", type=int, default=255, help="the only system id commands are taken from")
    p.add_argument("--mode", default="MANUAL", choices=sorted(MODES))
    p.add_argument("--armed", action="store_true", help="start armed (as if the pilot armed it)")
    p.add_argument("--pilot", action="store_true",
                   help="a built-in pilot gives random held MANUAL_CONTROL steps while armed")
    p.add_argument("--position-delay", type=float, default=20.0,
                   help="seconds after arming before LOCAL_POSITION_NED (inf: never, as without a DVL)")
    p.add_argument("--default-rate", type=float, default=4.0, help="stream rate before SET_MESSAGE_INTERVAL (Hz)")
    p.add_argument("--gain", type=float, default=1.0, help="JS_GAIN_DEFAULT")
    p.add_argument("--unanswered", nargs="*", default=[], help="parameters left unanswered (a firmware without them)")
    p.add_argument("--outputs", choices=["motors", "passthrough"], default="motors",
                   help="SERVO1..6_FUNCTION: the autopilot's motors (33-38) or RC pass-through (51-56)")
    p.add_argument("--gcs-timeout", type=float, default=5.0, help="GCS heartbeat failsafe (s, 0: off)")
    p.add_argument("--pilot-timeout", type=float, default=3.0, help="pilot input failsafe (s, 0: off)")
    p.add_argument("--water-density", type=float, default=1000.0)
    p.add_argument("--pressure-noise", type=float, default=0.2,
                   help="standard deviation of SCALED_PRESSURE2 (hPa; 0.2, about 2 mm: a Bar30's resolution)")
    p.add_argument("--firmware", default="4.1.2")
    p.add_argument("--dt", type=float, default=0.02, help="physics step (s)")
    p.add_argument("--x0", type=float, nargs=8, default=[0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    p.add_argument("--truth", help="JSON lines of the true state per physics step")
    p.add_argument("--commands", help="JSON lines of every command received and fault injected")
    p.add_argument("--vehicle-params", help="vehicle file whose coefficients the simulated vehicle has")
    p.add_argument("--hold-until-armed", action="store_true", help="the vehicle stays at --x0 until armed")
    p.add_argument("--fault", choices=["heartbeat-stop", "state-freeze", "drop-reorder", "self-disarm", "malformed"])
    p.add_argument("--fault-after", type=float, default=1.0,
                   help="seconds after the first pilot command before the fault starts")
    args = p.parse_args(argv)
    try:
        FakeArduSub(args).run()
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
