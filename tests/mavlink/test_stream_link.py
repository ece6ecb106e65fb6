"""MAVLink over TCP (client and one-peer server) and a serial port (a pseudo-terminal here),
behind the same interface as the UDP link; URLs from pymavlink's forms."""

from __future__ import annotations

import os
import socket
import time

import pytest

from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink, new_mav
from m4.mavlink.connect import listens_for_peer, open_link
from m4.mavlink.link import LinkError, UdpLink


def packed(*msgs) -> bytes:
    mav = new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID)
    return b"".join(m.pack(mav) for m in msgs)


def heartbeat():
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, 0, 0, 0, 4, 3)


def position(t_ms):
    return mavlink.MAVLink_local_position_ned_message(t_ms, 1.0, 2.0, -3.0, 0.0, 0.0, 0.0)


def receive(link, want: int, timeout_s: float = 2.0) -> list:
    got, deadline = [], time.monotonic() + timeout_s
    while len(got) < want and time.monotonic() < deadline:
        got += link.receive()
        time.sleep(0.005)
    return got


def parse_all(read, timeout_s: float = 2.0) -> list:
    """Messages parsed from what `read()` returns until one message came or timeout_s passed."""
    parser, got, deadline = new_mav(None, 255, 0), [], time.monotonic() + timeout_s
    while not got and time.monotonic() < deadline:
        got += parser.parse_buffer(read()) or []
    return got


def _recv(sock):
    sock.settimeout(0.1)
    try:
        return sock.recv(4096)
    except TimeoutError:
        return b""


@pytest.mark.parametrize("url", ["udpin:127.0.0.1:0", "udp:127.0.0.1:0"])
def test_udp_urls_open_a_udp_link(url):
    link = open_link(url, FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    try:
        assert isinstance(link, UdpLink) and link.endpoint.mode == "udpin"
    finally:
        link.close()


@pytest.mark.parametrize("url", ["tcp:127.0.0.1", "tcpx:127.0.0.1:5760", "serial:/dev/ttyS0", "/dev/", "nothing"])
def test_bad_urls_are_rejected_naming_the_forms(url):
    with pytest.raises(LinkError, match="HOST:PORT"):
        open_link(url, FC_SYSTEM_ID, COMPANION_COMPONENT_ID)


def test_a_missing_serial_device_or_a_refused_tcp_server_is_one_clear_error():
    with pytest.raises(LinkError, match="/dev/m4-no-such-port"):
        open_link("/dev/m4-no-such-port,921600", FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]          # bound, not listening: connections are refused
        with pytest.raises(LinkError, match=f"tcp:127.0.0.1:{port}: cannot open"):
            open_link(f"tcp:127.0.0.1:{port}", FC_SYSTEM_ID, COMPANION_COMPONENT_ID)


def test_tcp_server_hears_its_peer_answers_it_and_refuses_a_second_one_once_locked():
    link = open_link("tcpin:127.0.0.1:0", FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    fc = socket.create_connection(("127.0.0.1", link.local_port))
    stray = None
    try:
        data = packed(heartbeat(), position(20))
        fc.sendall(data[:7])                # a frame split across reads
        time.sleep(0.05)
        link.receive()
        fc.sendall(data[7:])
        assert [m.get_type() for m in receive(link, 2)] == ["HEARTBEAT", "LOCAL_POSITION_NED"]
        link.lock_peer(fc.getsockname())
        stray = socket.create_connection(("127.0.0.1", link.local_port))
        stray.sendall(packed(position(40)))
        time.sleep(0.05)
        assert link.receive() == [] and link.foreign_datagrams == 1
        link.send(mavlink.MAVLink_m4_setpoint_message(1, 1, 20, 20, [1.0] * 4, [0.5] * 4, [0.0] * 4, 0))
        assert [m.get_type() for m in parse_all(lambda: _recv(fc))] == ["M4_SETPOINT"]
    finally:
        for s in (fc, stray):
            if s is not None:
                s.close()
        link.close()


def test_tcp_client_talks_to_a_listening_flight_controller():
    with socket.create_server(("127.0.0.1", 0)) as server:
        link = open_link(f"tcp:127.0.0.1:{server.getsockname()[1]}", FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
        conn, _ = server.accept()
        try:
            conn.sendall(packed(heartbeat()))
            assert [m.get_type() for m in receive(link, 1)] == ["HEARTBEAT"]
            link.send(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, b"hello"))
            got = parse_all(lambda: _recv(conn))
            assert [(m.get_type(), m.get_srcComponent()) for m in got] == [("STATUSTEXT", COMPANION_COMPONENT_ID)]
        finally:
            conn.close()
            link.close()


def test_serial_link_over_a_pseudo_terminal():
    master, slave = os.openpty()
    link = open_link(f"{os.ttyname(slave)},921600", FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    try:
        os.write(master, packed(heartbeat(), position(20)) + b"\x00garbage\xfd\x01")
        assert [m.get_type() for m in receive(link, 2)] == ["HEARTBEAT", "LOCAL_POSITION_NED"]
        link.send(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, b"on the wire"))
        os.set_blocking(master, False)

        def read_master():
            try:
                return os.read(master, 4096)
            except BlockingIOError:
                return b""
        assert [m.get_type() for m in parse_all(read_master)] == ["STATUSTEXT"]
    finally:
        link.close()
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("url, listens", [
    ("udpin:127.0.0.1:14550", True), ("udp:127.0.0.1:14550", True), ("udpin://127.0.0.1:14550", True),
    ("udpout:127.0.0.1:14550", False), ("tcp:127.0.0.1:5760", False), ("tcpin:127.0.0.1:5760", False),
    ("/dev/ttyTHS1,921600", False),
])
def test_only_a_listening_udp_link_must_wait_for_its_peer_before_sending(url, listens):
    assert listens_for_peer(url) is listens
