"""`pinc serve`'s refusals, each before anything is sent: a command without the page's token,
a name that could leave the data folder, numbers past the vehicle's limits, a file that is not
there, a second job. And in a real browser (Debian's chromium, when installed): a refusal shown
on the page, and another site's page that cannot read pinc's page or command the vehicle.

No autopilot is needed: the server keeps trying its link while it answers.
"""

import http.server
import json
import re
import subprocess
import threading
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from test_vehicle_link import ROOT, pinc_binary

VEHICLE = ROOT / "tests" / "fixtures" / "ardusub" / "sitl_vectored.toml"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("serve_data")
    # Port 9 (discard): nothing answers there, as with an autopilot switched off.
    proc = subprocess.Popen([str(pinc_binary()), "serve", "--connect", "tcp:127.0.0.1:9", "--timeout", "1",
                             "--data", str(data), "--port", "0", "--vehicle", str(VEHICLE), "--max-depth", "3",
                             "--max-distance", "30"],
                            stderr=subprocess.PIPE, text=True)
    first = proc.stderr.readline()
    m = re.search(r"http://(127\.0\.0\.1:\d+)", first)
    assert m, first
    log = []
    threading.Thread(target=lambda: log.extend(proc.stderr), daemon=True).start()
    base = f"http://{m.group(1)}"
    page = urllib.request.urlopen(base + "/").read().decode()
    token = re.search(r'const TOKEN = "([0-9a-f]{32})"', page).group(1)
    yield base, token, data, log
    proc.terminate()
    proc.wait(10)


def call(base, path, body=None, token=None, method=None):
    headers = {"Content-Type": "application/json"}
    if token:
        headers["X-Pinc-Token"] = token
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base + path, data=data, headers=headers, method=method)
    try:
        with urllib.request.urlopen(req) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def test_commands_without_the_pages_token_are_refused(server):
    base, token, _, log = server
    for bad in (None, "0" * 32, token[:-1]):
        status, reply = call(base, "/api/stop", {}, token=bad)
        assert status == 403 and "token" in reply["error"], (bad, reply)
        status, reply = call(base, "/api/excite", {"depth_band": [0.5, 2], "axes": ["heave"], "duration": 60}, token=bad)
        assert status == 403
    assert any("refused POST /api/stop: missing or wrong token" in line for line in log), log
    # The token itself never leaves the page: not in the state a script can read.
    assert token not in json.dumps(call(base, "/api/state")[1])


@pytest.mark.parametrize("query", [
    "kind=recordings&name=..", "kind=recordings&name=../../etc/passwd", "kind=recordings&name=%2Fetc%2Fpasswd",
    "kind=models&name=m&file=..%2F..%2Fx", "kind=recordings&name=.hidden", "kind=..&name=x",
])
def test_names_that_could_leave_the_data_folder_are_refused(server, query):
    base, token, _, _ = server
    status, reply = call(base, "/api/download?" + query)
    assert status == 404 and ("refused" in reply["error"] or "unknown kind" in reply["error"]), reply


def test_deletes_and_fits_take_only_plain_names_that_exist(server):
    base, token, data, _ = server
    outside = data.parent / "outside.txt"
    outside.write_text("keep me")
    status, reply = call(base, "/api/delete", {"kind": "recordings", "name": "../outside.txt"}, token=token)
    assert status == 400 and "refused" in reply["error"] and outside.exists()
    status, reply = call(base, "/api/delete", {"kind": "recordings", "name": "none.mcap"}, token=token)
    assert status == 400 and reply["error"] == "recordings/none.mcap does not exist in the data folder"
    status, reply = call(base, "/api/fit", {"recording": "none.mcap"}, token=token)
    assert status == 400 and "does not exist" in reply["error"]
    status, reply = call(base, "/api/fly", {"model": "none", "duration": 30, "references": {"kind": "hold"}},
                         token=token)
    assert status == 400 and reply["error"] == "models/none/model.pinc does not exist in the data folder"
    (data / "recordings" / "kept.mcap").write_bytes(b"x")
    status, reply = call(base, "/api/delete", {"kind": "recordings", "name": "kept.mcap"}, token=token)
    assert status == 200 and not (data / "recordings" / "kept.mcap").exists()


