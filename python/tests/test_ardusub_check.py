"""`pinc vehicle check` against ArduSub itself: the real autopilot firmware (4.8.0-dev) in
ArduPilot's simulator, started from sub.parm's defaults by ../shared/ardusub_sitl/run_in_netns.sh
in a private network namespace (every packet stays on its loopback). $PINC_ARDUSUB_SITL names
that folder (`.ci/run` sets it); without it the test skips.

One simulator run, pinc its first client (port 5760), then each step in turn: the check for a
DVL and a USBL fails naming each parameter to change; --set saves the old values to a file and
sets them; the values are read back by pymavlink (a second ground station on port 5762) and by
the check, which passes; --restore sets the saved values back, read back the same two ways.
About 40 s.

Needs target/release/pinc (`--features vehicle`) and pymavlink.
"""

import json
import subprocess
import sys

import pytest

# The simulator's folder, or a skip naming why (test_ardusub_sitl.py's).
from test_ardusub_sitl import RUN
from test_vehicle_link import pinc_binary

# What a DVL and a USBL need that sub.parm's defaults do not have (the simulator's values, read
# from it), and what `--set` gives them.
DEFAULTS = {"VISO_TYPE": 0.0, "EK3_SRC1_VELXY": 3.0, "GPS1_TYPE": 1.0}
WANTED = {"VISO_TYPE": 1.0, "EK3_SRC1_VELXY": 6.0, "GPS1_TYPE": 14.0}

# A second ground station (system 254, the simulator's SERIAL1) that reads parameters by name
# and prints them as JSON: the read-back that is not pinc's.
READ_BACK = """
import json, sys, time
from pymavlink import mavutil
m = mavutil.mavlink_connection("tcp:127.0.0.1:5762", source_system=254)
m.wait_heartbeat(timeout=20)
found = {}
deadline = time.time() + 10
while len(found) < len(sys.argv) - 1 and time.time() < deadline:
    for name in sys.argv[1:]:
        if name not in found:
            m.mav.param_request_read_send(m.target_system, m.target_component, name.encode(), -1)
    end = time.time() + 0.5
    while time.time() < end:
        p = m.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.1)
        if p is not None and p.param_id in sys.argv[1:]:
            found[p.param_id] = p.param_value
print(json.dumps(found))
"""


def test_check_fails_names_each_parameter_sets_them_and_restores_them(tmp_path):
    pytest.importorskip("pymavlink", reason="the read-back needs pymavlink (pip install './python[test]')")
    reader = tmp_path / "read_back.py"
    reader.write_text(READ_BACK)
    backup = tmp_path / "before.parm"
    check = f"'{pinc_binary()}' vehicle check --connect tcp:127.0.0.1:5760 --timeout 30"
    read = f"'{sys.executable}' '{reader}' {' '.join(WANTED)}"

    def step(name, cmd):
        return f"{cmd} > '{tmp_path}/{name}.out' 2> '{tmp_path}/{name}.err'; echo $? > '{tmp_path}/{name}.rc'"

    script = tmp_path / "steps.sh"
    script.write_text("\n".join([
        step("before", f"{check} --sensors dvl,usbl --json"),
        # Without a position the declination is the owner's to give: --set refuses, changing nothing.
        step("no_declination", f"{check} --sensors none --set --backup '{tmp_path}/never.parm'"),
        step("set", f"{check} --sensors dvl,usbl --set --backup '{backup}'"),
        step("read_set", read),
        step("after", f"{check} --sensors dvl,usbl --json"),
        step("restore", f"{check} --restore '{backup}' --json"),
        step("read_restored", read),
        step("restored", f"{check} --sensors dvl,usbl --json"),
    ]) + "\n")
    r = subprocess.run([str(RUN), "-d", str(tmp_path / "sitl"), "--", "bash", str(script)],
                       capture_output=True, text=True, timeout=150)
    assert r.returncode == 0, r.stderr

    def out(name):
        rc = int((tmp_path / f"{name}.rc").read_text())
        return rc, (tmp_path / f"{name}.out").read_text(), (tmp_path / f"{name}.err").read_text()

    rc, stdout, stderr = out("before")
    before = json.loads(stdout)
    print(stderr.strip())
    assert rc == 1, stderr
    assert before["failed"] == list(WANTED), before["failed"]
    for name in WANTED:
        assert name in stderr, stderr
    found = {c["name"]: c["found"] for c in before["checks"]}
    assert {n: found[n] for n in WANTED} == DEFAULTS
    # The firmware answers the ground-station id under its new name only, and is the one tried.
    assert "MAV_GCS_SYSID" in found and "SYSID_MYGCS" not in found and found["MAV_GCS_SYSID"] == 255
    assert before["firmware"]["version"] == "4.8.0-dev" and before["firmware"]["tried"], before["firmware"]
    assert "--sensors dvl,usbl --set" in before["set_command"]

    rc, stdout, stderr = out("no_declination")
    assert rc == 1 and "cannot set COMPASS_DEC" in stderr and "nothing was changed" in stderr, stderr
    assert not (tmp_path / "never.parm").exists()

    rc, stdout, stderr = out("set")
    print(stdout.strip())
    assert rc == 0, stderr
    saved = [line for line in backup.read_text().splitlines() if not line.startswith("#")]
    assert saved == [f"{n},{v:g}" for n, v in DEFAULTS.items()], saved
    for name, value in WANTED.items():
        assert f"set {name} {DEFAULTS[name]:g} -> {value:g} (confirmed)" in stdout, stdout
    assert "reboot the autopilot" in stdout

    assert json.loads(out("read_set")[1]) == WANTED
    rc, stdout, stderr = out("after")
    assert rc == 0 and json.loads(stdout)["passed"], stdout + stderr

    rc, stdout, stderr = out("restore")
    assert rc == 0, stderr
    restored = json.loads(stdout)["restored"]
    assert [(x["name"], x["to"], x["changed"]) for x in restored] == [(n, v, True) for n, v in DEFAULTS.items()]
    assert json.loads(out("read_restored")[1]) == DEFAULTS
    rc, stdout, stderr = out("restored")
    again = json.loads(stdout)
    assert rc == 1 and again["failed"] == list(WANTED), stderr
    assert {c["name"]: c["found"] for c in again["checks"] if c["name"] in WANTED} == DEFAULTS
