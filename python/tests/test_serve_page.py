"""`pinc serve`'s page clicked through in a real browser against ArduSub's simulator: the status,
an excitation until the watch stops it, a fit, a 30 s flight and STOP (serve_page_driver.py does
the clicking inside the simulator's network namespace, with an independent MAVLink observer).
The page's figures are checked against the flight's MCAP, STOP against what the firmware says.

Needs $PINC_ARDUSUB_SITL (the firmware), Debian's chromium and chromium-driver (`apt install
chromium chromium-driver`; `.ci/run` installs them), selenium (the test extra), and
target/release/pinc and mpc_track with `train` and `vehicle`. Skips, saying which, without them.
About 4 minutes (real time).
"""

import json
import math
import shutil
import sys
from pathlib import Path

import pytest

from test_ardusub_live import OWNER_VEHICLE
from test_ardusub_sitl import NO_POSITION, run_on_firmware
from test_vehicle_link import pinc_binary, read_mcap

HERE = Path(__file__).resolve().parent
DRIVER = HERE / "serve_page_driver.py"

for needed in ("/usr/bin/chromium", "/usr/bin/chromedriver"):
    if not Path(needed).exists():
        pytest.skip(f"{needed} is missing: apt install chromium chromium-driver", allow_module_level=True)
pytest.importorskip("selenium", reason="selenium is in the Python package's test extra")


def wrap_deg(a):
    return (a + 180.0) % 360.0 - 180.0


def figures_of(mcap):
    """RMS depth and heading errors of a flight from its log alone (the state and the reference
    at each cycle), and the number of cycles."""
    topics = read_mcap(mcap)
    states = dict(topics["/vehicle/state"])
    refs = topics["/mpc/reference"]
    depth = [states[t]["sim"]["z"] - r["depth_m"] for t, r in refs]
    heading = [wrap_deg(states[t]["psi_deg"] - r["heading_deg"]) for t, r in refs]
    rms = lambda v: math.sqrt(sum(x * x for x in v) / len(v))  # noqa: E731
    return len(refs), rms(depth), rms(heading)


