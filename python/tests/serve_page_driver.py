"""Drives `pinc serve`'s page in a real browser (Debian's chromium, headless, through
chromedriver and selenium) against ArduSub's simulator, as an owner would: the status, an
excitation until the watch stops it, a fit, a 30 s flight, STOP during a second flight, and a
flight on a gamepad (injected through the Gamepad API) ended by closing the page, and one on
Cockpit's joystick. Meant
to run inside run_in_netns.sh's namespace (everything on its loopback):

- an independent observer (pymavlink) is the firmware's first client (on 5760: it starts the
  simulation) and notes, on this machine's clock, every heartbeat's armed flag (asked at 10 Hz)
  and the thruster outputs;
- `pinc serve` keeps its own link on 5762, its runs connect on 5763;
- a flight on Cockpit's joystick reads it from a mavlink2rest stand-in (mavlink2rest_stand_in.py);
- then the autopilot reboots (the server's link comes back), and the server is killed mid-excitation
  (the autopilot's failsafe takes over, the recording stays `.partial`; a new server fits it);
- each step leaves a screenshot; the page's figures and the observer's times go to --out (JSON).

usage: serve_page_driver.py --pinc BIN --vehicle V.toml --data DIR --shots DIR --out FILE [--run-arg ARG]...
"""

import argparse
import json
import subprocess
import threading
import time
from pathlib import Path

from mavlink2rest_stand_in import Mavlink2Rest
from pymavlink import mavutil
from selenium import webdriver
from selenium.webdriver.chrome.options import Options
from selenium.webdriver.chrome.service import Service
from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select

PORT = 8780
HEARTBEAT, SERVO_OUTPUT_RAW = 0, 36