@pytest.mark.parametrize("path,body,says", [
    ("/api/excite", {"depth_band": [0.5, 3.5], "axes": ["heave"], "duration": 60},
     "depth_band bottom 3.5 m is outside the vehicle's limits: 0 to 3 m"),
    ("/api/excite", {"depth_band": [0.5, 2], "axes": ["roll"], "duration": 60}, 'unknown axis "roll"'),
    ("/api/excite", {"depth_band": [0.5, 2], "axes": ["heave"], "duration": 6000}, "duration 6000 s"),
    ("/api/fly", {"model": "m", "duration": 30, "references": {"kind": "steps", "depth": [1, 9], "depth_at": 5,
                                                               "heading": [0, 0], "heading_at": 5}},
     "depth to 9 m is outside the vehicle's limits"),
    ("/api/fly", {"model": "m", "duration": 90, "references": {"kind": "survey", "width": 60, "length": 10,
                                                               "spacing": 2, "speed": 0.3, "depth": 2}},
     "past the vehicle's limit of 30 m"),
    ("/api/fly", {"model": "m", "duration": 30, "references": {"kind": "hold"}, "arm": False},
     "unknown field `arm`"),
    ("/api/fit", {"recording": "x.mcap", "epochs": 0}, "epochs 0 must be 1 to 2000"),
])
def test_numbers_past_the_vehicles_limits_are_refused_before_anything_is_sent(server, path, body, says):
    base, token, _, log = server
    status, reply = call(base, path, body, token=token)
    assert status == 400 and says in reply["error"], reply
    assert call(base, "/api/state")[1]["job"] is None, "nothing started"


# The browser part: Debian's chromium, when installed.
BROWSER = Path("/usr/bin/chromium").exists() and Path("/usr/bin/chromedriver").exists()


@pytest.fixture(scope="module")
def browser():
    if not BROWSER:
        pytest.skip("/usr/bin/chromium or /usr/bin/chromedriver is missing: apt install chromium chromium-driver")
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is in the Python package's test extra")
    from selenium.webdriver.chrome.service import Service
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"):
        options.add_argument(flag)
    b = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    yield b
    b.quit()


def wait_for(what, ok, browser, timeout=10):
    from selenium.webdriver.support.ui import WebDriverWait
    return WebDriverWait(browser, timeout).until(lambda _: ok(), message=what)


def test_a_refusal_is_shown_on_the_page(server, browser, tmp_path):
    from selenium.webdriver.common.by import By
    base, _, _, _ = server
    browser.get(base + "/")
    bottom = browser.find_element(By.ID, "ex-bottom")
    bottom.clear()
    bottom.send_keys("5")
    browser.find_element(By.ID, "ex-start").click()
    message = lambda: browser.find_element(By.ID, "message").text  # noqa: E731
    wait_for("the refusal", lambda: "outside the vehicle's limits" in message(), browser)
    assert message() == "depth_band bottom 5 m is outside the vehicle's limits: 0 to 3 m (the limits on the page)"
    assert browser.find_element(By.ID, "message").get_attribute("class") == "bad"
    browser.save_screenshot(str(tmp_path / "refusal.png"))


EVIL = """<!doctype html><html><body><script>
const out = {};
fetch("TARGET/").then(r => r.text()).then(t => out.read = t.slice(0, 40)).catch(e => out.read = "blocked: " + e)
  .then(() => fetch("TARGET/api/stop", {method: "POST", headers: {"X-Pinc-Token": "guess"}, body: "{}"}))
  .then(r => out.stop = r.status).catch(e => out.stop = "blocked: " + e)
  .then(() => fetch("TARGET/api/excite", {method: "POST", mode: "no-cors", body: "{}"}))
  .then(r => out.simple = r.type).catch(e => out.simple = "blocked: " + e)
  .then(() => { document.title = JSON.stringify(out); });
</script></body></html>"""


def test_another_sites_page_can_neither_read_the_token_nor_command(server, browser, tmp_path):
    base, _, _, log = server
    (tmp_path / "evil.html").write_text(EVIL.replace("TARGET", base))
    handler = lambda *a, **k: http.server.SimpleHTTPRequestHandler(*a, directory=str(tmp_path), **k)  # noqa: E731
    site = http.server.ThreadingHTTPServer(("127.0.0.2", 0), handler)
    threading.Thread(target=site.serve_forever, daemon=True).start()
    try:
        browser.get(f"http://127.0.0.2:{site.server_address[1]}/evil.html")
        wait_for("the other site's script", lambda: browser.title.startswith("{"), browser)
        out = json.loads(browser.title)
    finally:
        site.shutdown()
    print(out)
    # Reading pinc's page (and so its token) across origins: blocked by the browser.
    assert str(out["read"]).startswith("blocked"), out
    # A header-carrying POST needs a CORS preflight the server never grants: never sent.
    assert str(out["stop"]).startswith("blocked"), out
    # A "simple" POST is sent, but carries no token: refused by the server.
    assert out["simple"] == "opaque"
    assert any("refused POST /api/excite: missing or wrong token" in line for line in log), log
    assert not any("STOP (neutral" in line for line in log), log


