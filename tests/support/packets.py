"""MAVLink messages packed as one sender puts them on the wire (for tests)."""

from __future__ import annotations

from m4.mavlink import new_mav
from m4.mavlink.signing import setup_signing


class PacketSink:
    """A pymavlink connection's `file` that keeps every packet written to it."""

    def __init__(self):
        self.packets: list[bytes] = []

    def write(self, packet) -> None:
        self.packets.append(bytes(packet))


def packed(msgs, system: int = 1, component: int = 1, key: bytes | None = None, link_id: int = 0) -> list[bytes]:
    """Each of `msgs`, in order, packed by one sender `system/component` (signed with `key` on
    `link_id`)."""
    sink = PacketSink()
    mav = new_mav(sink, system, component)
    if key is not None:
        setup_signing(mav, key, link_id)
    for msg in msgs:
        mav.send(msg)
    return sink.packets
