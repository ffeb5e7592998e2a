"""What the simulator's second ground stations (sitl_inject.py, dvl_stand_in.py) share: their
connection on the simulator's third port, made while the client they run starts it."""

import time

from pymavlink import mavutil


def connect(port, proc, tries=150):
    """A MAVLink connection to 127.0.0.1:`port`, retried every 0.2 s (the simulator listens
    once the client `proc` connects to 5760); None if `proc` ends or it never answers."""
    for _ in range(tries):
        try:
            return mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=254, retries=0)
        except OSError:
            time.sleep(0.2)
            if proc.poll() is not None:
                return None
    return None
