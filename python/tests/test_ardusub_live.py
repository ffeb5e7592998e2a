"""The live session on ArduSub itself (4.8.0-dev in ArduPilot's simulator, run by
../shared/ardusub_sitl/run_in_netns.sh in a private network namespace), on a stock BlueROV2:
no GPS, no DVL (`no_position_source.parm`), the outputs the autopilot's own motors, pinc the
firmware's first client (so it meets the autopilot's boot: arming refused, its EKF not yet
aligned), and only what an owner has: the vehicle file of the thrusters
(tests/fixtures/ardusub/sitl_vectored.toml, the BlueROV2's hull), no sensor flags. The
simulator's truth (SIM_STATE) is read only to check the figures.

- the command way is checked against the autopilot's outputs before anything is sent;
- the shipped model (trained for pinc's BlueROV2, not the simulator's) flies with the
  estimator on its defaults, which waits for the autopilot's estimate, says the heading is
  magnetic, and holds its targets against the truth;
- ArduSub's own ALT_HOLD flies the same references, logged in the same schema, beside it;
- a vehicle file identified from 86 s of stock excitation (the owner's path followed as a new
  user would: it spun the vehicle through the estimator before) tracks or stops within a turn.

$PINC_ARDUSUB_SITL names the simulator's folder (`.ci/run` sets it); without it these skip
(test_ardusub_sitl.py holds the firmware's location and the skip).
"""

import json
import math
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from mcap.reader import make_reader

# The firmware's location, its run script and the skip where it is missing: one home.
from test_ardusub_sitl import FIXTURES, JS_GAIN, NO_POSITION, run_on_firmware
from test_vehicle_link import pinc_binary, read_mcap
from test_vehicle_drive import mpc_track_binary

OWNER_VEHICLE = FIXTURES / "sitl_vectored.toml"
IDENTIFIED_86S = FIXTURES / "sitl_identified_86s.toml"
STOCK = [NO_POSITION, JS_GAIN]


def fly(out_dir, *extra, vehicle=OWNER_VEHICLE, parms=STOCK):
    """60 s of the default references on the stock firmware; the summary (JSON) and the run.
    `vehicle=None` gives no vehicle file (a fitted model carries its thrusters)."""
    own_vehicle = [] if vehicle is None else ["--vehicle", vehicle]
    client = [mpc_track_binary(), "--connect", "tcp:127.0.0.1:5760", *own_vehicle, "--arm", "--sim-truth",
              "--json", "--out-dir", out_dir, "--timeout", "30", *extra]
    r = run_on_firmware(out_dir, parms, client)
    assert r.stdout.strip(), f"mpc_track printed no summary (exit {r.returncode}): {r.stderr}"
    s = json.loads(r.stdout)
    live = s["live"]
    print(json.dumps({k: s[k] for k in ("samples", "rms_depth_m", "rms_heading_deg", "held_heading_error_max_deg",
                                        "steady_heading_error_deg", "stopped")}))
    print(json.dumps({k: live.get(k) for k in ("flown_by", "truth_rms", "estimate_rms_error", "raw_depth_rms_error",
                                               "heading_reference", "autopilot_not_ready", "model_misfits",
                                               "process_noise_scale", "fused", "rejected", "stop_trigger")}))
    return r, s


def metadata(path):
    """The MCAP file's metadata records."""
    with open(path, "rb") as f:
        return list(make_reader(f).iter_metadata())


def log_lines(summary):
    return [m["message"] for _, m in read_mcap(Path(summary["log"]))["/log"]]


@pytest.fixture(scope="module")
def stock_flights(tmp_path_factory):
    """Three flights of the stock vehicle at once, each on its own simulator (CI time: one
    flight's): pinc's MPC on the shipped model (default solver), the same on Clarabel, and
    ArduSub's own ALT_HOLD; pinc the first client of each."""
    runs = {"pinc": (), "clarabel": ("--qp", "clarabel"), "althold": ("--autopilot-hold", "althold")}
    with ThreadPoolExecutor(len(runs)) as pool:
        futures = {who: pool.submit(fly, tmp_path_factory.mktemp(f"stock_{who}"), *extra) for who, extra in runs.items()}
        return {who: f.result() for who, f in futures.items()}


@pytest.fixture(scope="module")
def pinc_stock(stock_flights):
    """pinc's MPC on the shipped model, the stock vehicle, pinc the first client."""
    return stock_flights["pinc"]


