"""A MAVLink router stand-in, the part of BlueOS's that matters to a ground station's joystick
reaching pinc: one upstream link to the autopilot (TCP client) and a TCP server whose every client
is a link of its own (BlueOS's "Internal Link", 127.0.0.1:5777). Frames are forwarded whole
(header and signature as they came), never back to the link they came from, in one of the two
ways BlueOS's routers route (read in their sources):

- `broadcast`: every frame to every other link (bluerobotics/mavlink-server);
- `target`: a frame naming a target system only to the links that system was heard on, the
  others to every link (mavlink-router's `Endpoint::accept_msg`, BlueOS 1.4's default).

Started by a test inside the simulator's network namespace; it stops with its process.
"""

import os
import socket
import threading

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402


class Hub:
    def __init__(self, upstream, port, route="broadcast"):
        assert route in ("broadcast", "target"), route
        self.route = route
        self.links = []  # (socket, systems heard on it)
        self.lock = threading.Lock()
        up = socket.create_connection(upstream, timeout=30)
        up.settimeout(None)
        self._add(up)
        self.server = socket.create_server(("127.0.0.1", port))
        threading.Thread(target=self._accept, daemon=True).start()

    def _add(self, sock):
        link = (sock, set())
        with self.lock:
            self.links.append(link)
        threading.Thread(target=self._read, args=(link,), daemon=True).start()

    def _accept(self):
        while True:
            sock, _ = self.server.accept()
            self._add(sock)

    def _read(self, link):
        sock, heard = link
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        while True:
            try:
                data = sock.recv(4096)
            except OSError:
                data = b""
            if not data:
                with self.lock:
                    self.links.remove(link)
                return
            for msg in parser.parse_buffer(data) or []:
                if msg.get_type() == "BAD_DATA":
                    continue
                heard.add(msg.get_srcSystem())
                target = getattr(msg, "target_system", getattr(msg, "target", 0)) or 0
                frame = msg.get_msgbuf()
                with self.lock:
                    others = [(s, h) for s, h in self.links if s is not sock]
                for s, h in others:
                    if self.route == "target" and target and target not in h:
                        continue
                    try:
                        s.sendall(frame)
                    except OSError:
                        pass
