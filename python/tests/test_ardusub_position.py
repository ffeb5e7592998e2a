"""pinc's MPC on four axes against ArduSub's own position controllers, on the firmware itself
(4.8.0-dev in ArduPilot's simulator, ../shared/ardusub_sitl), its GPS as the position source,
the full pilot gain and a 0.3 m/s current towards 30 deg (tests/fixtures/ardusub/current_0_3.parm).

Each comparison flies its runs side by side, each on its own simulator (CI time: one flight's,
not the sum). Every figure is against the simulator's truth (SIM_STATE: `lat_int`/`lon_int`,
depth, yaw), from where the vehicle truly was when control started.

- station: 60 s holding where control starts through a depth step (1 -> 2 m at 30 s) and a turn
  (0 -> 45 deg at 20 s): pinc on the simulator's own vehicle file, ArduSub's GUIDED streamed the
  same targets at the same rate, and POSHOLD (which holds where it entered and ignores depth and
  heading targets: the firmware's README);
- survey: 4 legs of 10 m, 2 m apart, 0.3 m/s, 2 m deep, pinc and GUIDED on the same schedule;
- the position source lost mid-station (SIM_GPS1_ENABLE 0): the goal dropped within a second,
  depth and heading held, no stop.

$PINC_ARDUSUB_SITL names the simulator's folder (`.ci/run` sets it); without it these skip.
"""

import json
import sys
from concurrent.futures import ThreadPoolExecutor

from test_ardusub_sitl import FIXTURES, INJECT, JS_GAIN, VEHICLE as SIM_VEHICLE, run_on_firmware
from test_ardusub_live import log_lines
from test_vehicle_drive import mpc_track_binary

CURRENT = FIXTURES / "current_0_3.parm"
GPS_CURRENT = [JS_GAIN, CURRENT]
# GPS comes about 20 s after arming (the firmware's README): wait for it, neutral, up to 45 s.
COMMON = ("--vehicle", SIM_VEHICLE, "--wait-position", "45", "--max-distance", "25")


def fly(out_dir, *extra, faults=(), timeout=420):
    """One flight on its own simulator; its summary (JSON) and the run."""
    client = [mpc_track_binary(), "--connect", "tcp:127.0.0.1:5760", "--arm", "--sim-truth", "--json",
              "--out-dir", out_dir, "--timeout", "30", *COMMON, *extra]
    if faults:
        inject = [sys.executable, INJECT, "--log", out_dir / "faults.jsonl"]
        for at, name, value in faults:
            inject += ["--at", str(at), name, str(value)]
        client = [*inject, "--", *client]
    r = run_on_firmware(out_dir, GPS_CURRENT, client, timeout=timeout)
    assert r.stdout.strip(), f"mpc_track printed no summary (exit {r.returncode}): {r.stderr}"
    s = json.loads(r.stdout)
    return r, s


def side_by_side(runs):
    with ThreadPoolExecutor(len(runs)) as pool:
        futures = {who: pool.submit(fly, *args, **kw) for who, (args, kw) in runs.items()}
        return {who: f.result() for who, f in futures.items()}


def row(who, r, s):
    live = s["live"]
    h = live["truth_horizontal"]
    assert s["stopped"] is None and r.returncode == 0, (who, r.stderr[-3000:])
    assert h is not None, (who, "no horizontal truth")
    out = {"horizontal_rms_m": h["rms_m"], "horizontal_max_m": h["max_m"], "finished_s": h["finished_s"],
           "schedule_s": h["schedule_end_s"], "depth_rms_m": live["truth_rms"]["depth_m"],
           "heading_rms_deg": live["truth_rms"]["heading_deg"], "held_heading_deg": s["held_heading_error_max_deg"],
           "samples": s["samples"]}
    print(f"{who:24s} {json.dumps(out)}")
    return out


def test_station_keeping_in_a_current_beside_guided_and_poshold(tmp_path):
    runs = side_by_side({
        "pinc (simulator's file)": ((tmp_path / "pinc", "--oracle", "--qp", "riccati", "--scenario", "station"), {}),
        "ArduSub GUIDED": ((tmp_path / "guided", "--autopilot-hold", "guided", "--scenario", "station"), {}),
        "ArduSub POSHOLD": ((tmp_path / "poshold", "--autopilot-hold", "poshold", "--scenario", "station"), {}),
    })
    t = {who: row(who, *run) for who, run in runs.items()}
    pinc, guided, poshold = t["pinc (simulator's file)"], t["ArduSub GUIDED"], t["ArduSub POSHOLD"]
    assert pinc["samples"] >= 740
    # pinc holds the point closer than GUIDED, and far closer than POSHOLD, in the same current.
    assert pinc["horizontal_rms_m"] < guided["horizontal_rms_m"], t
    assert pinc["horizontal_max_m"] < guided["horizontal_max_m"], t
    assert pinc["horizontal_rms_m"] < poshold["horizontal_rms_m"], t
    assert pinc["depth_rms_m"] <= 0.13, t


def test_a_survey_in_a_current_beside_guided(tmp_path):
    runs = side_by_side({
        "pinc (simulator's file)": ((tmp_path / "pinc", "--oracle", "--qp", "riccati", "--scenario", "survey"), {}),
        "ArduSub GUIDED": ((tmp_path / "guided", "--autopilot-hold", "guided", "--scenario", "survey"), {}),
    })
    t = {who: row(who, *run) for who, run in runs.items()}
    pinc, guided = t["pinc (simulator's file)"], t["ArduSub GUIDED"]
    assert pinc["horizontal_rms_m"] < guided["horizontal_rms_m"], t
    assert pinc["finished_s"] is not None and guided["finished_s"] is not None, t
    assert pinc["finished_s"] <= guided["finished_s"] + 0.5, t
    assert pinc["depth_rms_m"] <= 0.13, t


def test_the_position_source_lost_drops_the_goal_and_holds_depth_and_heading(tmp_path):
    # The GPS switched off 40 s after arming (about 20 s into control, GPS fused from about 20 s
    # after arming): the goal is dropped within a second of the last fused position, the run
    # goes on to its end on depth and heading, and says so in the terminal and the log.
    r, s = fly(tmp_path, "--oracle", "--qp", "riccati", "--scenario", "station",
               faults=[(40, "SIM_GPS1_ENABLE", 0)])
    live = s["live"]
    assert s["stopped"] is None and r.returncode == 0, r.stderr[-3000:]
    changes = live["horizontal_goal_changes"]
    assert changes and changes[0][1] is True, changes
    assert "horizontal goal dropped" in r.stderr, r.stderr[-3000:]
    assert any("horizontal goal dropped" in line for line in log_lines(s))
    assert live["truth_rms"]["depth_m"] <= 0.2 and s["held_heading_error_max_deg"] <= 2.0, live["truth_rms"]