# Cockpit's extras, as its own source types them (bluerobotics/cockpit, src/libs/blueos/schemas.ts
# and src/types: checked there with zod, where one wrong field drops the extension's whole file).
HTTP_METHODS = {"GET", "POST", "PUT", "DELETE", "PATCH"}
ACTION_TYPES = {"http-request", "mavlink-message", "javascript"}
MODIFIER_KEYS = {"regular", "shift"}


def check_cockpit_extras(x):
    """Every field Cockpit's types require, of the type they require; what is wrong, by path."""
    def has(obj, where, field, kind, optional=False):
        if field not in obj:
            assert optional, f"{where}.{field} is missing"
            return None
        assert isinstance(obj[field], kind) and not (kind is int and isinstance(obj[field], bool)), \
            f"{where}.{field} is {obj[field]!r}, not {kind}"
        return obj[field]

    has(x, "extras", "targetCockpitApiVersion", str)
    has(x, "extras", "targetSystem", str)
    for i, w in enumerate(has(x, "extras", "widgets", list, optional=True) or []):
        where = f"widgets[{i}]"
        has(w, where, "name", str)
        has(w, where, "iframeUrl", str)
        assert "iconUrl" in w or "iframeIcon" in w, f"{where}: either iconUrl or iframeIcon"
        for f, kind in (("iconUrl", str), ("iframeIcon", str), ("collapsibleContainerName", str), ("version", str),
                        ("startCollapsed", bool), ("useExtensionPathAsBaseUrl", bool),
                        ("contentZoom", (int, float)), ("scaleContentWithWidget", bool)):
            has(w, where, f, kind, optional=True)
    ids = set()
    for i, a in enumerate(has(x, "extras", "actions", list, optional=True) or []):
        where = f"actions[{i}]"
        ids.add(has(a, where, "id", str))
        has(a, where, "name", str)
        assert has(a, where, "type", str) in ACTION_TYPES, f"{where}.type"
        has(a, where, "version", str, optional=True)
        c = has(a, where, "config", dict)
        has(c, where + ".config", "name", str)
        assert has(c, where + ".config", "method", str) in HTTP_METHODS, f"{where}.config.method"
        has(c, where + ".config", "url", str)
        has(c, where + ".config", "body", str)
        for f in ("headers", "urlParams"):
            d = has(c, where + ".config", f, dict, optional=f == "urlParams") or {}
            assert all(isinstance(k, str) and isinstance(v, str) for k, v in d.items()), f"{where}.config.{f}"
    for i, g in enumerate(has(x, "extras", "joystickSuggestions", list, optional=True) or []):
        where = f"joystickSuggestions[{i}]"
        has(g, where, "id", str)
        has(g, where, "name", str)
        has(g, where, "description", str, optional=True)
        assert all(isinstance(t, str) for t in has(g, where, "targetVehicleTypes", list, optional=True) or [])
        for j, s in enumerate(has(g, where, "buttonMappingSuggestions", list)):
            w = f"{where}.buttonMappingSuggestions[{j}]"
            for f in ("id", "actionProtocol", "actionName", "actionId"):
                has(s, w, f, str)
            has(s, w, "button", int)
            assert has(s, w, "modifierKey", str) in MODIFIER_KEYS, f"{w}.modifierKey"
            assert s["actionProtocol"] != "cockpit-action" or s["actionId"] in ids, f"{w}: no action {s['actionId']}"


