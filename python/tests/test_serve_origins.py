"""Who may command the vehicle through `pinc serve`, in a real browser (Debian's chromium) behind a
stand-in of BlueOS's nginx: `/extensionv2/pinc/` proxied to the extension, its own
`Access-Control-Allow-Origin` hidden and `*` added to every answer (BlueOS's core/tools/nginx/nginx.conf
does `proxy_hide_header` and `add_header ... * always`), so any page can read pinc's token there.

- another site's page, plain and in a sandboxed frame, reads the token and still cannot start,
  hold, resume or fly: its browser's preflight is refused, and nothing reaches a command;
- Cockpit's action, as Cockpit sends it (its URL, `Content-Type` and token headers, a `fetch`), is
  taken from Cockpit Lite's page at BlueOS's own address and from Cockpit desktop's file page.

No vehicle here (the server's link points at a closed port): a command taken is one that reaches
its own checks ("hold here" answers that the vehicle's depth is not known, STOP sends neutral and
disarm); python/tests/test_ardusub_hold.py holds the firmware's vehicle with the same request.
"""

import http.client
import http.server
import json
import re
import shutil
import subprocess
import threading
import urllib.request
from pathlib import Path

import pytest

from test_vehicle_link import ROOT, pinc_binary

BROWSER = Path("/usr/bin/chromium").exists() and Path("/usr/bin/chromedriver").exists()
VEHICLE = ROOT / "tests" / "fixtures" / "ardusub" / "sitl_vectored.toml"
PREFIX = "/extensionv2/pinc"


class Nginx(http.server.BaseHTTPRequestHandler):
    """BlueOS's nginx as far as an extension sees it: the path prefix stripped, the request passed on
    whole (OPTIONS too), the answer's own Allow-Origin replaced by `*`; `/extensionv2/cockpitlite/`
    served from a folder (Cockpit Lite at the vehicle's address)."""
    upstream = None
    pages = None

    def log_message(self, *args):
        pass

    def _forward(self):
        if self.path.startswith("/extensionv2/cockpitlite/"):
            body = (self.pages / self.path.rsplit("/", 1)[1]).read_bytes()
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        if not self.path.startswith(PREFIX + "/"):
            self.send_error(404)
            return
        length = int(self.headers.get("Content-Length") or 0)
        body = self.rfile.read(length) if length else None
        conn = http.client.HTTPConnection(*self.upstream, timeout=20)
        headers = {k: v for k, v in self.headers.items() if k.lower() not in ("host", "connection")}
        headers["Host"] = self.headers["Host"]  # nginx's proxy_set_header Host $host
        conn.request(self.command, self.path[len(PREFIX):], body=body, headers=headers)
        r = conn.getresponse()
        data = r.read()
        self.send_response(r.status)
        for k, v in r.getheaders():
            if k.lower() not in ("access-control-allow-origin", "content-length", "connection", "transfer-encoding"):
                self.send_header(k, v)
        self.send_header("Access-Control-Allow-Origin", "*")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    do_GET = do_POST = do_OPTIONS = _forward


# What a page does with pinc's address: reads the token from the extras (which BlueOS's `*` lets it),
# then each command as Cockpit's action would send it; each outcome by name in the title.
SCRIPT = """
const out = {};
(async () => {
  try {
    const extras = await (await fetch("TARGET/cockpit_extras.json")).json();
    out.token = extras.actions[0].config.headers["X-Pinc-Token"];
  } catch (e) { out.token = "blocked: " + e; }
  const headers = {"Content-Type": "application/json", "X-Pinc-Token": out.token};
  for (const [name, body] of COMMANDS) {
    try {
      const r = await fetch("TARGET/api/" + name, {method: "POST", headers, body: JSON.stringify(body)});
      out[name] = [r.status, (await r.json()).error || "taken"];
    } catch (e) { out[name] = "blocked: " + e; }
  }
  (window.parent || window).postMessage(JSON.stringify(out), "*");
  document.title = JSON.stringify(out);
})();
"""
ATTACKS = [["excite", {"depth_band": [0.5, 2.5], "axes": ["heave"], "duration": 30}], ["hold", {}], ["resume", {}],
           ["fly", {"model": "sim", "references": {"kind": "hold"}, "duration": 30}]]
COCKPIT = [["hold", {}], ["stop", {}]]


def page(target, commands):
    return f"<!doctype html><html><body><script>{SCRIPT.replace('TARGET', target).replace('COMMANDS', json.dumps(commands))}</script></body></html>"


