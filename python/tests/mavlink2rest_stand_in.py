"""mavlink2rest's part in a ground station's joystick reaching pinc: Cockpit sends its
MANUAL_CONTROL through mavlink2rest, which keeps each sender's last message with a count of
those that came (its data.rs), and answers
GET /v1/mavlink/vehicles/255/components/240/messages/MANUAL_CONTROL with
{"message": {"type": "MANUAL_CONTROL", "target": .., "x": .., ...},
 "status": {"time": {"first_update": .., "last_update": .., "counter": N, "frequency": F}}},
or `None` before the first. Served on 127.0.0.1:PORT until the process ends.
"""

import datetime
import http.server
import json
import threading

PATH = "/v1/mavlink/vehicles/255/components/240/messages/MANUAL_CONTROL"


class Mavlink2Rest:
    def __init__(self, port):
        self.lock = threading.Lock()
        self.message, self.counter, self.first = None, 1, None
        stand_in = self

        class Answer(http.server.BaseHTTPRequestHandler):
            def do_GET(self):
                if self.path != PATH:
                    self.send_error(404)
                    return
                data = stand_in.answer().encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *args):
                pass

        server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Answer)
        threading.Thread(target=server.serve_forever, daemon=True).start()

    def keep(self, target, x, y, z, r, buttons=0):
        """One MANUAL_CONTROL as Cockpit sends it (x forward, y right, r a turn right in
        -1000..1000, z 0..1000 with 500 centred and above 500 up)."""
        now = datetime.datetime.now().astimezone().isoformat()
        with self.lock:
            self.message = {"type": "MANUAL_CONTROL", "target": target, "x": x, "y": y, "z": z, "r": r,
                            "buttons": buttons}
            self.counter += 1
            self.first = self.first or now
            self.last = now

    def answer(self):
        with self.lock:
            if self.message is None:
                return "None"
            time = {"first_update": self.first, "last_update": self.last, "counter": self.counter, "frequency": 25.0}
            return json.dumps({"message": self.message, "status": {"time": time}})
