"""A MAVLink 2 link over UDP: the generated protocol object on a socket of our own.

URLs, as pymavlink writes them: `udpin:HOST:PORT` listens there and answers whoever wrote
last; `udpout:HOST:PORT` sends there from an ephemeral port and reads the replies. Each
packet sent and each packet received (good or rejected) goes to the tlog when one is given.
Nothing here blocks: `receive()` drains what has arrived, `wait_readable()` waits.
`lock_peer(address)` pins a udpin link to one sender (e.g. the flight controller once its
HEARTBEAT came): datagrams from anyone else are then dropped and counted (`foreign_datagrams`)
and can no longer redirect the replies. Short of that, `peer_filter` says which messages may
redirect a udpin link's replies to their sender (default: any good message; garbage never).
`receive_from(max_datagrams)` bounds the work of one call, so a flood cannot starve the caller.
`on_refused(sender, system, component, why)`, when set, hears of every packet the link refused
that claims an identity: one signing refused (why: m4.mavlink.signing.refusal) or, once
locked, a datagram from another address (why: "other address"; its first frame's header).
"""

from __future__ import annotations

import select
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from m4.mavlink.dialect import mavlink, new_mav
from m4.mavlink.frame_reader import read_datagram
from m4.mavlink.second_sender import OTHER_ADDRESS
from m4.mavlink.signing import SigningCounters, refusal, setup_signing
from m4.mavlink.tlog import TlogWriter

MODES = ("udpin", "udpout")
_DATAGRAM_MAX = 65535
DATAGRAM_PAYLOAD_MAX = 1400      # below a 1500-byte Ethernet MTU with IP and UDP headers
_SIGNATURE_REFUSED = "Invalid signature"      # pymavlink's BAD_DATA reason


class LinkError(ValueError):
    """A link URL is malformed or its socket cannot be opened (e.g. port in use)."""


@dataclass(frozen=True)
class Endpoint:
    mode: str          # "udpin" or "udpout"
    host: str
    port: int

    @property
    def url(self) -> str:
        return f"{self.mode}:{self.host}:{self.port}"


def parse_url(url: str) -> Endpoint:
    """`udpin:HOST:PORT` or `udpout:HOST:PORT` (also with `://`)."""
    mode, sep, rest = url.partition(":")
    rest = rest.removeprefix("//")
    host, _, port = rest.rpartition(":")
    if not sep or mode not in MODES or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise LinkError(f"bad MAVLink URL {url!r}: expected udpin:HOST:PORT or udpout:HOST:PORT")
    if mode == "udpout" and int(port) == 0:
        raise LinkError(f"bad MAVLink URL {url!r}: udpout needs a port to send to (udpout:HOST:PORT, PORT > 0)")
    return Endpoint(mode, host, int(port))


class MavlinkLink:
    """What every link shares: the protocol object writing to `self.write(packet)` (signing
    with `key` when one is given), `send`, `receive`, `parse` and the signing counters. A
    subclass provides `write(packet)` and `receive_from()`."""

    def __init__(self, source_system: int, source_component: int, tlog: TlogWriter | None, key: bytes | None,
                 link_id: int):
        self.tlog = tlog
        self.mav = new_mav(self, source_system, source_component)
        if key is not None:
            setup_signing(self.mav, key, link_id)
        self.bad_packets = 0
        self.on_refused: Callable[[Any, int, int, str], None] | None = None

    def parse(self, data: bytes, sender: Any) -> list[mavlink.MAVLink_message]:
        """The good messages in `data` from `sender`; the rest counted in bad_packets, and each
        packet signing refused told to on_refused."""
        out, bad = parse_bytes(self.mav, data, self.tlog)
        self.bad_packets += len(bad)
        for msg in bad:
            if msg.reason == _SIGNATURE_REFUSED:
                self.refused(sender, bytes(msg.data), refusal(self.mav.signing.secret_key, bytes(msg.data)))
        return out

    def refused(self, sender: Any, packet: bytes, why: str) -> None:
        """Tell on_refused of a refused `packet` claiming an identity."""
        ids = claimed_ids(packet)
        if self.on_refused is not None and ids is not None:
            self.on_refused(sender, *ids, why)

    def send(self, msg: mavlink.MAVLink_message) -> None:
        self.mav.send(msg)

    def send_all(self, msgs) -> None:
        """Send several messages back to back (a datagram link packs them into as few as fit)."""
        for msg in msgs:
            self.mav.send(msg)

    def receive(self) -> list[mavlink.MAVLink_message]:
        """Every message that has arrived; rejected and garbled packets are counted, not returned."""
        return [msg for _, msgs in self.receive_from() for msg in msgs]

    @property
    def source_ids(self) -> tuple[int, int]:
        """(system, component) every packet sent goes out as."""
        return self.mav.srcSystem, self.mav.srcComponent

    @property
    def signing_key(self) -> bytes | None:
        """The signing key (None: the link neither signs nor checks signatures)."""
        return self.mav.signing.secret_key

    def signing_counters(self) -> SigningCounters:
        return SigningCounters.of(self.mav)


