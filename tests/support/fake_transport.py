"""A socket-free FcTransport: what arrives is queued by the test, what is sent is kept.

The bytes still go through a real MAVLink parser (and signing, with a key; m4.mavlink.link's
MavlinkLink), so a test feeds it what a flight controller would put on the wire, garbage
included; only the socket is gone.
"""

from __future__ import annotations

from collections import deque

from m4.mavlink import mavlink, new_mav
from m4.mavlink.link import MavlinkLink
from m4.mavlink.second_sender import OTHER_ADDRESS


class FakeTransport(MavlinkLink):
    def __init__(self, source_system: int, source_component: int, key: bytes | None = None):
        super().__init__(source_system, source_component, None, key, 0)
        self.inbox: deque[tuple[bytes, object]] = deque()
        self.sent: list[bytes] = []
        self.locked_peer = None
        self.hear_others = False
        self.foreign_datagrams = 0

    # -- the test's side ---------------------------------------------------------------------------
    def deliver(self, sender, *msgs: mavlink.MAVLink_message, mav: mavlink.MAVLink) -> None:
        """One datagram from `sender` holding `msgs`, packed by `mav` (the sender's ids and key)."""
        self.inbox.append((b"".join(msg.pack(mav) for msg in msgs), sender))

    def sent_messages(self) -> list[mavlink.MAVLink_message]:
        parser = new_mav(None, 255, 0)
        return [m for p in self.sent for m in parser.parse_buffer(p) or ()]

    # -- FcTransport -------------------------------------------------------------------------------
    def write(self, packet: bytes) -> None:
        self.sent.append(bytes(packet))

    def receive_from(self):
        out = []
        while self.inbox:
            data, sender = self.inbox.popleft()
            if self.locked_peer is not None and sender != self.locked_peer and not self.hear_others:
                self.foreign_datagrams += 1
                self.refused(sender, data, OTHER_ADDRESS)
                continue
            out.append((sender, self.parse(data, sender)))
        return out

    def lock_peer(self, address, hear_others: bool = False) -> None:
        self.locked_peer, self.hear_others = address, hear_others

    def fileno(self) -> int:
        return -1

    def close(self) -> None:
        self.inbox.clear()
