"""One entry point from a pymavlink-style URL to a link: UDP (udpin, udpout, udp = udpin),
TCP (tcp: connect, tcpin: listen for one peer) or a serial device (`/dev/NAME,BAUD`).

Every link has the same small interface: `send(msg)`, `receive()`, `receive_from()` (each
batch with its sender), `lock_peer(address)`, `fileno()`, `signing_counters()`, `close()`,
and the counters `bad_packets` and `foreign_datagrams`.
"""

from __future__ import annotations

from companion.mavlink.link import LinkError, UdpLink
from companion.mavlink.tlog import TlogWriter


def open_link(url: str, source_system: int, source_component: int, *, tlog: TlogWriter | None = None,
              key: bytes | None = None, link_id: int = 0):
    """Open the link a URL names; LinkError says what is wrong with it."""
    mode = url.partition(":")[0]
    if mode == "udp":
        url = "udpin" + url[len(mode):]
    return UdpLink(url, source_system, source_component, tlog=tlog, key=key, link_id=link_id)


__all__ = ["LinkError", "open_link"]