class UdpLink(MavlinkLink):
    def __init__(self, url: str, source_system: int, source_component: int, *,
                 tlog: TlogWriter | None = None, key: bytes | None = None, link_id: int = 0):
        self.endpoint = parse_url(url)
        super().__init__(source_system, source_component, tlog, key, link_id)
        self.peer: tuple[str, int] | None = None
        self.locked_peer: tuple[str, int] | None = None
        self.hear_others = False
        self.foreign_datagrams = 0
        self.peer_filter: Callable[[mavlink.MAVLink_message], bool] = lambda msg: True
        self._batch: list[bytes] | None = None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if self.endpoint.mode == "udpin":
                self.sock.bind((self.endpoint.host, self.endpoint.port))
            else:
                self.peer = (socket.gethostbyname(self.endpoint.host), self.endpoint.port)
                self.sock.bind(("127.0.0.1" if self.peer[0].startswith("127.") else "0.0.0.0", 0))
        except OSError as e:
            self.sock.close()
            raise LinkError(f"{self.endpoint.url}: cannot open ({e.strerror or e})") from None
        self.sock.setblocking(False)
        self._readable = select.poll()
        self._readable.register(self.sock, select.POLLIN)

    @property
    def local_port(self) -> int:
        return self.sock.getsockname()[1]

    def fileno(self) -> int:
        return self.sock.fileno()

    def write(self, packet: bytes) -> None:
        """Called by the protocol object with each packed packet (collected inside `send_all`)."""
        if self._batch is not None:
            self._batch.append(bytes(packet))
        else:
            self.send_datagram([packet])

    def send_datagram(self, packets: list[bytes]) -> None:
        """Put packed packets on the wire as one datagram (a subclass may impair the wire:
        sitl/links/emulation.py)."""
        if self.peer is None:
            return
        try:
            self.sock.sendto(b"".join(packets), self.peer)
        except OSError:
            return           # no listener (yet) or a full buffer: UDP drops, as on a radio
        if self.tlog is not None:
            self.tlog.record_all(packets)

    def send_all(self, msgs) -> None:
        """Send several messages in as few datagrams as fit in `DATAGRAM_PAYLOAD_MAX` bytes (as
        PX4 does; every MAVLink parser reads several packets from one datagram)."""
        self._batch = []
        try:
            for msg in msgs:
                self.mav.send(msg)
        finally:
            batch, self._batch = self._batch, None
        datagram: list[bytes] = []
        for packet in batch:
            if datagram and sum(map(len, datagram)) + len(packet) > DATAGRAM_PAYLOAD_MAX:
                self.send_datagram(datagram)
                datagram = []
            datagram.append(packet)
        if datagram:
            self.send_datagram(datagram)

    def receive_from(self, max_datagrams: int | None = None
                     ) -> list[tuple[tuple[str, int], list[mavlink.MAVLink_message]]]:
        """Like `receive()`, with each datagram's sender: [(address, its messages), ...]; at most
        `max_datagrams` datagrams (None: all that have arrived), the rest stays queued. After a
        datagram, whether another waits is asked without reading (a read that finds nothing
        raises, and costs several times as much)."""
        out = []
        while max_datagrams is None or len(out) < max_datagrams:
            datagram = self.read_datagram()
            if datagram is None:
                return out
            out.append((datagram[1], self.ingest(*datagram)))
            if not self._readable.poll(0):
                return out
        return out

    def read_datagram(self) -> tuple[bytes, tuple[str, int]] | None:
        """The next datagram off the wire and its sender, unparsed (None: nothing waiting)."""
        while True:
            try:
                return self.sock.recvfrom(_DATAGRAM_MAX)
            except (BlockingIOError, InterruptedError):
                return None
            except OSError:
                continue

    def ingest(self, data: bytes, sender: tuple[str, int]) -> list[mavlink.MAVLink_message]:
        """The messages of one datagram from `sender` (what `receive()` does with each)."""
        others = self.locked_peer is not None and sender != self.locked_peer
        if others and not self.hear_others:
            self.foreign_datagrams += 1
            self.refused(sender, data, OTHER_ADDRESS)
            return []
        out = self.parse(data, sender)
        self.bad_packets += drop_cut_frame(self.mav)
        if self.endpoint.mode == "udpin" and not others and any(map(self.peer_filter, out)):
            self.peer = sender
        return out

    def lock_peer(self, address: tuple[str, int] | None, hear_others: bool = False) -> None:
        """From now on only `address` is answered (None: anyone again) and heard (with
        hear_others, the others too, for the caller to judge; they never redirect the replies)."""
        self.locked_peer = address
        self.hear_others = hear_others
        if address is not None and self.endpoint.mode == "udpin":
            self.peer = address

    def close(self) -> None:
        self.sock.close()


