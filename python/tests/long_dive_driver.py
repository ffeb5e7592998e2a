"""A whole dive on pilot assist through `pinc serve`, as an owner flies it: the page open in
Chromium with a gamepad injected through the Gamepad API, the sticks scripted (a dive at the
start, then every minute down, a turn, back up, a turn back), one page reload mid-flight (the
browser's reconnect), one reboot of the autopilot (the flight stops; the link comes back; the
pilot flies again to the end). Every 10 s it notes the resident memory of `pinc serve` and of
the flight (`mpc_track`) from /proc, and the data folder's size as the page shows it; at the end
each flight's summary (cycles, deadline misses, cycle times). Meant to run inside
run_in_netns.sh's namespace (everything on its loopback); the observer is the firmware's first
client, as in serve_page_driver.py.

usage: long_dive_driver.py --pinc BIN --model DIR --data DIR --out FILE --minutes N [--history S]
"""

import argparse
import json
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path

from selenium import webdriver
from selenium.webdriver.chrome.options import Options
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select

from serve_page_driver import INJECTED_GAMEPAD, PORT, Observer, _answers, shut_down, wait

# Heave and yaw sticks over each minute (s from the minute's start, the axes' values; None:
# the heave stick half down or half up, towards DEPTH): 0.75 m of heave, a turn, 0.75 m, the
# turn back. Full heave is the page's 0.3 m/s, full yaw 20 deg/s.
MINUTE = [((15, 20), None), ((30, 35), [0.5, 0, 0, 0]), ((40, 45), None), ((50, 55), [-0.5, 0, 0, 0])]
# The first 10 s: down 1.5 m.
FIRST = ((0, 10), [0, 0.5, 0, 0])
DEPTH = 1.6


def sticks_at(t, depth):
    """The gamepad's axes `t` s into a flight, at `depth` (m) now."""
    if FIRST[0][0] <= t < FIRST[0][1]:
        return FIRST[1]
    if t < 60:
        return [0, 0, 0, 0]
    for (a, b), axes in MINUTE:
        if a <= t % 60 < b:
            return axes or [0, 0.5 if depth < DEPTH else -0.5, 0, 0]
    return [0, 0, 0, 0]


# What the page's sticks did, counted inside it: each request to api/sticks (sent, answered,
# failed and why, the slowest answer since the last look) and the page's own 50 ms timer (how
# often it fired), so a gap in the sticks says whether the timer, the requests or the server
# stalled. Injected before the page's script, beside the gamepad.
STICKS_PROBE = """
window.__probe = {sent: 0, answered: 0, failed: 0, errors: {}, slowest_ms: 0, ticks: 0};
setInterval(() => window.__probe.ticks++, 50);
const __fetch = window.fetch.bind(window);
window.fetch = async (url, options) => {
  if (!String(url).includes("api/sticks")) return __fetch(url, options);
  const p = window.__probe, t0 = performance.now();
  p.sent++;
  try { const r = await __fetch(url, options); p.answered++; return r; }
  catch (e) { p.failed++; p.errors[e.name] = (p.errors[e.name] || 0) + 1; throw e; }
  finally { p.slowest_ms = Math.max(p.slowest_ms, performance.now() - t0); }
};
"""
READ_PROBE = """
const p = window.__probe;
if (!p) return null;
const out = Object.assign({}, p, {errors: Object.assign({}, p.errors), takes_sticks: typeof takesSticks === "undefined" ? null : takesSticks,
                                  heap_mb: performance.memory ? performance.memory.usedJSHeapSize / 1048576 : null});
p.slowest_ms = 0;
return out;
"""


def state(since=10**9):
    """The server's state without the flight's cycles (unless asked from `since`)."""
    with urllib.request.urlopen(f"http://127.0.0.1:{PORT}/api/state?since={since}", timeout=5) as r:
        return json.loads(r.read())


