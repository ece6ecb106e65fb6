"""One entry point from a pymavlink-style URL to a link: UDP (udpin, udpout, udp = udpin),
TCP (tcp: connect, tcpin: listen for one peer) or a serial device (`/dev/NAME[,BAUD]`, `COMn`).

Every link has the same small interface: `send(msg)`, `receive()`, `receive_from()` (each
batch with its sender), `lock_peer(address)`, `fileno()`, `signing_counters()`, `close()`,
`local_port`, and the counters `bad_packets` and `foreign_datagrams`.
"""

from __future__ import annotations

import re

from m4.mavlink.link import LinkError, UdpLink, parse_url
from m4.mavlink.stream_link import SERIAL_DEFAULT_BAUD, open_serial, open_tcp
from m4.mavlink.tlog import TlogWriter

_TCP = re.compile(r"^(tcp|tcpin):(?://)?([^:\s]+):(\d{1,5})$")
_SERIAL = re.compile(r"^(/dev/\S+?|COM\d+)(?:,(\d+))?$")
_UDP_MODES = ("udp", "udpin", "udpout")


def check_url(url: str) -> str:
    """The URL as open_link reads it (udp: is udpin:) when it names a link open_link can open;
    LinkError saying what is wrong otherwise. Only the text is checked: nothing is opened."""
    if m := _TCP.match(url):
        port = int(m.group(3))
        if not 0 <= port <= 65535 or (m.group(1) == "tcp" and port == 0):
            raise LinkError(f"bad MAVLink URL {url!r}: port out of range")
        return url
    if _SERIAL.match(url):
        return url
    mode = url.partition(":")[0]
    if mode not in _UDP_MODES:
        raise LinkError(f"bad MAVLink URL {url!r}: expected udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
                        f"tcpin:HOST:PORT or a serial device /dev/NAME,BAUD")
    url = "udpin" + url[len(mode):] if mode == "udp" else url
    parse_url(url)
    return url


def listens_for_peer(url: str) -> bool:
    """True for a UDP link that listens (udpin:, udp:): it learns its peer from the first packet
    it receives, so it has nobody to send to before that."""
    return check_url(url).startswith("udpin:")


def open_link(url: str, source_system: int, source_component: int, *, tlog: TlogWriter | None = None,
              key: bytes | None = None, link_id: int = 0):
    """Open the link a URL names; LinkError says what is wrong with it."""
    url = check_url(url)
    kwargs = {"tlog": tlog, "key": key, "link_id": link_id}
    if m := _TCP.match(url):
        return open_tcp(m.group(1), m.group(2), int(m.group(3)), source_system, source_component, **kwargs)
    if m := _SERIAL.match(url):
        return open_serial(m.group(1), int(m.group(2) or SERIAL_DEFAULT_BAUD), source_system, source_component,
                           **kwargs)
    return UdpLink(url, source_system, source_component, **kwargs)


__all__ = ["LinkError", "check_url", "listens_for_peer", "open_link"]