def parse_bytes(mav: mavlink.MAVLink, data: bytes, tlog: TlogWriter | None) -> tuple[list, list]:
    """(good messages, BAD_DATA of each rejected or garbled packet) in `data`; everything to the
    tlog, when there is one (the packets are gathered only for it)."""
    out, bad = [], []
    packets = [] if tlog is not None else None
    for msg in read_datagram(mav, data):
        refused = msg.get_type() == "BAD_DATA"
        (bad if refused else out).append(msg)
        if packets is not None:
            packets.append(bytes(msg.data) if refused else msg.get_msgbuf())
    if tlog is not None and packets:        # the datagram's packets at one time, as sent (TlogWriter.record_all)
        tlog.record_all(packets)
    return out, bad


def claimed_ids(packet: bytes) -> tuple[int, int] | None:
    """(system, component) a MAVLink 2 or 1 frame's header claims (None: too short to say)."""
    if len(packet) >= 7 and packet[0] == mavlink.PROTOCOL_MARKER_V2:
        return packet[5], packet[6]
    if len(packet) >= 5 and packet[0] == mavlink.PROTOCOL_MARKER_V1:
        return packet[3], packet[4]
    return None


def drop_cut_frame(mav: mavlink.MAVLink) -> int:
    """Forget a frame the datagram just parsed cut short (1: there was one, 0: none). Over UDP a
    datagram holds whole frames (every autopilot and router sends them so); kept, a cut frame
    would swallow the next datagrams as its missing bytes, so two bytes from anyone on the
    network (a MAVLink 2 start and a length of 255) silenced the link for the next ~270 bytes,
    before any signature could be checked."""
    if mav.buf_len() == 0:
        return 0
    mav.buf, mav.buf_index = bytearray(), 0
    mav.expected_length = mavlink.HEADER_LEN_V1 + 2        # what a new parser expects first
    return 1


def wait_readable(links, timeout_s: float) -> bool:
    """Block until one of `links` has data or `timeout_s` passes; True if data is waiting.
    A link with no socket yet (a TCP client between connections: fileno() < 0) is not
    waited on; with none left this just sleeps."""
    timeout_s = max(timeout_s, 0.0)
    waiting = [link for link in links if link.fileno() >= 0]
    if not waiting:
        time.sleep(timeout_s)
        return False
    readable, _, _ = select.select(waiting, [], [], timeout_s)
    return bool(readable)