def test_per_thruster_commands_are_refused_on_the_stock_outputs_and_status_says_the_ways(tmp_path):
    # Right after boot (pinc the first client): status says the autopilot's estimate is not
    # ready; excite with --command thrusters is refused before arming, naming each output; a
    # later status sees the ways, the pilot gain, the magnetic heading and a ready estimate,
    # and the vehicle still disarmed.
    inputs = tmp_path / "in.csv"
    inputs.write_text("X,Y,Z,Mz\n" + "10,0,0,0\n" * 50)
    status = [str(pinc_binary()), "vehicle", "status", "--connect", "tcp:127.0.0.1:5760", "--timeout", "30", "--json"]
    script = tmp_path / "refuse.sh"
    script.write_text("\n".join([
        f"{' '.join(status)} --window 1.5 > '{tmp_path}/early.json' 2> '{tmp_path}/early.err'",
        f"'{pinc_binary()}' vehicle excite --connect tcp:127.0.0.1:5760 --timeout 10 --vehicle '{OWNER_VEHICLE}' "
        f"--inputs '{inputs}' --out '{tmp_path}/run.mcap' --arm --command thrusters "
        f"> '{tmp_path}/excite.out' 2> '{tmp_path}/excite.err'; echo $? > '{tmp_path}/excite.rc'",
        "sleep 5",
        f"{' '.join(status)} --window 3 > '{tmp_path}/late.json' 2> '{tmp_path}/late.err'",
    ]) + "\n")
    r = run_on_firmware(tmp_path, STOCK, ["bash", script], timeout=120)
    assert r.returncode == 0, r.stderr
    early = json.loads((tmp_path / "early.json").read_text())
    assert early["ekf_not_ready"], early
    err = (tmp_path / "excite.err").read_text()
    assert (tmp_path / "excite.rc").read_text().strip() == "1", err
    assert "safety stop [refused]" in err, err
    for n in range(1, 7):
        assert f"on output {n}, whose SERVO{n}_FUNCTION is {32 + n} (Motor{n})" in err, err
    assert "arming" not in err.lower(), "refused before any arm command"
    late = json.loads((tmp_path / "late.json").read_text())
    print(json.dumps({k: late[k] for k in ("command_ways", "js_gain", "heading_reference", "ekf_flags",
                                           "ekf_not_ready", "armed")}))
    assert late["armed"] is False
    assert late["command_ways"]["manual"]["allowed"] and not late["command_ways"]["thrusters"]["allowed"]
    assert late["js_gain"] == 1.0 and late["heading_reference"] == "magnetic"
    assert late["ekf_not_ready"] == [] and late["ekf_position_measured"] is False
    # The autopilot's vertical velocity: left out while its EKF initialises, then vouched for.
    assert early["vertical_velocity"]["ekf_vouches"] is False, early["vertical_velocity"]
    assert late["vertical_velocity"]["ekf_vouches"] is True and late["vertical_velocity"]["rate_hz"] > 5, late


def test_the_shipped_model_holds_a_stock_vehicle_on_its_defaults(pinc_stock):
    r, s = pinc_stock
    live = s["live"]
    assert s["stopped"] is None and r.returncode == 0, r.stderr
    assert s["samples"] >= 740 and live["disarm_sent"]
    # pinc, the first client, waited for the autopilot's estimate (it arms before its yaw is
    # aligned) and said so; then it said which heading it steers by.
    assert "waiting for the autopilot:" in r.stderr, r.stderr
    assert live["heading_reference"] == "magnetic"
    assert any("MAGNETIC north" in line for line in log_lines(s))
    # The estimate against the truth, on a model that is not this vehicle's (the issue's
    # targets: w 0.10 m/s, r 0.02 rad/s; measured w 0.015, r 0.010, from 0.32 and 0.014 at
    # first, 0.12-0.14 with the heave gain alone). The heave comes from the autopilot's own
    # vertical velocity (GLOBAL_POSITION_INT.vz: its accelerometers and depth sensor), each
    # sample's burst read whole before it is estimated.
    e = live["estimate_rms_error"]
    assert live["truth_samples"] >= 700
    assert e["w"] <= 0.05 and e["r"] <= 0.02, e
    assert live["vertical_velocity"]["taken"] >= 700, live["vertical_velocity"]
    assert e["z"] < live["raw_depth_rms_error"], (e, live["raw_depth_rms_error"])
    # Tracking, against the truth (depth) and the autopilot's heading.
    assert live["truth_rms"]["depth_m"] <= 0.20 and s["rms_heading_deg"] <= 6.0


