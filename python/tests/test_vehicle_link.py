"""`pinc vehicle status` and `pinc vehicle record` against the fake ArduSub autopilot
(fake_ardusub.py) over UDP on loopback.

Needs the `pinc` binary (target/release/pinc, or $PINC_BIN; CI builds it before pytest), the
Python bindings (the fake moves `pinc.simulate`), pymavlink and mcap.
"""

import json
import math
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("pymavlink", reason="the fake autopilot needs pymavlink (pip install './python[test]')")
mcap_reader = pytest.importorskip("mcap.reader", reason="reading the recording needs mcap (pip install mcap)")
pytest.importorskip("zstandard", reason="the recording's chunks are zstd: pip install zstandard")

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
FAKE = HERE / "fake_ardusub.py"


def pinc_binary() -> Path:
    given = os.environ.get("PINC_BIN")
    path = Path(given) if given else ROOT / "target" / "release" / "pinc"
    if not path.is_file():
        pytest.skip(f"{path} is not built: run `cargo build --release --features vehicle` first (CI builds it before pytest)")
    return path


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Fake:
    """The fake autopilot in its own process, listening on a free loopback port."""

    def __init__(self, *args: str):
        self.port = free_udp_port()
        self.proc = subprocess.Popen(
            [sys.executable, str(FAKE), "--listen", f"127.0.0.1:{self.port}", *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline()
        if "fake ArduSub" not in line:
            self.proc.kill()
            err = self.proc.stderr.read()
            pytest.fail(f"the fake autopilot did not start: {line!r} {err}")
        self.url = f"udpout:127.0.0.1:{self.port}"

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()


@pytest.fixture
def fake_factory():
    fakes = []

    def start(*args):
        f = Fake(*args)
        fakes.append(f)
        return f

    yield start
    for f in fakes:
        f.stop()


def run_pinc(*args, timeout=20):
    return subprocess.run([str(pinc_binary()), *args], capture_output=True, text=True, timeout=timeout)


def test_status_reports_an_armed_vehicle_with_a_position(fake_factory):
    fake = fake_factory("--armed", "--pilot", "--position-delay", "0", "--firmware", "4.1.2")
    r = run_pinc("vehicle", "status", "--connect", fake.url, "--timeout", "5", "--window", "2", "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert (s["vehicle_type"], s["autopilot"], s["mode"], s["armed"]) == ("SUBMARINE", "ARDUPILOTMEGA", "MANUAL", True)
    assert s["system_id"] == 1 and s["custom_mode"] == 19
    assert s["firmware"].startswith("4.1.2 (official")
    assert s["capability"] == "full"
    assert all(p["seen"] for p in s["parts"].values()), s["parts"]
    # pinc asks for its control rate (1 / 0.08 s = 12.5 Hz); the fake steps at 50 Hz, so it
    # can honour 12.5 Hz exactly; the window's count gives the rate to a sample or so.
    for name in ["ATTITUDE", "LOCAL_POSITION_NED", "SCALED_PRESSURE2", "SERVO_OUTPUT_RAW"]:
        assert s["messages"][name]["rate_hz"] == pytest.approx(12.5, rel=0.1), name
    assert s["parts"]["velocity"]["source"] == "LOCAL_POSITION_NED"


def test_status_without_a_position_says_depth_and_heading_only(fake_factory):
    # Disarmed, in ALT_HOLD, and no position source (as without a DVL): depth from pressure.
    fake = fake_factory("--mode", "ALT_HOLD", "--position-delay", "inf")
    r = run_pinc("vehicle", "status", "--connect", fake.url, "--timeout", "5", "--window", "1.5", "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert (s["mode"], s["armed"], s["capability"]) == ("ALT_HOLD", False, "depth_heading")
    assert not s["parts"]["position"]["seen"] and not s["parts"]["velocity"]["seen"]
    assert s["parts"]["depth"]["seen"] and s["parts"]["depth"]["source"] == "SCALED_PRESSURE2"
    assert "LOCAL_POSITION_NED" not in s["messages"]
    # And the text form says why.
    r = run_pinc("vehicle", "status", "--connect", fake.url, "--timeout", "5", "--window", "1")
    assert r.returncode == 0, r.stderr
    assert "no measured body velocities" in r.stdout and "ALT_HOLD" in r.stdout
    assert "the MPC runs on the state estimate" in r.stdout, r.stdout


def test_commands_from_another_system_id_are_ignored(fake_factory):
    # ArduSub takes commands from SYSID_MYGCS only: sending as 200, the interval requests and
    # the version request go unanswered, and the streams stay at the fake's default 4 Hz.
    fake = fake_factory("--armed", "--pilot", "--position-delay", "0")
    r = run_pinc("vehicle", "status", "--connect", fake.url, "--gcs-sysid", "200", "--timeout", "5",
                 "--window", "2", "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["firmware"] is None
    assert s["messages"]["ATTITUDE"]["rate_hz"] == pytest.approx(4.0, rel=0.15)


def test_status_exits_1_when_nothing_answers():
    port = free_udp_port()
    start = time.monotonic()
    r = run_pinc("vehicle", "status", "--connect", f"udpin:127.0.0.1:{port}", "--timeout", "1.5")
    took = time.monotonic() - start
    assert r.returncode == 1
    assert "no autopilot heartbeat" in r.stderr and "1.5 s" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert took < 1.5 + 3.0
    r = run_pinc("vehicle", "status", "--connect", "bogus:1.2.3.4:5")
    assert r.returncode == 1 and "unknown transport" in r.stderr


def read_mcap(path):
    topics = {}
    with open(path, "rb") as f:
        for _schema, channel, message in mcap_reader.make_reader(f).iter_messages():
            topics.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
    return topics


def test_record_holds_the_fakes_state_at_matching_times(fake_factory, tmp_path):
    truth_path = tmp_path / "truth.jsonl"
    fake = fake_factory("--armed", "--pilot", "--position-delay", "0.5", "--truth", str(truth_path))
    out = tmp_path / "run.mcap"
    r = run_pinc("vehicle", "record", "--connect", fake.url, "--out", str(out), "--duration", "3",
                 "--timeout", "5")
    assert r.returncode == 0, r.stderr
    assert out.is_file() and not (tmp_path / "run.mcap.partial").exists()
    fake.stop()
    truth = {}
    for line in truth_path.read_text().splitlines():
        t = json.loads(line)
        truth[t["boot_ms"]] = t
    topics = read_mcap(out)
    for topic in ["/vehicle/state", "/mpc/command", "/vehicle/outputs", "/log", "/mavlink/HEARTBEAT",
                  "/mavlink/ATTITUDE", "/mavlink/LOCAL_POSITION_NED", "/mavlink/SCALED_PRESSURE2",
                  "/mavlink/SERVO_OUTPUT_RAW"]:
        assert topics.get(topic), f"no {topic} in {sorted(topics)}"

    # Each value crosses MAVLink as a float32 (relative error 6e-8): positions of a few metres
    # and velocities below 1 m/s come back within 1e-6, and turning the NED velocity by a
    # float32 heading adds as much again; 1e-5 leaves a factor of 5 or more.
    tol = 1e-5
    compared = 0
    names = ["x", "y", "z", "psi", "u", "v", "w", "r"]
    for log_time, s in topics["/vehicle/state"]:
        ms = round(log_time / 1e6)
        assert s["t_autopilot_s"] == pytest.approx(ms / 1000)
        if s["capability"] != "full":
            continue
        want = truth[ms]["state"]
        for i, name in enumerate(names):
            got = s["sim"][name]
            diff = got - want[i]
            if name == "psi":  # pinc unwraps from where it joined; the fake from its start
                diff = (diff + math.pi) % (2 * math.pi) - math.pi
            assert abs(diff) < tol, f"{name} at {ms} ms: {got} vs {want[i]}"
        compared += 1
    # 3 s at 12.5 Hz, less the start-up: at least 25 full samples.
    assert compared >= 25, compared
    moved = [t["state"] for t in truth.values()]
    assert max(abs(m[4]) for m in moved) > 0.02, "the fake's pilot should have moved the vehicle"

    # The thruster outputs are the fake's PWM at the same boot time.
    for _, o in topics["/vehicle/outputs"]:
        ms = o["time_usec"] // 1000
        assert [o["pwm"][str(c)] for c in range(1, 7)] == truth[ms]["pwm"]
    # A plain recording knows no body input: nulls at every state time.
    commands = dict(topics["/mpc/command"])
    for log_time, _ in topics["/vehicle/state"]:
        assert all(v is None for v in commands[log_time]["input"].values())
    assert any("armed" in m["message"] for _, m in topics["/log"])

    # `pinc dataset import` reads the file: every state row is read, and without a body input
    # no window can be cut, which is what it must say.
    r = run_pinc("dataset", "import", "--out", str(tmp_path / "ds"), str(out))
    if r.returncode != 0:
        for unread in ["no messages on topic", "not an MCAP", "damaged", "not JSON", "no field", "has no"]:
            assert unread not in r.stderr, r.stderr
        found = re.search(r"(\d+) rows with NaN", r.stderr)
        assert found, r.stderr
        # The import may drop a row at an edge while aligning; the rest are all read.
        assert int(found.group(1)) >= len(topics["/vehicle/state"]) - 2, r.stderr


def test_record_refuses_when_nothing_answers(tmp_path):
    port = free_udp_port()
    out = tmp_path / "none.mcap"
    r = run_pinc("vehicle", "record", "--connect", f"udpin:127.0.0.1:{port}", "--out", str(out),
                 "--timeout", "1", "--duration", "1")
    assert r.returncode == 1 and "no autopilot heartbeat" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_finishes_the_recording(fake_factory, tmp_path):
    import signal

    fake = fake_factory("--armed", "--pilot", "--position-delay", "0")
    out = tmp_path / "run.mcap"
    proc = subprocess.Popen([str(pinc_binary()), "vehicle", "record", "--connect", fake.url, "--out", str(out),
                             "--timeout", "5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # Recording has begun once the partial file exists; then a second of messages.
    deadline = time.monotonic() + 8
    while not (tmp_path / "run.mcap.partial").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=10)
    assert proc.returncode == 0, stderr
    assert "Ctrl-C" in stdout
    assert out.is_file() and not (tmp_path / "run.mcap.partial").exists()
    with open(out, "rb") as f:  # finished: the summary section is written
        assert mcap_reader.make_reader(f).get_summary() is not None
    topics = read_mcap(out)
    assert len(topics["/vehicle/state"]) >= 5
    assert "recording ended: Ctrl-C" in topics["/log"][-1][1]["message"]


def test_fake_mixes_manual_control_like_ardusub_and_disarms_on_pilot_silence(fake_factory, tmp_path):
    """The fake itself, driven by pymavlink as the ground station (system 255): what the
    later commanding steps rely on."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    truth = tmp_path / "truth.jsonl"
    fake = fake_factory("--position-delay", "0", "--truth", str(truth), "--x0", "0", "0", "5", "0", "0", "0", "0", "0")
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{fake.port}", source_system=255, source_component=190)
    m = gcs.mav
    m.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    assert gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=5) is not None
    m.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                        mavutil.mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, 50_000, 0, 0, 0, 0, 0)
    m.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)

    def outputs_after(x, y, z, r, seconds=0.6):
        end = time.monotonic() + seconds
        last = None
        while time.monotonic() < end:
            m.manual_control_send(1, x, y, z, r, 0)
            m.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            msg = gcs.recv_match(type="SERVO_OUTPUT_RAW", blocking=True, timeout=0.1)
            if msg is not None:
                last = [msg.servo1_raw, msg.servo2_raw, msg.servo3_raw, msg.servo4_raw, msg.servo5_raw,
                        msg.servo6_raw]
        return last

    # Full forward: the factor signs fitted on ArduSub's own simulator log (docs/VEHICLE.md),
    # -1 -1 +1 +1 on the horizontal thrusters, +-400 us at JS_GAIN_DEFAULT 1.
    assert outputs_after(1000, 0, 500, 0) == [1100, 1100, 1900, 1900, 1500, 1500]
    # Half up (z = 750): the vertical thrusters' factor is -1, 0.8 us per unit above 500.
    assert outputs_after(0, 0, 750, 0) == [1500, 1500, 1500, 1500, 1300, 1300]
    # Pilot input stops: disarmed by the 3 s failsafe, with a STATUSTEXT saying so.
    end = time.monotonic() + 6
    text = None
    while time.monotonic() < end and text is None:
        m.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        msg = gcs.recv_match(type="STATUSTEXT", blocking=True, timeout=0.5)
        if msg is not None:
            text = msg.text
    assert text is not None and "pilot input failsafe" in text
    time.sleep(0.3)  # a few more physics ticks, so the truth file has the outputs after the disarm
    fake.stop()
    rows = [json.loads(line) for line in truth.read_text().splitlines()]
    armed = [r for r in rows if r["armed"]]
    # Going forward, then up: u > 0 while forward, z falls (NED: up) during the heave step.
    assert max(r["state"][4] for r in armed) > 0.05
    up = [r for r in armed if r["pwm"][4] == 1300]
    assert up and up[-1]["state"][2] < up[0]["state"][2]
    assert rows[-1]["pwm"] == [1500] * 6 and not rows[-1]["armed"]