def test_cockpit_finds_the_page_as_a_widget_and_hold_and_stop_as_actions(server, tmp_path):
    base, token, data, log = server
    registered = json.loads(urllib.request.urlopen(base + "/register_service").read())
    assert registered["works_in_relative_paths"] is True
    path = registered["extras"]["cockpit"]
    assert path.startswith("/"), "Cockpit appends it to the extension's address"
    extras = json.loads(urllib.request.urlopen(base + path).read())
    check_cockpit_extras(extras)
    # The checker itself refuses what Cockpit refuses (its docs' own `modifier` spelling, a
    # lower-case method, a widget without an icon).
    for broken in ("modifier", "post", "no icon"):
        bad = json.loads(json.dumps(extras))
        if broken == "modifier":
            s = bad["joystickSuggestions"][0]["buttonMappingSuggestions"][0]
            s["modifier"] = s.pop("modifierKey")
        elif broken == "post":
            bad["actions"][0]["config"]["method"] = "post"
        else:
            del bad["widgets"][0]["iconUrl"]
        with pytest.raises(AssertionError):
            check_cockpit_extras(bad)
    widget = extras["widgets"][0]
    assert widget["iframeUrl"] == "/" and urllib.request.urlopen(base + widget["iconUrl"]).status == 200
    # Each action as Cockpit sends it: its URL under BlueOS's extension path, its headers
    # (the page's token) and body.
    actions = {a["id"]: a["config"] for a in extras["actions"]}
    for c in actions.values():
        assert c["url"].startswith("http://{{ vehicle-address }}/extensionv2/pinc/api/"), c["url"]
        assert c["headers"]["X-Pinc-Token"] == token
    def send(c):
        local = base + c["url"].split("/extensionv2/pinc", 1)[1]
        req = urllib.request.Request(local, data=c["body"].encode(), headers=c["headers"], method=c["method"])
        try:
            with urllib.request.urlopen(req) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read())
    assert send(actions["pinc-hold-here"]) == (409, {"error": "no fitted model to hold with: excite and fit first"})
    assert send(actions["pinc-resume"]) == (
        409, {"error": "nothing to resume from: no hold or pilot flight is running"})
    status, reply = send(actions["pinc-stop"])
    assert status == 200 and reply["stopped"] is True, reply
    # The token outlives a restart (Cockpit keeps the headers it copied): the data folder's.
    proc = subprocess.Popen([str(pinc_binary()), "serve", "--connect", "tcp:127.0.0.1:9", "--timeout", "1",
                             "--data", str(data), "--port", "0", "--vehicle", str(VEHICLE)],
                            stderr=subprocess.PIPE, text=True)
    try:
        again = "http://" + re.search(r"http://(127\.0\.0\.1:\d+)", proc.stderr.readline()).group(1)
        assert json.loads(urllib.request.urlopen(again + path).read())["actions"][0]["config"]["headers"] == \
            extras["actions"][0]["config"]["headers"]
    finally:
        proc.terminate()
        proc.wait(10)
    assert (data / ".token").stat().st_mode & 0o077 == 0, "the token file is the owner's alone"


def test_the_page_works_inside_cockpits_iframe(server, browser, tmp_path):
    # Cockpit shows an extension's widget as an iframe of its page; here the frame sits on
    # another origin's page, the strictest case (from BlueOS's menu they share one).
    from selenium.webdriver.common.by import By
    base, _, _, log = server
    (tmp_path / "cockpit.html").write_text(
        f'<!doctype html><html><body><iframe id="pinc" src="{base}/" width="1200" height="900"></iframe></body></html>')
    handler = lambda *a, **k: http.server.SimpleHTTPRequestHandler(*a, directory=str(tmp_path), **k)  # noqa: E731
    site = http.server.ThreadingHTTPServer(("127.0.0.2", 0), handler)
    threading.Thread(target=site.serve_forever, daemon=True).start()
    try:
        browser.get(f"http://127.0.0.2:{site.server_address[1]}/cockpit.html")
        browser.switch_to.frame(browser.find_element(By.ID, "pinc"))
        wait_for("the page's status in the frame", lambda: browser.find_element(By.ID, "link-state").text != "", browser)
        browser.find_element(By.ID, "stop").click()
        message = lambda: browser.find_element(By.ID, "message").text  # noqa: E731
        wait_for("STOP from inside the frame", lambda: message().startswith("STOP sent"), browser)
        browser.save_screenshot(str(tmp_path / "in_cockpit.png"))
    finally:
        browser.switch_to.default_content()
        site.shutdown()
    assert any("STOP (neutral" in line for line in log), log