class Observer:
    """The firmware as a bystander sees it: (monotonic time, armed) per heartbeat, and the
    thruster outputs (monotonic time, servo1..6)."""

    def __init__(self):
        self.m = self.connect()
        self.heartbeats, self.outputs, self.mode = [], [], None
        self.lock = threading.Lock()
        threading.Thread(target=self.read, daemon=True).start()

    @staticmethod
    def connect():
        for _ in range(150):
            try:
                return mavutil.mavlink_connection("tcp:127.0.0.1:5760", source_system=255, source_component=190,
                                                  retries=0)
            except OSError:
                time.sleep(0.2)
        raise AssertionError("the simulator's 5760 did not open")

    def reboot(self, armed=False):
        """Reboots the autopilot (the simulator starts itself again) and connects to it again:
        the simulation waits for a client on 5760. ArduPilot refuses a reboot while armed
        (COMMAND_ACK FAILED, measured) unless its sixth parameter is 20190226: `armed` sends it."""
        force = 20190226 if armed else 0
        self.m.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 0, 1, 0, 0, 0, 0, force,
                                     0)
        time.sleep(1.0)
        self.m = self.connect()
        self.ask_rates()

    def ask_rates(self):
        for msg_id, hz in ((HEARTBEAT, 10), (SERVO_OUTPUT_RAW, 25)):
            self.m.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id,
                                         1e6 / hz, 0, 0, 0, 0, 0)

    def read(self):
        while True:
            try:
                msg = self.m.recv_match(blocking=True, timeout=1)
            except OSError:
                time.sleep(0.1)
                continue
            if msg is None:
                continue
            now = time.monotonic()
            kind = msg.get_type()
            with self.lock:
                if kind == "HEARTBEAT" and msg.get_srcSystem() == 1 and msg.get_srcComponent() == 1:
                    armed = bool(msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                    self.heartbeats.append((now, armed))
                    self.mode = msg.custom_mode
                elif kind == "SERVO_OUTPUT_RAW":
                    self.outputs.append((now, [getattr(msg, f"servo{i}_raw") for i in range(1, 7)]))

    def armed(self):
        with self.lock:
            return bool(self.heartbeats) and self.heartbeats[-1][1]

    def disarmed_after(self, t):
        with self.lock:
            return next((h[0] - t for h in self.heartbeats if h[0] >= t and not h[1]), None)

    def outputs_after(self, t, span=1.0):
        with self.lock:
            return [(round(o[0] - t, 3), o[1]) for o in self.outputs if t - 0.2 <= o[0] <= t + span]


# A gamepad as the Gamepad API gives one (standard mapping), its axes set by the test.
INJECTED_GAMEPAD = """
window.__pad = {id: "pinc test pad", index: 0, connected: true, mapping: "standard", axes: [0, 0, 0, 0],
                buttons: [], timestamp: 0};
navigator.getGamepads = () => [window.__pad.connected ? window.__pad : null];
"""


def wait(what, ok, timeout, every=0.2):
    until = time.monotonic() + timeout
    while time.monotonic() < until:
        # The page rebuilds its lists as the server's state arrives: an element read while it is
        # replaced is stale, which is "not yet", not a failure; so is one not there yet, on a page
        # still loading (a reload under load: an hour's dive stopped on it at 18 minutes).
        try:
            v = ok()
        except (StaleElementReferenceException, NoSuchElementException):
            v = None
        if v:
            return v
        time.sleep(every)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--pinc", required=True)
    p.add_argument("--vehicle", required=True)
    p.add_argument("--data", required=True)
    p.add_argument("--shots", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--run-arg", action="append", default=[])
    a = p.parse_args()
    shots = Path(a.shots)
    shots.mkdir(parents=True, exist_ok=True)
    result = {"steps": []}

    observer = Observer()
    rest = Mavlink2Rest(6040)
    serve_log = open(Path(a.out).with_suffix(".serve.log"), "w")

    def start_serve():
        return subprocess.Popen([a.pinc, "serve", "--connect", "tcp:127.0.0.1:5762", "--flight-connect",
                                 "tcp:127.0.0.1:5763", "--data", a.data, "--port", str(PORT), "--vehicle", a.vehicle,
                                 *[f"--run-arg={x}" for x in a.run_arg]],
                                stdout=serve_log, stderr=subprocess.STDOUT)

    serve = start_serve()
    options = Options()
    options.binary_location = "/usr/bin/chromium"
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1400,2000"):
        options.add_argument(flag)
    browser = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    text = lambda id_: browser.find_element(By.ID, id_).text  # noqa: E731

    def shot(name):
        browser.save_screenshot(str(shots / f"{len(result['steps']) + 1:02d}_{name}.png"))
        result["steps"].append(name)

    def field(id_, value):
        e = browser.find_element(By.ID, id_)
        e.clear()
        e.send_keys(str(value))

    def click(id_):
        browser.find_element(By.ID, id_).click()

    def options(id_):
        return [o.text for o in Select(browser.find_element(By.ID, id_)).options]

    def choose(id_, name):
        # The list may be rebuilt between finding the option and picking it: picked is when the
        # select says so.
        def picked():
            Select(browser.find_element(By.ID, id_)).select_by_visible_text(name)
            return browser.find_element(By.ID, id_).get_attribute("value") == name
        wait(f"{name} picked in {id_}", picked, 10)

    def job_done(timeout):
        wait("the job's end", lambda: text("job-state") in ("finished", "failed", "stopped"), timeout)
        return text("job-state")

    try:
        wait("pinc serve", lambda: serve.poll() is None and _answers(), 30)
        browser.get(f"http://127.0.0.1:{PORT}/")
        observer.ask_rates()
        # 1. Status: the link, the mode and a depth, as the observer sees the firmware.
        wait("the vehicle on the page", lambda: text("link-state").startswith("connected") and text("v-depth") != "-", 60)
        result["status"] = {k: text(k) for k in ("link-state", "v-mode", "v-armed", "v-depth", "v-heading", "v-position",
                                                  "v-ekf")}
        result["observer_mode"] = observer.mode
        shot("status")

        # 2. The excitation, until the watch's stop.
        field("ex-top", 0.5)
        field("ex-bottom", 2.5)
        field("ex-duration", 150)
        click("ex-start")
        wait("the excitation to start", lambda: text("job-kind") == "excite", 10)
        wait("armed by the excitation", observer.armed, 60)
        result["excite_state"] = job_done(240)
        result["excite"] = {"verdict": text("job-verdict"), "recording": _maybe(browser, "excite-recording"),
                            "elapsed": text("job-elapsed")}
        shot("excited")

        # 3. The fit of that recording (few epochs: the test's time).
        wait("the recording in the list", lambda: result["excite"]["recording"] in options("fit-recording"), 10)
        choose("fit-recording", result["excite"]["recording"])
        field("fit-epochs", 5)
        click("fit-start")
        wait("the fit to start", lambda: text("job-kind") == "fit", 10)
        result["fit_state"] = job_done(600)
        result["fit"] = {"passed": _maybe(browser, "fit-passed"), "model": _maybe(browser, "fit-model"),
                         "warnings": _maybe(browser, "fit-warnings")}
        wait("the report's plot", lambda: browser.execute_script(
            "const i = document.getElementById('fit-report-img'); return i && i.complete && i.naturalWidth > 0;"), 20)
        shot("fitted")

        # 4. A 30 s flight of depth and heading steps on the fitted model.
        model = result["fit"]["model"]
        wait("the model in the list", lambda: model in options("fly-model"), 10)
        choose("fly-model", model)
        for k, v in (("fly-d0", 1.0), ("fly-d1", 1.5), ("fly-dat", 10), ("fly-h0", 0), ("fly-h1", 45), ("fly-hat", 15),
                     ("fly-duration", 30)):
            field(k, v)
        click("fly-start")
        wait("the flight to start", lambda: text("job-kind") == "fly", 10)
        wait("live samples", lambda: int(text("job-samples")) >= 100, 90)
        shot("flying")
        # A reload mid-flight: the flight goes on, the page gets its whole history again; a
        # second tab sees the same job.
        before = int(text("job-samples"))
        browser.refresh()
        wait("the page after a reload", lambda: text("job-state") == "running" and int(text("job-samples")) > before, 10)
        first = browser.current_window_handle
        browser.switch_to.new_window("tab")
        browser.get(f"http://127.0.0.1:{PORT}/")
        wait("the second tab", lambda: text("job-state") == "running", 10)
        result["second_tab"] = {"job-what": text("job-what"), "job-samples": int(text("job-samples"))}
        browser.close()
        browser.switch_to.window(first)
        result["flight_state"] = job_done(120)
        result["flight"] = {k: _maybe(browser, k) for k in ("fig-samples", "fig-rms-depth", "fig-rms-heading",
                                                            "fig-stopped", "job-samples", "job-what")}
        shot("flown")

        # 5. STOP during a second flight: neutral and disarmed, as the observer sees it.
        field("fly-duration", 60)
        click("fly-start")
        wait("the second flight", lambda: text("job-kind") == "fly" and text("job-state") == "running", 10)
        wait("armed, and control running", lambda: observer.armed() and int(text("job-samples")) >= 25, 90, every=0.05)
        clicked = time.monotonic()
        click("stop")
        wait("disarmed", lambda: observer.disarmed_after(clicked) is not None, 5, every=0.02)
        time.sleep(1.0)
        result["stop"] = {"disarmed_after_s": observer.disarmed_after(clicked),
                          "outputs": observer.outputs_after(clicked)}
        result["stop_state"] = job_done(15)
        wait("the page's STOP line", lambda: "disarmed seen after" in text("stop-result")
             and not text("stop-result").endswith("after -"), 5)
        result["stop"]["page"] = text("stop-result")
        result["stop"]["job_log_tail"] = text("job-log").splitlines()[-4:]
        shot("stopped")

        # 6. Reloading the page keeps the job, the data folder lists everything.
        browser.refresh()
        wait("the page after a reload", lambda: text("job-state") == "stopped", 10)
        result["files"] = [(r.get_attribute("data-kind"), r.get_attribute("data-name"))
                           for r in browser.find_elements(By.CSS_SELECTOR, "#files tr")]
        shot("reloaded")

        # 6b. A flight on the gamepad, injected through the Gamepad API as a browser sees one:
        # the heave stick held down takes the vehicle down, centred it holds, unplugged mid-stick
        # it holds, and the page closed stops the flight (neutral and disarm) 3 s later.
        browser.execute_script(INJECTED_GAMEPAD)
        Select(browser.find_element(By.ID, "fly-kind")).select_by_value("pilot")
        field("fly-pw", 0.3)
        field("fly-duration", 120)
        click("fly-start")
        wait("the gamepad's flight", lambda: text("job-kind") == "fly" and text("job-state") == "running"
             or (text("job-state") == "failed" and (_ for _ in ()).throw(AssertionError(text("job-log")))), 10)
        wait("armed, and control running", lambda: observer.armed() and len(state()["job"]["samples"]) >= 25, 90)
        wait("the page's gamepad", lambda: text("pad-state") == "pinc test pad", 5)

        def last_sample():
            s = state()["job"]["samples"][-1]
            return {"t": s["t"], "depth_m": s["depth_m"], "depth_ref_m": s["depth_ref_m"]}

        def sticks(axes):
            browser.execute_script(f"window.__pad.axes = {json.dumps(axes)};")

        pilot = {"start": last_sample()}
        sticks([0, 0.5, 0, 0])  # left stick down: heave down at half of 0.3 m/s
        time.sleep(5.0)
        pilot["held_5_s"] = last_sample()
        sticks([0, 0, 0, 0])
        time.sleep(4.0)
        pilot["centred_4_s"] = last_sample()
        time.sleep(2.0)
        pilot["centred_6_s"] = last_sample()
        sticks([0, 0.5, 0, 0])
        time.sleep(2.0)
        browser.execute_script("window.__pad.connected = false;")
        time.sleep(1.5)
        pilot["unplugged_1_5_s"] = last_sample()
        time.sleep(2.0)
        pilot["unplugged_3_5_s"] = last_sample()
        shot("gamepad")
        closed = time.monotonic()
        browser.get("about:blank")
        wait("disarmed after the page closed", lambda: observer.disarmed_after(closed) is not None, 20, every=0.05)
        pilot["disarmed_after_close_s"] = observer.disarmed_after(closed)
        browser.get(f"http://127.0.0.1:{PORT}/")
        pilot["state"] = job_done(15)
        pilot["log_tail"] = [line for line in text("job-log").splitlines() if "sticks" in line][-6:]
        result["pilot"] = pilot

        # 6c. A flight on Cockpit's joystick, read where BlueOS keeps it (a mavlink2rest stand-in
        # on 6040, pinc serve's default --joystick): the heave stick held down takes the vehicle
        # down; pinc takes Cockpit's place as the autopilot's ground station and gives it back.
        joystick = {"z": 500}
        stop_joystick = threading.Event()

        def cockpit():
            while not stop_joystick.is_set():
                rest.keep(1, 0, 0, joystick["z"], 0)
                time.sleep(0.04)

        threading.Thread(target=cockpit, daemon=True).start()
        Select(browser.find_element(By.ID, "fly-kind")).select_by_value("joystick")
        field("fly-pw", 0.3)
        field("fly-duration", 20)
        click("fly-start")
        wait("armed, and control running on the joystick", lambda: observer.armed()
             and text("job-kind") == "fly" and len(state()["job"]["samples"]) >= 25
             or (text("job-state") == "failed" and (_ for _ in ()).throw(AssertionError(text("job-log")))), 90)
        # Up first (half the stick, 0.15 m/s, 4 s): the dive below starts well above the 3 m
        # limit whatever depth the gamepad's flight left the vehicle at (2.0 m once: the dive and
        # its stop reached 3 m, a safety stop).
        joystick["z"] = 750
        time.sleep(4.0)
        joystick["z"] = 500
        time.sleep(1.0)
        cockpit_flight = {"start": last_sample()}
        joystick["z"] = 250  # half the heave stick down: 0.15 m/s
        time.sleep(5.0)
        cockpit_flight["held_5_s"] = last_sample()
        joystick["z"] = 500
        shot("cockpit_joystick")
        # A joystick flight runs until STOP or resume: resume hands the vehicle back.
        time.sleep(1.0)
        click("resume")
        cockpit_flight["state"] = job_done(40)
        wait("the resume's answer", lambda: text("message").startswith("handed back"), 10)
        cockpit_flight["resume"] = text("message")
        cockpit_flight["log_tail"] = [line for line in text("job-log").splitlines() if "MAV_GCS_SYSID" in line]
        stop_joystick.set()
        result["cockpit_joystick"] = cockpit_flight

        # 7. The autopilot reboots: the server's link comes back by itself.
        links = state()["vehicle"]["links_opened"]
        observer.reboot()
        wait("the link again", lambda: state()["vehicle"]["connected"] and state()["vehicle"]["links_opened"] > links, 60)
        wait("the page's link", lambda: text("link-state").startswith("connected"), 10)
        result["reboot"] = {"links_opened": state()["vehicle"]["links_opened"], "page": text("link-state")}
        shot("rebooted")

        # 8. The server killed mid-excitation: the run dies with it, the autopilot's pilot-input
        # failsafe takes the thrusters to neutral, the recording stays as .partial; a new server
        # lists it and fits it.
        field("ex-duration", 90)
        click("ex-keep-going")
        click("ex-start")
        wait("the excitation", lambda: text("job-kind") == "excite" and text("job-state") == "running", 10)
        wait("armed", observer.armed, 60)
        # Long enough for the fit (at least 208 sample periods of excitation after arming).
        wait("50 s of excitation", lambda: float(text("job-elapsed").strip("( s)")) >= 50, 90, every=0.5)
        killed = time.monotonic()
        serve.kill()
        serve.wait()
        time.sleep(6.0)
        # This server's children only (another test may run its own excitation meanwhile).
        running = subprocess.run(["pgrep", "-af", "vehicle excite"], capture_output=True, text=True).stdout
        left = [line.split()[0] for line in running.splitlines() if str(a.data) in line]
        result["killed"] = {"outputs": observer.outputs_after(killed, span=6.0), "children_left": left,
                            "armed_after_6_s": observer.armed()}
        serve = start_serve()
        wait("pinc serve again", _answers, 30)
        browser.get(f"http://127.0.0.1:{PORT}/")
        wait("the partial recording listed", lambda: any(
            "partial" in r.text for r in browser.find_elements(By.CSS_SELECTOR, "#files tr")), 20)
        partial = wait("the partial recording in the fit's list",
                       lambda: [o for o in options("fit-recording") if o.endswith(".partial")], 10)
        result["killed"]["partial"] = partial
        choose("fit-recording", partial[0])
        field("fit-epochs", 5)
        click("fit-start")
        wait("the fit to start", lambda: text("job-kind") == "fit", 10)
        result["partial_fit_state"] = job_done(300)
        result["partial_fit"] = {"passed": _maybe(browser, "fit-passed"), "error": _maybe(browser, "job-error")}
        shot("partial_fitted")
    finally:
        shut_down(browser, serve, result, a.out)


def shut_down(browser, serve, result, out):
    """The browser and the server stopped, and `result` written to `out` with the server's exit
    code (None: it was still running, as it should be)."""
    result["serve_exit"] = serve.poll()
    browser.quit()
    serve.terminate()
    serve.wait(10)
    Path(out).write_text(json.dumps(result, indent=1))


def state():
    import urllib.request
    with urllib.request.urlopen(f"http://127.0.0.1:{PORT}/api/state", timeout=2) as r:
        return json.loads(r.read())


def _answers():
    import urllib.request
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{PORT}/api/state", timeout=1) as r:
            return r.status == 200
    except OSError:
        return False


def _maybe(browser, id_):
    found = browser.find_elements(By.ID, id_)
    return found[0].text if found else None


if __name__ == "__main__":
    main()