def rss_mb(pid):
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def flight_pid(serve_pid):
    """The server's mpc_track child, if one runs."""
    out = subprocess.run(["pgrep", "-P", str(serve_pid), "mpc_track"], capture_output=True, text=True).stdout.split()
    return int(out[0]) if out else None


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--pinc", required=True)
    p.add_argument("--model", required=True, help="a folder with model.pinc (pinc fit's output)")
    p.add_argument("--data", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--minutes", type=float, required=True)
    p.add_argument("--history", type=float, default=300.0)
    a = p.parse_args()
    total = a.minutes * 60.0
    reload_at, reboot_at = 0.3 * total, 0.7 * total
    data = Path(a.data)
    shutil.copytree(a.model, data / "models" / "dive")
    result = {"minutes": a.minutes, "history_s": a.history, "memory": [], "flights": [], "events": []}

    observer = Observer()
    serve_log = open(Path(a.out).with_suffix(".serve.log"), "w")
    serve = subprocess.Popen([a.pinc, "serve", "--connect", "tcp:127.0.0.1:5762", "--flight-connect",
                              "tcp:127.0.0.1:5763", "--data", str(data), "--port", str(PORT),
                              "--max-duration", str(total + 60), "--history", str(a.history)],
                             stdout=serve_log, stderr=subprocess.STDOUT)
    options = Options()
    options.binary_location = "/usr/bin/chromium"
    # Twice, about 14 minutes after a page was opened, it sent no sticks for 10 s and the server
    # stopped the flight. With Chromium's timer throttling off (a pilot's page is in front) and the
    # page reading each sticks answer (giving a request up after 1 s), the hour ran with every
    # request answered; which of the two did it is not isolated.
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1400,2000",
                 "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                 "--disable-backgrounding-occluded-windows", "--disable-features=IntensiveWakeUpThrottling"):
        options.add_argument(flag)
    browser = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    # The gamepad stays plugged in across the reload, as a real one does: injected into every
    # page before its own script runs (centred until the script sets its axes again).
    browser.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": INJECTED_GAMEPAD + STICKS_PROBE})
    text = lambda id_: browser.find_element(By.ID, id_).text  # noqa: E731

    def open_page():
        browser.get(f"http://127.0.0.1:{PORT}/")
        wait("the vehicle on the page", lambda: text("link-state").startswith("connected"), 60)

    def fly(seconds):
        """Starts a pilot flight from the page; returns when control runs (the clock's zero)."""
        wait("the model in the list", lambda: "dive" in [o.text for o in Select(browser.find_element(
            By.ID, "fly-model")).options], 20)

        def choose():
            # The page rebuilds its lists when the data folder changes (the last flight's files
            # written): an element read while it is replaced is stale, and the choice is made again.
            Select(browser.find_element(By.ID, "fly-model")).select_by_visible_text("dive")
            Select(browser.find_element(By.ID, "fly-kind")).select_by_value("pilot")
            return True

        wait("the model and the pilot flight chosen", choose, 10)
        e = browser.find_element(By.ID, "fly-duration")
        e.clear()
        e.send_keys(str(int(seconds)))
        job_before = (state().get("job") or {}).get("id")
        browser.find_element(By.ID, "fly-start").click()
        wait("the flight's start", lambda: (state().get("job") or {}).get("id") != job_before, 10)
        try:
            wait("armed, and control running", lambda: observer.armed() and state()["job"]["samples_total"] >= 5, 90)
        except AssertionError as e:
            raise AssertionError(f"{e}; the flight said: {state()['job']['lines'][-10:]}") from e
        wait("the page's gamepad", lambda: text("pad-state") == "pinc test pad", 5)
        return time.monotonic()

    def finished_flight(reason):
        j = wait("the flight's end", lambda: (lambda job: job if job["state"] != "running" else None)(
            state()["job"]), 60)
        # A flight stopped early is a failed job: its summary is in its folder either way.
        written = data / "flights" / j["what"].split(" on ")[0] / "summary.json"
        summary = json.loads(written.read_text()) if written.is_file() else {}
        live = summary.get("live") or {}
        result["flights"].append({
            "ended_by": reason, "state": j["state"], "cycles_streamed": j["samples_total"],
            "cycles_in_figures": summary.get("samples"), "deadline_misses": summary.get("deadline_misses"),
            "history": live.get("history"), "cycle_ms_median": summary.get("cycle_ms_median"),
            "cycle_ms_p99": summary.get("cycle_ms_p99"), "solve_ms_max": summary.get("solve_ms_max"),
            "state_age_ms": live.get("state_age_ms"), "stopped": summary.get("stopped"),
            "error": j.get("error"), "log_tail": j["lines"][-5:]})

    try:
        wait("pinc serve", lambda: serve.poll() is None and _answers(), 30)
        observer.ask_rates()
        open_page()
        began = fly(total)
        flight_began, flight = began, 1
        reloaded = rebooted = False
        next_note = began
        depth, heave_phase = 0.0, None
        while time.monotonic() - began < total:
            now = time.monotonic()
            # The heave stick's way is chosen once per phase, from the depth when it starts.
            phase = int((now - flight_began) // 5)
            if phase != heave_phase:
                heave_phase = phase
                job = state()["job"]
                newest = state(since=max(job["samples_total"] - 1, 0))["job"]["samples"]
                depth = newest[-1]["depth_m"] if newest and newest[-1]["depth_m"] is not None else depth
            axes = sticks_at(now - flight_began, depth)
            browser.execute_script(f"if (window.__pad) window.__pad.axes = {json.dumps(axes)};")
            if not reloaded and now - began >= reload_at:
                # The browser reconnects: the flight goes on (the page is gone < 3 s, the flight
                # holds on its deadman meanwhile), the page takes the flight up again.
                t0 = time.monotonic()
                open_page()
                try:
                    wait("the page on the flight again", lambda: text("job-state") == "running", 10)
                except AssertionError as e:
                    raise AssertionError(f"{e}; the flight said: {state()['job']['lines'][-10:]}") from e
                result["events"].append({"t_s": t0 - began, "what": "page reloaded",
                                         "took_s": time.monotonic() - t0, "job_state": text("job-state")})
                reloaded = True
            if not rebooted and now - began >= reboot_at:
                links = state()["vehicle"]["links_opened"]
                t0 = time.monotonic()
                observer.reboot(armed=True)
                finished_flight("the autopilot rebooted")
                wait("the link again", lambda: state()["vehicle"]["connected"] and
                     state()["vehicle"]["links_opened"] > links, 90)
                result["events"].append({"t_s": t0 - began, "what": "autopilot rebooted",
                                         "link_back_after_s": time.monotonic() - t0})
                rebooted = True
                left = total - (time.monotonic() - began)
                flight_began, flight = fly(max(left, 30.0)), 2
                result["events"].append({"t_s": flight_began - began, "what": "second flight"})
            if now >= next_note:
                st = state()
                child = flight_pid(serve.pid)
                result["memory"].append({
                    "t_s": now - began, "flight": flight, "flight_t_s": now - flight_began,
                    "serve_mb": rss_mb(serve.pid), "mpc_track_mb": rss_mb(child) if child else None,
                    "data_mb": st["server"]["data_mb"], "max_data_mb": st["server"]["limits"]["max_data_mb"],
                    "page_data": text("s-data"), "page_cycles": int(text("job-samples")),
                    "page_sticks": browser.execute_script(READ_PROBE)})
                next_note += 10.0
                # Written as it goes: an hour's figures outlive a run cut short.
                Path(a.out).write_text(json.dumps(result, indent=1))
            time.sleep(0.25)
        # A pilot flight runs until STOP or resume: the dive's end is the page's resume (the
        # vehicle handed back), at the dive's length.
        browser.find_element(By.ID, "resume").click()
        finished_flight("resume")
        result["page_navigation"] = text("job-nav")
    finally:
        shut_down(browser, serve, result, a.out)


if __name__ == "__main__":
    main()
