"""One entry point from a pymavlink-style URL to a link: UDP (udpin, udpout, udp = udpin),
TCP (tcp: connect, tcpin: listen for one peer) or a serial device (`/dev/NAME[,BAUD]`, `COMn`).

Every link has the same small interface: `send(msg)`, `receive()`, `receive_from()` (each
batch with its sender), `lock_peer(address)`, `fileno()`, `signing_counters()`, `close()`,
`local_port`, and the counters `bad_packets` and `foreign_datagrams`.
"""

from __future__ import annotations

import re

from companion.mavlink.link import LinkError, UdpLink
from companion.mavlink.stream_link import SERIAL_DEFAULT_BAUD, open_serial, open_tcp
from companion.mavlink.tlog import TlogWriter

_TCP = re.compile(r"^(tcp|tcpin):(?://)?([^:\s]+):(\d{1,5})$")
_SERIAL = re.compile(r"^(/dev/\S+?|COM\d+)(?:,(\d+))?$")


def open_link(url: str, source_system: int, source_component: int, *, tlog: TlogWriter | None = None,
              key: bytes | None = None, link_id: int = 0):
    """Open the link a URL names; LinkError says what is wrong with it."""
    kwargs = {"tlog": tlog, "key": key, "link_id": link_id}
    if m := _TCP.match(url):
        port = int(m.group(3))
        if not 0 <= port <= 65535 or (m.group(1) == "tcp" and port == 0):
            raise LinkError(f"bad MAVLink URL {url!r}: port out of range")
        return open_tcp(m.group(1), m.group(2), port, source_system, source_component, **kwargs)
    if m := _SERIAL.match(url):
        return open_serial(m.group(1), int(m.group(2) or SERIAL_DEFAULT_BAUD), source_system, source_component,
                           **kwargs)
    mode = url.partition(":")[0]
    if mode == "udp":
        url = "udpin" + url[len(mode):]
    try:
        return UdpLink(url, source_system, source_component, **kwargs)
    except LinkError:
        if mode not in ("udp", "udpin", "udpout"):
            raise LinkError(f"bad MAVLink URL {url!r}: expected udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
                            f"tcpin:HOST:PORT or a serial device /dev/NAME,BAUD") from None
        raise


__all__ = ["LinkError", "open_link"]
