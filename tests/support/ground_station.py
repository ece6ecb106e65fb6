"""A ground station (system 255) on a loopback udpin link, as the FC's second link meets it: it
keeps what it hears and waits for what it expects."""

from __future__ import annotations

import time

from m4.mavlink import mavlink
from m4.mavlink.link import UdpLink, wait_readable


class GroundStation:
    def __init__(self, component: int = 190, key: bytes | None = None):
        self.link = UdpLink("udpin:127.0.0.1:0", 255, component, key=key)
        self.heard: list[mavlink.MAVLink_message] = []

    @property
    def url(self) -> str:
        """The URL the FC sends to it by."""
        return f"udpout:127.0.0.1:{self.link.local_port}"

    def wait(self, name: str, match=lambda m: True, count: int = 1, timeout_s: float = 15.0) -> list:
        """The first `count` messages `name` heard that `match` (AssertionError after timeout_s)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            found = [m for m in self.heard if m.get_type() == name and match(m)]
            if len(found) >= count:
                return found
            wait_readable([self.link], 0.05)
            self.heard += self.link.receive()
        heard = sorted({m.get_type() for m in self.heard})
        raise AssertionError(f"no {count} {name} within {timeout_s} s; heard {heard}")

    def send(self, msg) -> None:
        """To the FC, once it has been heard since the last `ask` (a udpin link answers whoever
        wrote last: a restarted FC's new port)."""
        deadline = time.monotonic() + 15.0
        while not self.heard:
            assert time.monotonic() < deadline, "nothing heard from the FC in 15 s"
            wait_readable([self.link], 0.05)
            self.heard += self.link.receive()
        self.link.send(msg)

    def ask(self, msg, name: str, match=lambda m: True, count: int = 1) -> list:
        """Send `msg`, forgetting what was heard so far; the answers `name` that `match`."""
        self.heard.clear()
        self.send(msg)
        return self.wait(name, match, count)

    def set(self, name: str, value: float, param_type: int = mavlink.MAV_PARAM_TYPE_REAL32, component: int = 1):
        """PARAM_SET; the PARAM_VALUE that answers it."""
        return self.ask(mavlink.MAVLink_param_set_message(1, component, name.encode(), value, param_type),
                        "PARAM_VALUE", lambda m: m.param_id == name)[0]

    def close(self) -> None:
        self.link.close()