@pytest.fixture(scope="module")
def clicked(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("serve_page")
    out = tmp / "result.json"
    client = [sys.executable, DRIVER, "--pinc", pinc_binary(), "--vehicle", OWNER_VEHICLE, "--data", tmp / "data",
              "--shots", tmp / "shots", "--out", out]
    r = run_on_firmware(tmp, [NO_POSITION], client, timeout=900)
    serve_log = out.with_suffix(".serve.log")
    print(serve_log.read_text() if serve_log.exists() else "(no server log)")
    assert r.returncode == 0, f"the page's run failed: {r.stderr[-4000:]}"
    result = json.loads(out.read_text())
    print(json.dumps(result, indent=1))
    print("screenshots:", sorted(str(p) for p in (tmp / "shots").iterdir()))
    return tmp, result


def test_status_shows_the_firmware_as_an_independent_observer_sees_it(clicked):
    _, result = clicked
    status = result["status"]
    assert status["link-state"].startswith("connected (system 1)")
    assert status["v-mode"] == "MANUAL" and result["observer_mode"] == 19  # ArduSub's MANUAL
    assert status["v-armed"] == "disarmed"
    assert status["v-position"] == "none"  # a stock vehicle: no GPS, no DVL
    assert status["v-depth"].endswith(" m") and status["v-heading"].endswith(" deg")


def test_excitation_fit_and_flight_from_the_page(clicked):
    tmp, result = clicked
    assert result["excite_state"] == "finished", result["excite"]
    assert result["excite"]["recording"].endswith(".mcap")
    assert "the fit's report passes" in result["excite"]["verdict"], result["excite"]
    assert result["fit_state"] == "finished" and result["fit"]["passed"] == "passed", result["fit"]
    assert result["flight_state"] == "finished", result["flight"]
    flight = result["flight"]
    name = flight["job-what"].split()[0]
    [mcap] = (tmp / "data" / "flights" / name).glob("mpc_*.mcap")
    cycles, rms_depth, rms_heading = figures_of(mcap)
    print(f"log: {cycles} cycles, RMS depth {rms_depth:.4f} m, heading {rms_heading:.3f} deg; page: {flight}")
    # Every cycle was plotted live, and the page's figures are the log's.
    assert int(flight["fig-samples"]) == cycles == int(flight["job-samples"])
    assert cycles >= 0.95 * 30 / 0.08
    assert float(flight["fig-rms-depth"].split()[0]) == pytest.approx(rms_depth, abs=6e-5)
    assert float(flight["fig-rms-heading"].split()[0]) == pytest.approx(rms_heading, abs=6e-4)
    assert flight["fig-stopped"] == "no: ran to the end"
    kinds = {kind for kind, _ in result["files"]}
    assert kinds == {"recordings", "excitations", "models", "flights"}, result["files"]


def test_stop_reaches_neutral_and_disarmed_within_half_a_second(clicked):
    _, result = clicked
    stop = result["stop"]
    assert stop["disarmed_after_s"] is not None and stop["disarmed_after_s"] <= 0.5, stop
    # The thrusters' outputs (SERVO_OUTPUT_RAW at 25 Hz): neutral within 0.5 s, and neutral since.
    after = [(dt, outputs) for dt, outputs in stop["outputs"] if dt >= 0]
    neutral = [all(v == 1500 for v in outputs) for _, outputs in after]
    assert True in neutral, after
    first = neutral.index(True)
    assert after[first][0] <= 0.5 and all(neutral[first:]), after
    assert result["stop_state"] == "stopped"
    assert "disarmed seen after" in stop["page"]
    # The flight's own process stopped too, saying why.
    assert any("interrupted" in line or "STOP" in line for line in stop["job_log_tail"]), stop


def test_a_reload_and_a_second_tab_see_the_flight_going_on(clicked):
    _, result = clicked
    assert result["second_tab"]["job-what"] == result["flight"]["job-what"]
    assert result["second_tab"]["job-samples"] >= 100


def test_the_gamepad_moves_the_vehicle_centred_and_unplugged_holds_and_a_closed_page_disarms(clicked):
    _, result = clicked
    p = result["pilot"]
    print(json.dumps(p, indent=1))
    # Half the heave stick (0.15 m/s) for 5 s: down by more than 0.4 m.
    assert p["held_5_s"]["depth_m"] - p["start"]["depth_m"] >= 0.4, p
    # Centred: the depth held where it came to rest (the reference unchanged, the depth near it).
    assert abs(p["centred_6_s"]["depth_ref_m"] - p["centred_4_s"]["depth_ref_m"]) < 1e-6, p
    assert abs(p["centred_6_s"]["depth_m"] - p["centred_6_s"]["depth_ref_m"]) < 0.15, p
    # Unplugged mid-stick: the page sends centred sticks at once, the flight holds within 1.5 s.
    assert abs(p["unplugged_3_5_s"]["depth_ref_m"] - p["unplugged_1_5_s"]["depth_ref_m"]) < 1e-6, p
    # The page closed: the server stops the flight 10 s later, the vehicle disarmed.
    assert 10.0 <= p["disarmed_after_close_s"] <= 11.5, p
    assert p["state"] == "stopped" and any("no sticks from the page for 10 s" in line for line in p["log_tail"]), p


def test_cockpits_joystick_flies_from_the_page_and_the_ground_station_place_is_given_back(clicked):
    _, result = clicked
    c = result["cockpit_joystick"]
    print(json.dumps(c, indent=1))
    # Half the heave stick (0.15 m/s) for 5 s: down by more than 0.4 m.
    assert c["held_5_s"]["depth_m"] - c["start"]["depth_m"] >= 0.4, c
    # Ended by the page's resume (the flight runs until STOP or resume): handed back.
    assert c["state"] == "finished" and c["resume"].startswith("handed back to the pilot: mode MANUAL"), c
    taken, given = [line for line in c["log_tail"] if "(pinc; it was 255)" in line], \
        [line for line in c["log_tail"] if "MAV_GCS_SYSID = 255 again" in line]
    assert taken and given, c


def test_the_link_comes_back_after_the_autopilot_reboots(clicked):
    _, result = clicked
    assert result["reboot"]["links_opened"] >= 2 and result["reboot"]["page"].startswith("connected"), result["reboot"]


def test_a_server_killed_mid_run_leaves_the_vehicle_to_the_failsafe_and_a_partial_recording(clicked):
    _, result = clicked
    killed = result["killed"]
    assert killed["children_left"] == [], "the excitation died with the server"
    # ArduSub's pilot-input failsafe (3 s without MANUAL_CONTROL): the thrusters to neutral.
    after = [(dt, outputs) for dt, outputs in killed["outputs"] if dt >= 0]
    neutral = [all(v == 1500 for v in outputs) for _, outputs in after]
    assert True in neutral, after
    first = neutral.index(True)
    print(f"neutral {after[first][0]:.2f} s after the kill")
    assert after[first][0] <= 4.0 and all(neutral[first:]), after
    assert len(killed["partial"]) == 1 and killed["partial"][0].endswith(".mcap.partial")
    assert result["partial_fit_state"] == "finished", result["partial_fit"]
