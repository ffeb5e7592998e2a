"""The live view (`mpc_track --foxglove`, feature `live-view`): a client of Foxglove's WebSocket
protocol (the `websockets` package, speaking `foxglove.sdk.v1`, the SDK server's version of it)
connects while a run goes, subscribes to every topic the server advertises, and checks each
message it receives against the MCAP log the same run wrote: same topic, same log time, same
content.
"""

import json
import struct
import subprocess
import time
from pathlib import Path

import pytest

from test_vehicle_link import read_mcap
from test_vehicle_drive import mpc_track_binary

sync_client = pytest.importorskip("websockets.sync.client", reason="pip install './python[test]' (websockets)")

PROTOCOL = "foxglove.sdk.v1"  # the SDK server's name for the protocol (inline schemas)
MESSAGE_DATA = 0x01


def start_run(tmp_path, seconds):
    binary = mpc_track_binary()
    if "--foxglove" not in subprocess.run([str(binary), "--help"], capture_output=True, text=True).stdout:
        pytest.skip(f"{binary} was built without feature live-view (the test command builds it with --all-features)")
    p = subprocess.Popen([str(binary), "--duration", str(seconds), "--foxglove", "127.0.0.1:0", "--json",
                          "--out-dir", str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # The port it picked comes first on stderr.
    line = p.stderr.readline()
    assert line.startswith("live view: ws://127.0.0.1:"), line
    port = int(line.split(":")[-1].split()[0])
    return p, f"ws://127.0.0.1:{port}"


def test_a_client_receives_what_the_log_holds_as_the_run_goes(tmp_path):
    p, url = start_run(tmp_path, 6)
    channels, received = {}, []
    started = time.monotonic()
    with sync_client.connect(url, subprotocols=[PROTOCOL], open_timeout=10, max_size=None) as ws:
        assert ws.subprotocol == PROTOCOL
        subscribed = {}
        while True:
            try:
                frame = ws.recv(timeout=3)
            except TimeoutError:
                break
            except Exception:  # the server closed: the run ended
                break
            if isinstance(frame, str):
                m = json.loads(frame)
                if m["op"] == "advertise":
                    new = [c for c in m["channels"] if c["id"] not in channels]
                    for c in new:
                        channels[c["id"]] = c
                        subscribed[len(subscribed) + 1] = c["id"]
                    subs = [{"id": sid, "channelId": cid} for sid, cid in subscribed.items() if cid in
                            {c["id"] for c in new}]
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                continue
            assert frame[0] == MESSAGE_DATA, frame[:1]
            sid, log_time = struct.unpack_from("<IQ", frame, 1)
            received.append((channels[subscribed[sid]]["topic"], log_time, json.loads(frame[13:])))
    out, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    elapsed = time.monotonic() - started
    summary = json.loads(out)
    # What was advertised: the log's topics, with their schemas, as JSON.
    topics = {c["topic"] for c in channels.values()}
    assert {"/vehicle/state", "/mpc/command", "/mpc/reference", "/mpc/prediction", "/log"} <= topics, topics
    assert all(c["encoding"] == "json" and c["schemaEncoding"] == "jsonschema" for c in channels.values())
    # A watched run goes in real time: 6 s of samples took about 6 s.
    assert elapsed >= 5.0, elapsed
    # Every message received is the log's, at its log time.
    log = read_mcap(Path(summary["log"]))
    key = lambda topic, t, m: (topic, t, json.dumps(m, sort_keys=True))  # noqa: E731
    logged = {key(topic, t, m) for topic, msgs in log.items() for t, m in msgs}
    states = [r for r in received if r[0] == "/vehicle/state"]
    print(f"{len(received)} messages received ({len(states)} states) of {sum(len(v) for v in log.values())} "
          f"in the log, over {elapsed:.1f} s")
    assert len(states) >= 0.8 * summary["samples"], (len(states), summary["samples"])
    for topic, t, m in received:
        assert key(topic, t, m) in logged, (topic, t, m)
