"""UDP links: URLs, port in use, and tlogs of both directions readable by pymavlink."""

from __future__ import annotations

import socket
import time

import pytest

from m4.mavlink import mavlink, mavutil
from m4.mavlink.link import DATAGRAM_PAYLOAD_MAX, LinkError, UdpLink, parse_url, wait_readable
from m4.mavlink.tlog import TLOG_TIME, TlogWriter
from tests.support.packets import packed


@pytest.mark.parametrize("url", ["", "udp:127.0.0.1:5", "udpin:127.0.0.1", "udpin:127.0.0.1:x",
                                 "tcp:127.0.0.1:5760", "udpout:127.0.0.1:0", "udpin:127.0.0.1:70000"])
def test_bad_url_is_rejected_with_the_expected_form(url):
    with pytest.raises(LinkError, match="HOST:PORT"):
        parse_url(url)


def test_url_forms():
    assert parse_url("udpin:127.0.0.1:14550").port == 14550
    assert parse_url("udpout://localhost:5").host == "localhost"


def test_port_in_use_is_a_link_error():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        with pytest.raises(LinkError, match=f"udpin:127.0.0.1:{port}: cannot open"):
            UdpLink(f"udpin:127.0.0.1:{port}", 1, 1)


def _receive(link, n, timeout_s=2.0):
    got, deadline = [], time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        wait_readable([link], 0.05)
        got += link.receive()
    return got


def test_tlog_holds_both_directions_and_pymavlink_reads_it(tmp_path):
    path = tmp_path / "flight.tlog"
    with TlogWriter(path) as tlog:
        fc = UdpLink("udpin:127.0.0.1:0", 1, 1, tlog=tlog)
        companion = UdpLink(f"udpout:127.0.0.1:{fc.local_port}", 1, 191)
        companion.send(mavlink.MAVLink_m4_setpoint_message(1, 1, 0, 20, [14.7] * 4, [0.78] * 4, [0.0] * 4, 0))
        assert [m.get_type() for m in _receive(fc, 1)] == ["M4_SETPOINT"]
        fc.send(mavlink.MAVLink_attitude_message(20, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))
        assert [m.get_type() for m in _receive(companion, 1)] == ["ATTITUDE"]
        fc.close()
        companion.close()
    log = mavutil.mavlink_connection(str(path))
    msgs = []
    while (msg := log.recv_match(blocking=False)) is not None:
        msgs.append(msg)
    assert [(m.get_type(), m.get_srcComponent()) for m in msgs] == [("M4_SETPOINT", 191), ("ATTITUDE", 1)]
    assert msgs[0]._timestamp <= msgs[1]._timestamp
    assert abs(msgs[0]._timestamp - time.time()) < 60.0


def test_a_datagrams_packets_go_to_the_tlog_at_one_time(tmp_path, monkeypatch):
    """The packets sent in one datagram are recorded together: one clock read and one write (the
    SITL sends its frame of seven messages as one datagram every control step)."""
    import m4.mavlink.tlog as tlog_module

    clock = iter(range(10**9, 2 * 10**9, 10**6))          # a clock that moves 1 ms at every read
    monkeypatch.setattr(tlog_module.time, "time_ns", lambda: next(clock))
    path = tmp_path / "sent.tlog"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx, TlogWriter(path) as tlog:
        rx.bind(("127.0.0.1", 0))
        link = UdpLink(f"udpout:127.0.0.1:{rx.getsockname()[1]}", 1, 1, tlog=tlog)
        link.send_all([mavlink.MAVLink_attitude_message(t, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6) for t in range(3)])
        link.close()
        assert tlog.records == 3
    log = mavutil.mavlink_connection(str(path))
    msgs = []
    while (msg := log.recv_match(blocking=False)) is not None:
        msgs.append(msg)
    assert [m.time_boot_ms for m in msgs] == [0, 1, 2]
    assert len({m._timestamp for m in msgs}) == 1