def test_the_default_riccati_solver_flies_the_stock_vehicle_as_clarabel_does(stock_flights):
    # The live session's default solver (Riccati) tracks as Clarabel on the firmware (measured
    # before the switch: truth depth RMS 0.1250 against 0.1252 m, heading 4.23 against 4.25 deg,
    # solve median 0.10 against 0.51 ms), every cycle solved.
    _, riccati = stock_flights["pinc"]
    r, s = stock_flights["clarabel"]
    assert s["stopped"] is None and r.returncode == 0, r.stderr
    assert riccati["samples"] >= 740 and riccati["fallbacks"] == 0, riccati
    for key in ("depth_m", "heading_deg"):
        got, want = riccati["live"]["truth_rms"][key], s["live"]["truth_rms"][key]
        assert abs(got - want) <= 0.1 * want, (key, got, want)
    solvers = {who: {m.name: m.metadata for m in metadata(Path(run["log"]))}["run"]["qp_solver"]
               for who, run in (("default", riccati), ("asked", s))}
    assert solvers == {"default": "riccati", "asked": "clarabel"}


def test_ardusubs_own_althold_flies_the_same_references_beside_pinc(stock_flights, pinc_stock):
    r, s = stock_flights["althold"]
    live = s["live"]
    assert s["stopped"] is None and r.returncode == 0, r.stderr
    assert live["flown_by"] == "althold" and live["hold_mode_entered_s"] is not None
    assert s["samples"] >= 740
    # The same schema: the same summary and log topics as pinc's run.
    _, mine = pinc_stock
    assert set(read_mcap(Path(s["log"]))) >= {"/vehicle/state", "/mpc/reference", "/log", "/truth", "/estimate"}
    table = {
        "pinc": (mine["live"]["truth_rms"]["depth_m"], mine["rms_heading_deg"], mine["held_heading_error_max_deg"]),
        "ALT_HOLD": (live["truth_rms"]["depth_m"], s["rms_heading_deg"], s["held_heading_error_max_deg"]),
    }
    for who, (d, h, held) in table.items():
        print(f"{who:9s} RMS depth (truth) {d:.3f} m, RMS heading (autopilot's) {h:.2f} deg, held {held:.2f} deg")
    # pinc steers the heading better than the autopilot's own hold on the same references.
    assert table["pinc"][1] < table["ALT_HOLD"][1], table


def test_a_vehicle_file_identified_from_86_s_tracks_or_stops_within_a_turn(tmp_path):
    # The owner's path of the issue, on the stock vehicle: the identified file as the
    # controller's model (--oracle) and the estimator's. Before this round's estimator, this
    # file spun the vehicle at 1.83 rad/s for the whole run (17 turns, 501 measurements gated
    # out, no stop, exit 0; measured with main at b32dcd8).
    r, s = fly(tmp_path, "--oracle", vehicle=IDENTIFIED_86S)
    live = s["live"]
    truths = [m for _, m in read_mcap(Path(s["log"]))["/truth"]]
    # How far the vehicle turned, summed, over the whole run (the truth's heading unwrapped).
    turned = 0.0
    for a, b in zip(truths, truths[1:]):
        turned += abs(math.remainder(b["psi"] - a["psi"], 2 * math.pi))
    spin = max(abs(m["r"]) for m in truths)
    print(f"turned {math.degrees(turned):.0f} deg in all, fastest {spin:.2f} rad/s; stop {live['stop_trigger']}")
    if s["stopped"] is None:
        assert r.returncode == 0 and s["samples"] >= 740
        assert s["rms_heading_deg"] <= 10.0 and s["held_heading_error_max_deg"] <= 5.0, s
    else:
        assert r.returncode == 1 and live["disarm_sent"], r.stderr
        assert live["stop_trigger"] in ("estimate_lost", "yaw_rate"), live["stop_trigger"]
        assert "neutral command sent" in r.stderr
        # The default references turn 45 deg: what the vehicle turned beyond that before the
        # stop is less than one full turn.
        assert turned < 2 * math.pi, math.degrees(turned)
