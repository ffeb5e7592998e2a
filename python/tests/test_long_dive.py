"""A whole dive on pilot assist through `pinc serve` on the firmware (long_dive_driver.py flies
it in Chromium with a scripted gamepad, one page reload, one autopilot reboot): the memory of
the server and of the flight flat once their kept history is full, no deadline missed, the data
folder's size under the limit the page shows.

CI flies 5 minutes with 60 s of history (flat from 2 minutes on). The hour, measured once and
written up in docs/PILOT.md, is the same test with `PINC_LONG_DIVE_MINUTES=60` (the default 300 s
of history, flat from 5 minutes on).

Needs $PINC_ARDUSUB_SITL, chromium and chromium-driver, selenium (the test extra), and
target/release/pinc and mpc_track with `train` and `vehicle`.
"""

import json
import os
import sys
from pathlib import Path

import pytest

from test_ardusub_fit import pinc_fit
from test_ardusub_sitl import NO_POSITION, run_on_firmware
from test_vehicle_link import pinc_binary

HERE = Path(__file__).resolve().parent
DRIVER = HERE / "long_dive_driver.py"
STOCK_RECORDING = HERE.parents[1] / "tests" / "fixtures" / "ardusub" / "stock_designed_60s.mcap"
MINUTES = float(os.environ.get("PINC_LONG_DIVE_MINUTES", "5"))
LONG = MINUTES >= 20
HISTORY_S = 300.0 if LONG else 60.0
# Memory is judged from here on (s into the flight): the kept history full, and a tenth more.
SETTLED_S = 300.0 if LONG else 120.0

for needed in ("/usr/bin/chromium", "/usr/bin/chromedriver"):
    if not Path(needed).exists():
        pytest.skip(f"{needed} is missing: apt install chromium chromium-driver", allow_module_level=True)
pytest.importorskip("selenium", reason="selenium is in the Python package's test extra")


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("long_dive")
    pinc_fit(STOCK_RECORDING, tmp / "fitted", epochs=5)
    out = tmp / "result.json"
    client = [sys.executable, DRIVER, "--pinc", pinc_binary(), "--model", tmp / "fitted", "--data", tmp / "data",
              "--out", out, "--minutes", MINUTES, "--history", HISTORY_S]
    r = run_on_firmware(tmp, [NO_POSITION], client, timeout=MINUTES * 60 + 600)
    serve_log = out.with_suffix(".serve.log")
    print(serve_log.read_text()[-4000:] if serve_log.exists() else "(no server log)")
    assert r.returncode == 0, f"the dive failed: {r.stderr[-4000:]}"
    result = json.loads(out.read_text())
    print(json.dumps(result, indent=1))
    return result


def flat(values):
    """The largest over the first: how much the memory grew after it settled."""
    values = [v for v in values if v is not None]
    assert len(values) >= 3, values
    return max(values) / values[0]


def test_the_memory_is_flat_once_the_history_is_full(dive):
    settled = [m for m in dive["memory"] if m["flight_t_s"] >= SETTLED_S]
    serve = flat([m["serve_mb"] for m in dive["memory"] if m["t_s"] >= SETTLED_S])
    first = flat([m["mpc_track_mb"] for m in settled if m["flight"] == 1])
    print(f"resident memory after {SETTLED_S:.0f} s: pinc serve x{serve:.3f}, the flight x{first:.3f}")
    assert serve <= 1.10 and first <= 1.10, (serve, first)
    if LONG:
        second = flat([m["mpc_track_mb"] for m in settled if m["flight"] == 2])
        assert second <= 1.10, second


def test_no_deadline_missed_and_every_cycle_streamed(dive):
    first, second = dive["flights"]
    assert first["ended_by"] == "the autopilot rebooted" and second["ended_by"] == "resume", dive["flights"]
    for f in dive["flights"]:
        forgotten = (f["history"] or {}).get("deadline_misses_forgotten", 0)
        assert f["deadline_misses"] == 0 and forgotten == 0, f
        # What the figures hold: the kept history (12.5 cycles a second), the rest counted.
        assert f["cycles_in_figures"] <= HISTORY_S * 1.1 / 0.08 + 1, f
    assert second["state"] == "finished" and second["stopped"] is None, second
    # The second flight flew what was left of the dive (after the reboot and the link's return).
    assert second["cycles_streamed"] >= 0.2 * MINUTES * 60 / 0.08, second


def test_the_page_came_back_and_the_link_after_the_reboot(dive):
    events = {e["what"]: e for e in dive["events"]}
    assert events["page reloaded"]["job_state"] == "running", events
    assert events["autopilot rebooted"]["link_back_after_s"] < 90, events
    assert "second flight" in events


def test_the_data_folder_stays_under_the_limit_the_page_shows(dive):
    last = dive["memory"][-1]
    assert last["data_mb"] < last["max_data_mb"], last
    assert f"of {last['max_data_mb']:.0f} MB" in last["page_data"], last
    grew = last["data_mb"] - dive["memory"][0]["data_mb"]
    print(f"the data folder grew {grew:.1f} MB in {MINUTES:g} minutes ({grew / MINUTES:.2f} MB a minute)")
    assert grew > 0, dive["memory"]