def test_a_run_the_data_folder_has_no_room_for_is_refused_before_it_starts(tmp_path):
    # A 10 MB limit with 8 MB held: a 30 s flight (about 6 MB) is refused, and the page's state
    # says what the folder holds.
    data = tmp_path / "data"
    (data / "recordings").mkdir(parents=True)
    (data / "recordings" / "old.mcap").write_bytes(b"\0" * 8_000_000)
    proc = subprocess.Popen([str(pinc_binary()), "serve", "--connect", "tcp:127.0.0.1:9", "--timeout", "1",
                             "--data", str(data), "--port", "0", "--vehicle", str(VEHICLE), "--max-data-mb", "10"],
                            stderr=subprocess.PIPE, text=True)
    try:
        base = "http://" + re.search(r"http://(127\.0\.0\.1:\d+)", proc.stderr.readline()).group(1)
        token = re.search(r'const TOKEN = "([0-9a-f]{32})"', urllib.request.urlopen(base + "/").read().decode()).group(1)
        (data / "models" / "m").mkdir(parents=True)
        (data / "models" / "m" / "model.pinc").write_bytes(b"x")
        steps = {"kind": "steps", "depth": [1, 1], "depth_at": 5, "heading": [0, 0], "heading_at": 5}
        status, reply = call(base, "/api/fly", {"model": "m", "duration": 30, "references": steps}, token=token)
        assert status == 507 and reply["error"].startswith(
            "refused: the data folder holds 8 MB of its 10 MB (pinc serve --max-data-mb) and a 30 s run needs about 6 MB"), reply
        state = call(base, "/api/state")[1]
        assert state["job"] is None and state["server"]["limits"]["max_data_mb"] == 10
        assert abs(state["server"]["data_mb"] - 8.0) < 0.1 and state["server"]["disk_free_mb"] > 0, state["server"]
    finally:
        proc.terminate()
        proc.wait(10)


def test_the_owners_limits_are_set_on_the_page_kept_in_the_data_folder_and_outlive_a_restart(tmp_path):
    def start():
        proc = subprocess.Popen([str(pinc_binary()), "serve", "--connect", "tcp:127.0.0.1:9", "--timeout", "1",
                                 "--data", str(tmp_path), "--port", "0", "--vehicle", str(VEHICLE)],
                                stderr=subprocess.PIPE, text=True)
        # The address is on the line that says so (a restart first says whose limits it took).
        line = next(line for line in proc.stderr if "http://" in line)
        base = "http://" + re.search(r"http://(127\.0\.0\.1:\d+)", line).group(1)
        token = re.search(r'const TOKEN = "([0-9a-f]{32})"', urllib.request.urlopen(base + "/").read().decode()).group(1)
        return proc, base, token

    def post(base, token, body):
        return call(base, "/api/limits", body, token)

    def limits(base):
        return json.loads(urllib.request.urlopen(base + "/api/state").read())["server"]["limits"]

    proc, base, token = start()
    try:
        # The defaults suit a dive, not a pool: said as such until the owner sets their own.
        first = limits(base)
        assert (first["max_depth"], first["max_distance"], first["max_duration"], first["owners"]) == \
            (50.0, 100.0, 1800.0, False), first
        assert post(base, token, {"max_depth": 0, "max_distance": 10, "max_duration": 60}) == \
            (400, {"error": "max_depth 0 m must be above 0 and at most 300 m"})
        assert post(base, token, {"max_depth": 12, "max_distance": 40}) [0] == 400
        assert post(base, token, {"max_depth": 12, "max_distance": 40, "max_duration": 900})[0] == 200
        now = limits(base)
        assert (now["max_depth"], now["max_distance"], now["max_duration"], now["owners"]) == (12.0, 40.0, 900.0, True)
        # A flight past them is refused, naming the limit.
        req = urllib.request.Request(base + "/api/fly", method="POST", headers={"X-Pinc-Token": token},
                                     data=json.dumps({"model": "m", "duration": 30, "references": {
                                         "kind": "steps", "depth": [1, 13], "depth_at": 10, "heading": [0, 0],
                                         "heading_at": 20}}).encode())
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(req)
        assert "depth to 13 m is outside the vehicle's limits: 0 to 12 m" in json.loads(e.value.read())["error"]
    finally:
        proc.terminate()
        proc.wait(10)
    assert json.loads((tmp_path / "limits.json").read_text()) == {"max_depth": 12.0, "max_distance": 40.0,
                                                                  "max_duration": 900.0}
    proc, base, _ = start()
    try:
        again = limits(base)
        assert (again["max_depth"], again["max_distance"], again["max_duration"]) == (12.0, 40.0, 900.0), again
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_refused_connection_names_the_addresses_blueos_serves():
    r = subprocess.run([str(pinc_binary()), "vehicle", "status", "--connect", "tcp:127.0.0.1:9", "--timeout", "1"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1, r
    assert "Connection refused" in r.stderr and "udpout:192.168.2.2:14550" in r.stderr \
        and "tcp:127.0.0.1:5777" in r.stderr, r.stderr