def sandboxed(target, commands):
    """A page framing the script in a sandbox (scripts allowed, its own origin not: `Origin: null`)."""
    inner = page(target, commands).replace("&", "&amp;").replace('"', "&quot;")
    return ("<!doctype html><html><body><script>addEventListener('message', e => document.title = e.data);</script>"
            f'<iframe sandbox="allow-scripts" srcdoc="{inner}"></iframe></body></html>')


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    if not BROWSER:
        pytest.skip("/usr/bin/chromium or /usr/bin/chromedriver is missing: apt install chromium chromium-driver")
    tmp = tmp_path_factory.mktemp("origins")
    data = tmp / "data"
    (data / "models" / "sim").mkdir(parents=True)
    shutil.copy(ROOT / "models" / "mpc_pinc_thrust.pinc", data / "models" / "sim" / "model.pinc")
    proc = subprocess.Popen([str(pinc_binary()), "serve", "--connect", "tcp:127.0.0.1:9", "--timeout", "1",
                             "--data", str(data), "--port", "0", "--vehicle", str(VEHICLE)],
                            stderr=subprocess.PIPE, text=True)
    m = re.search(r"http://(127\.0\.0\.1):(\d+)", proc.stderr.readline())
    log = []
    threading.Thread(target=lambda: log.extend(proc.stderr), daemon=True).start()
    pages = tmp / "pages"
    pages.mkdir()
    Nginx.upstream, Nginx.pages = (m.group(1), int(m.group(2))), pages
    nginx = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Nginx)
    threading.Thread(target=nginx.serve_forever, daemon=True).start()
    vehicle = f"http://127.0.0.1:{nginx.server_address[1]}"
    yield vehicle, pages, tmp, log
    nginx.shutdown()
    proc.terminate()
    proc.wait(10)


def chromium(*flags):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", *flags):
        options.add_argument(flag)
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)


def outcome(browser, url):
    from selenium.webdriver.support.ui import WebDriverWait
    browser.get(url)
    WebDriverWait(browser, 20).until(lambda b: b.title.startswith("{"), message=url)
    return json.loads(browser.title)


def test_another_sites_page_reads_the_token_through_blueos_and_still_moves_nothing(site):
    vehicle, _, tmp, log = site
    target = vehicle + PREFIX
    evil = tmp / "evil"
    evil.mkdir()
    (evil / "plain.html").write_text(page(target, ATTACKS))
    (evil / "framed.html").write_text(sandboxed(target, ATTACKS))
    handler = lambda *a, **k: http.server.SimpleHTTPRequestHandler(*a, directory=str(evil), **k)  # noqa: E731
    other = http.server.ThreadingHTTPServer(("127.0.0.2", 0), handler)
    threading.Thread(target=other.serve_forever, daemon=True).start()
    browser = chromium()
    try:
        results = {name: outcome(browser, f"http://127.0.0.2:{other.server_address[1]}/{name}.html")
                   for name in ("plain", "framed")}
    finally:
        browser.quit()
        other.shutdown()
    print(json.dumps(results))
    extras = json.loads(urllib.request.urlopen(target + "/cockpit_extras.json").read())
    token = extras["actions"][0]["config"]["headers"]["X-Pinc-Token"]
    for name, out in results.items():
        # BlueOS's `*` lets the page read the token...
        assert out["token"] == token, (name, out)
        # ...and the browser still sends none of the commands: their preflight is refused.
        for command, _ in ATTACKS:
            assert str(out[command]).startswith("blocked"), (name, command, out)
    refused = [line for line in log if "refused OPTIONS" in line]
    assert any("(http://127.0.0.2:" in line for line in refused), log
    assert any("(null)" in line for line in refused), log
    assert not any("serve: job" in line or "STOP (" in line for line in log), log


def test_cockpits_action_is_taken_from_blueos_address_and_from_cockpit_desktop(site):
    vehicle, pages, tmp, log = site
    target = vehicle + PREFIX
    (pages / "cockpit.html").write_text(page(target, COCKPIT))
    desktop = tmp / "desktop.html"
    desktop.write_text(page(target, COCKPIT))
    # Cockpit Lite: its page at the vehicle's own address, beside the extension.
    browser = chromium()
    try:
        lite = outcome(browser, vehicle + "/extensionv2/cockpitlite/cockpit.html")
    finally:
        browser.quit()
    # Cockpit desktop: Electron's file page, whose fetches carry `Origin: file://` (the file
    # protocol's privileges Electron grants by default; Chromium's flag for them here).
    browser = chromium("--allow-file-access-from-files")
    try:
        electron = outcome(browser, desktop.as_uri())
    finally:
        browser.quit()
    print(json.dumps({"lite": lite, "desktop": electron}))
    for out in (lite, electron):
        # Taken: "hold here" reaches its own check (no vehicle here), STOP sends neutral and disarm.
        assert out["hold"][0] == 409 and "depth is not known" in out["hold"][1], out
        assert out["stop"] == [200, "taken"], out
    assert sum("STOP (neutral and disarm sent" in line for line in log) == 2, log
