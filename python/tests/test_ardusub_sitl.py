"""Against ArduSub itself: the real autopilot firmware (4.8.0-dev) in ArduPilot's simulator,
run by ../shared/ardusub_sitl/run_in_netns.sh in a private network namespace (every packet
stays on its loopback). $PINC_ARDUSUB_SITL names that folder (`.ci/run` sets it); without it
these tests skip.

The closed loops are real time (the firmware's clock is the host's at speedup 1): about a
minute and a half each. The controller's model is the simulator's vehicle identified from its
own logs (tests/fixtures/ardusub/sitl_identified.toml, the owner's path of docs/VEHICLE.md);
the estimate is checked against the simulator's truth (SIM_STATE).

Needs target/release/pinc and target/release/mpc_track (`--features vehicle`), pymavlink and mcap.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from test_vehicle_link import ROOT, pinc_binary, read_mcap
from test_vehicle_drive import mpc_track_binary

SITL_DIR = os.environ.get("PINC_ARDUSUB_SITL")
if not SITL_DIR:
    pytest.skip("PINC_ARDUSUB_SITL is not set: the firmware tests need ArduSub's simulator "
                "(../shared/ardusub_sitl; .ci/run sets it)", allow_module_level=True)
SITL = Path(SITL_DIR)
RUN = SITL / "run_in_netns.sh"
if not (SITL / "ardusub").is_file():
    pytest.skip(f"{SITL}/ardusub is missing", allow_module_level=True)

HERE = Path(__file__).resolve().parent
INJECT = HERE / "sitl_inject.py"
FIXTURES = ROOT / "tests" / "fixtures" / "ardusub"
VEHICLE = FIXTURES / "sitl_truth.toml"
PASSTHROUGH = FIXTURES / "thrusters_passthrough.parm"
JS_GAIN = SITL / "js_gain_full.parm"
NO_POSITION = SITL / "no_position_source.parm"


def run_on_firmware(tmp_path, parms, client, timeout=300):
    """Runs `client` (a list) beside the firmware, pinc being its first client (on 5760)."""
    extra = ["-p", ",".join(str(p) for p in parms)] if parms else []  # none: sub.parm alone (GPS on)
    cmd = [str(RUN), "-d", str(tmp_path / "sitl"), *extra, "--", *map(str, client)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def mpc_track_args(tmp_path, way, *extra):
    # The simulator's depth sensor has 0.12 m of noise (its README) and lags its truth by about
    # 0.04 s (measured: raw depth at its own stamps against SIM_STATE): the estimator is told so.
    return [mpc_track_binary(), "--connect", "tcp:127.0.0.1:5760", "--vehicle", VEHICLE, "--oracle", "--arm",
            "--command", way, "--js-gain", "1", "--sim-truth", "--depth-std", "0.12", "--depth-delay", "0.04",
            "--json",
            "--out-dir", tmp_path / "out", "--timeout", "30", *extra]


def with_faults(client, faults, log):
    """`client` run by sitl_inject.py, which sets each `(seconds after arming, name, value)`
    simulator parameter and logs it to `log` (nothing added without faults)."""
    if not faults:
        return client
    inject = [sys.executable, INJECT, "--log", log]
    for at, name, value in faults:
        inject += ["--at", str(at), name, str(value)]
    return [*inject, "--", *client]


def closed_loop(tmp_path, parms, way, *extra, faults=(), timeout=300):
    client = with_faults(mpc_track_args(tmp_path, way, *extra), faults, tmp_path / "faults.jsonl")
    r = run_on_firmware(tmp_path, parms, client, timeout=timeout)
    assert r.stdout.strip(), f"mpc_track printed no summary (exit {r.returncode}): {r.stderr}"
    summary = json.loads(r.stdout)
    print(json.dumps({k: summary[k] for k in ("samples", "rms_depth_m", "rms_heading_deg",
                                              "held_heading_error_max_deg", "stopped")}), summary["live"])
    return r, summary


def fault_log(tmp_path):
    return [json.loads(line) for line in (tmp_path / "faults.jsonl").read_text().splitlines()]


def logs(summary):
    return [m["message"] for _, m in read_mcap(Path(summary["log"]))["/log"]]


# The targets for 60 s of the default references: RMS depth 0.15 m, heading 6 deg, held
# heading 1 deg; the estimate's RMS error 0.05 m/s and rad/s on w and r, 0.15 m/s on u and v.
# Runs on the firmware are not repeatable (TCP timing, the simulator's sensor noise): the
# depth and heave bounds carry a margin over the targets for that spread (measured runs:
# depth 0.131-0.147 m, w 0.051-0.077 m/s; docs/VEHICLE.md).
def assert_tracks(summary, r):
    assert summary["stopped"] is None and r.returncode == 0, r.stderr
    assert summary["samples"] >= 740
    assert summary["rms_depth_m"] <= 0.18 and summary["rms_heading_deg"] <= 6.0
    assert summary["held_heading_error_max_deg"] <= 1.0
    assert summary["live"]["disarm_sent"], "pinc armed, so it disarms at the end"


def assert_delivered(summary):
    # The thruster outputs carry what was commanded (a wrong --js-gain would show here).
    for name, ratio in summary["live"]["delivered_to_commanded"].items():
        assert ratio is None or abs(ratio - 1) <= 0.25, summary["live"]["delivered_to_commanded"]


def assert_estimate(summary):
    e = summary["live"]["estimate_rms_error"]
    assert summary["live"]["truth_samples"] >= 700
    assert e["w"] <= 0.07 and e["r"] <= 0.05, e
    assert e["u"] <= 0.15 and e["v"] <= 0.15, e


# `--command manual` with GPS flies in test_ardusub_fit.py (the simulator's own file beside the
# fitted four-axis model and GUIDED, its estimate's u, v, w within 0.05 m/s); here the
# per-thruster way.
@pytest.mark.parametrize("way", ["thrusters"])
def test_closed_loop_with_a_position_source(tmp_path, way):
    # GPS on (the simulator's GPS works under water): the EKF has a position ~20 s after
    # arming; control starts at the first full state and runs 60 s. pinc is the firmware's
    # first client, so its first arm commands are refused (EKF alignment) and it retries.
    parms = [JS_GAIN] if way == "manual" else [JS_GAIN, PASSTHROUGH]
    r, s = closed_loop(tmp_path, parms, way, "--wait-position", "45")
    assert_tracks(s, r)
    assert_estimate(s)
    assert "arming refused" in r.stderr and "Arm:" in r.stderr, r.stderr
    lines = logs(s)
    assert any("with a position source" in line for line in lines), lines
    assert any(line.startswith("autopilot ") for line in lines), "the autopilot's STATUSTEXTs are logged"


@pytest.mark.parametrize("way", ["manual", "thrusters"])
def test_closed_loop_on_a_stock_vehicle_runs_on_the_estimate(tmp_path, way):
    # No GPS, no DVL: depth from the external pressure sensor, heading and yaw rate from
    # ATTITUDE, the thruster outputs. The estimate gives u v w.
    # no_position_source.parm leaves JS_GAIN_DEFAULT at 0.5: js_gain_full.parm sets 1.0.
    parms = [NO_POSITION, JS_GAIN] if way == "manual" else [NO_POSITION, PASSTHROUGH]
    r, s = closed_loop(tmp_path, parms, way)
    assert_tracks(s, r)
    assert_delivered(s)
    assert_estimate(s)
    assert any("without a position source" in line for line in logs(s))


def test_position_source_lost_mid_run_goes_on_on_the_estimate(tmp_path):
    # GPS off 20 s into the control (it starts ~22 s after arming): the run goes on.
    r, s = closed_loop(tmp_path, [JS_GAIN], "manual", "--wait-position", "45", "--duration", "40",
                       faults=[(42, "SIM_GPS1_ENABLE", 0)])
    assert s["stopped"] is None and r.returncode == 0, r.stderr
    assert [f["name"] for f in fault_log(tmp_path) if f["event"] == "param_set"] == ["SIM_GPS1_ENABLE"]
    lines = logs(s)
    assert any("position source lost" in line for line in lines), lines
    assert s["rms_depth_m"] <= 0.15 and s["rms_heading_deg"] <= 6.0
    # ArduSub's EKF dead-reckons for 15 s after its GPS goes, reporting a good position for the
    # first 7 s while LOCAL_POSITION_NED's velocity drifts to 0.6 m/s on a still vehicle
    # (measured): pinc stops fusing it when the GPS loses its fix, within two of its reports.
    fault = next(f for f in fault_log(tmp_path) if f["event"] == "param_set")
    topics = read_mcap(Path(s["log"]))
    log_time, first = topics["/estimate"][0]
    t0 = first["t_autopilot_s"] - log_time * 1e-9  # the autopilot time of the log's time 0
    stops = [t * 1e-9 + t0 for t, m in topics["/log"] if "no longer measures its position" in m["message"]]
    assert stops, lines
    print(f"GPS off at {fault['boot_s']:.2f} s, position no longer fused at {stops[0]:.2f} s; "
          f"{s['live']['dead_reckoned_left_out']} measurements left out")
    assert 0 <= stops[0] - fault["boot_s"] <= 2.5
    assert s["live"]["dead_reckoned_left_out"] > 0
    # The estimate's sway after the loss against the truth (the vehicle holds still sideways).
    truths = [m for _, m in topics["/truth"]]
    after = [m for _, m in topics["/estimate"] if m["t_autopilot_s"] > fault["boot_s"] + 1]
    errs = []
    for e in after:
        near = min(truths, key=lambda tr: abs(tr["t_autopilot_s"] - e["t_autopilot_s"]))
        errs.append(e["estimate"][5] - near["v"])
    v_rms = (sum(x * x for x in errs) / len(errs)) ** 0.5
    print(f"v RMS error after the loss {v_rms:.3f} m/s")
    assert v_rms <= 0.15, v_rms
    # The dead-reckoned position's vertical velocity is still the EKF's (accelerometers and
    # depth): kept, it holds the heave (w RMS error over the run 0.025 m/s; 0.062 with it left
    # out with the position).
    assert s["live"]["estimate_rms_error"]["w"] <= 0.05, s["live"]["estimate_rms_error"]


def test_depth_sensor_lost_stops_with_neutral_and_disarms(tmp_path):
    # With SIM_BAR2_DISABLE the firmware keeps sending SCALED_PRESSURE2, its last reading
    # repeated (measured): pinc stops once the reading has not changed for --max-frozen (1 s).
    r, s = closed_loop(tmp_path, [NO_POSITION, JS_GAIN], "manual", "--duration", "40",
                       faults=[(15, "SIM_BAR2_DISABLE", 1)])
    assert r.returncode == 1
    assert s["live"]["stop_trigger"] == "sensor_lost" and s["live"]["disarm_sent"], s["live"]
    assert "depth reading has not changed" in r.stderr and "neutral command sent" in r.stderr, r.stderr
    fault = next(f for f in fault_log(tmp_path) if f["event"] == "param_set")
    stop, neutral = s["live"]["stop_autopilot_s"], s["live"]["neutral_autopilot_s"]
    print(f"depth sensor off at {fault['boot_s']:.3f} s, stop at {stop:.3f} s, neutral at {neutral:.3f} s "
          f"(autopilot time)")
    # The last real reading came up to one sample before the fault (the injector's autopilot
    # time is itself up to one sample old); the stop comes at the first sample past 1 s after it.
    assert 1.0 - 0.25 <= stop - fault["boot_s"] <= 1.0 + 0.25
    assert 0 <= neutral - stop <= 0.08


def test_signing_with_a_wrong_key_accepts_nothing(tmp_path):
    # The autopilot gets key A; pinc with key B hears nothing (every frame is signed with A) and
    # says why; pinc with key A works.
    key_a, key_b = tmp_path / "a.key", tmp_path / "b.key"
    key_a.write_text("correct horse battery staple\n")
    key_b.write_text("0123456789abcdef" * 4 + "\n")
    script = tmp_path / "signing.sh"
    script.write_text("\n".join([
        "set -u",
        f"'{pinc_binary()}' vehicle setup-signing --connect tcp:127.0.0.1:5760 --timeout 30 --key '{key_a}' "
        f"> '{tmp_path}/setup.out' 2> '{tmp_path}/setup.err' || exit 10",
        f"'{pinc_binary()}' vehicle status --connect tcp:127.0.0.1:5760 --timeout 5 --signing-key '{key_b}' "
        f"> '{tmp_path}/wrong.out' 2> '{tmp_path}/wrong.err'; echo $? > '{tmp_path}/wrong.rc'",
        f"'{pinc_binary()}' vehicle status --connect tcp:127.0.0.1:5760 --timeout 5 --json "
        f"> '{tmp_path}/unsigned.out' 2> '{tmp_path}/unsigned.err'; echo $? > '{tmp_path}/unsigned.rc'",
        f"'{pinc_binary()}' vehicle status --connect tcp:127.0.0.1:5760 --timeout 10 --json --signing-key '{key_a}' "
        f"> '{tmp_path}/right.out' 2> '{tmp_path}/right.err'; echo $? > '{tmp_path}/right.rc'",
    ]) + "\n")
    r = run_on_firmware(tmp_path, [JS_GAIN], ["bash", script], timeout=180)
    setup_err = (tmp_path / "setup.err").read_text() if (tmp_path / "setup.err").exists() else ""
    assert r.returncode == 0, (r.stderr, setup_err)
    assert "signing set up" in (tmp_path / "setup.out").read_text()
    assert (tmp_path / "wrong.rc").read_text().strip() == "1"
    wrong = (tmp_path / "wrong.err").read_text()
    assert "no autopilot heartbeat" in wrong and "signing is on" in wrong, wrong
    # Signed frames are dropped by a link without the key too... the autopilot signs all it
    # sends, and an unsigned link still parses signed frames: what it must not get is an answer
    # to its unsigned commands, so its status shows no state streams.
    right = json.loads((tmp_path / "right.out").read_text())
    assert (tmp_path / "right.rc").read_text().strip() == "0", (tmp_path / "right.err").read_text()
    assert right["capability"] != "none", right
