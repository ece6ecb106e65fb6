"""A socket-free FcTransport: what arrives is queued by the test, what is sent is kept.

The bytes still go through a real MAVLink parser (and signing, with a key), so a test feeds
it what a flight controller would put on the wire, garbage included; only the socket is gone.
"""

from __future__ import annotations

from collections import deque

from m4.mavlink import mavlink, new_mav
from m4.mavlink.link import parse_bytes
from m4.mavlink.signing import SigningCounters, setup_signing


class FakeTransport:
    def __init__(self, source_system: int, source_component: int, key: bytes | None = None):
        self.mav = new_mav(self, source_system, source_component)
        if key is not None:
            setup_signing(self.mav, key)
        self.inbox: deque[tuple[bytes, object]] = deque()
        self.sent: list[bytes] = []
        self.locked_peer = None
        self.hear_others = False
        self.bad_packets = 0
        self.foreign_datagrams = 0

    # -- the test's side ---------------------------------------------------------------------------
    def deliver(self, sender, *msgs: mavlink.MAVLink_message, mav: mavlink.MAVLink) -> None:
        """One datagram from `sender` holding `msgs`, packed by `mav` (the sender's ids and key)."""
        self.inbox.append((b"".join(msg.pack(mav) for msg in msgs), sender))

    def sent_messages(self) -> list[mavlink.MAVLink_message]:
        parser = new_mav(None, 255, 0)
        return [m for p in self.sent for m in parser.parse_buffer(p) or ()]

    # -- FcTransport -------------------------------------------------------------------------------
    @property
    def signing_key(self) -> bytes | None:
        return self.mav.signing.secret_key

    def write(self, packet: bytes) -> None:
        self.sent.append(bytes(packet))

    def send(self, msg: mavlink.MAVLink_message) -> None:
        self.mav.send(msg)

    def send_all(self, msgs) -> None:
        for msg in msgs:
            self.mav.send(msg)

    def receive_from(self):
        out = []
        while self.inbox:
            data, sender = self.inbox.popleft()
            if self.locked_peer is not None and sender != self.locked_peer and not self.hear_others:
                self.foreign_datagrams += 1
                continue
            msgs, bad = parse_bytes(self.mav, data, None)
            self.bad_packets += bad
            out.append((sender, msgs))
        return out

    def lock_peer(self, address, hear_others: bool = False) -> None:
        self.locked_peer, self.hear_others = address, hear_others

    def signing_counters(self) -> SigningCounters:
        return SigningCounters.of(self.mav)

    def fileno(self) -> int:
        return -1

    def close(self) -> None:
        self.inbox.clear()