def test_every_packet_received_goes_to_the_tlog_refused_ones_too(tmp_path):
    """A datagram's packets are recorded as they arrived, in order: the good ones and the ones
    signing refused (a tlog is where a refused packet is looked at afterwards)."""
    key, attitude = bytes(range(32)), mavlink.MAVLink_attitude_message(20, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
    good, forged = packed([attitude], key=key)[0], packed([attitude], key=bytes(32))[0]
    path = tmp_path / "received.tlog"
    with TlogWriter(path) as tlog, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        link = UdpLink("udpin:127.0.0.1:0", 1, 191, tlog=tlog, key=key)
        tx.sendto(good + forged, ("127.0.0.1", link.local_port))
        assert [m.get_type() for m in _receive(link, 1)] == ["ATTITUDE"] and link.bad_packets == 1
        link.close()
    data, records = path.read_bytes(), []
    while data:
        records.append(data[TLOG_TIME.size:TLOG_TIME.size + len(good)])
        data = data[TLOG_TIME.size + len(good):]
    assert records == [good, forged]


def test_without_a_tlog_no_packet_is_gathered_for_one(monkeypatch):
    """The packets of a datagram are gathered only for a tlog: a link without one never asks
    a message for its buffer."""
    asked = []
    monkeypatch.setattr(mavlink.MAVLink_message, "get_msgbuf", lambda msg: asked.append(msg))
    attitude = mavlink.MAVLink_attitude_message(20, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        link = UdpLink("udpin:127.0.0.1:0", 1, 191)
        tx.sendto(b"".join(packed([attitude] * 3)), ("127.0.0.1", link.local_port))
        assert [m.get_type() for m in _receive(link, 3)] == ["ATTITUDE"] * 3
        link.close()
    assert asked == []


def test_send_all_packs_messages_into_datagrams_below_the_mtu():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(2.0)
        link = UdpLink(f"udpout:127.0.0.1:{rx.getsockname()[1]}", 1, 1)
        link.send_all([mavlink.MAVLink_attitude_message(t, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6) for t in range(100)])
        link.close()
        parser, datagrams, got = mavlink.MAVLink(None), [], []
        while len(got) < 100:
            datagrams.append(rx.recv(65535))
            got += parser.parse_buffer(datagrams[-1]) or []
    assert [m.time_boot_ms for m in got] == list(range(100))
    assert 1 < len(datagrams) < 100 and max(map(len, datagrams)) <= DATAGRAM_PAYLOAD_MAX


def test_a_frame_cut_short_by_its_datagram_does_not_swallow_the_next_ones():
    """Two bytes from a stranger (a MAVLink 2 start, length 255) used to make the parser wait
    for 267 bytes and eat the FC's next datagrams; a datagram holds whole frames."""
    fc = UdpLink("udpin:127.0.0.1:0", 1, 1)
    companion = UdpLink(f"udpout:127.0.0.1:{fc.local_port}", 1, 191)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
        stranger.sendto(bytes([mavlink.PROTOCOL_MARKER_V2, 255]), ("127.0.0.1", fc.local_port))
        assert _receive(fc, 1, timeout_s=0.3) == []
        for t in (20, 40):
            companion.send(mavlink.MAVLink_attitude_message(t, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))
        got = _receive(fc, 2)
    fc.close()
    companion.close()
    assert [m.time_boot_ms for m in got] == [20, 40]
    assert fc.bad_packets == 1


class _CountingReads:
    """A socket whose reads are counted."""

    def __init__(self, sock: socket.socket):
        self.sock, self.reads = sock, 0

    def recvfrom(self, size: int):
        self.reads += 1
        return self.sock.recvfrom(size)

    def __getattr__(self, name: str):
        return getattr(self.sock, name)


def test_receiving_reads_each_waiting_datagram_and_no_more():
    """A read that finds nothing raises, at several times a read's cost: after the last datagram
    the link asks whether another waits instead of reading."""
    fc = UdpLink("udpin:127.0.0.1:0", 1, 1)
    companion = UdpLink(f"udpout:127.0.0.1:{fc.local_port}", 1, 191)
    for t in (20, 40):
        companion.send(mavlink.MAVLink_attitude_message(t, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))
    assert wait_readable([fc], 2.0)
    fc.sock = counting = _CountingReads(fc.sock)
    got = fc.receive_from()
    assert [m.time_boot_ms for _, msgs in got for m in msgs] == [20, 40] and counting.reads == 2
    assert fc.receive_from() == [] and counting.reads == 3        # nothing waits: one read finds nothing
    fc.close()
    companion.close()
