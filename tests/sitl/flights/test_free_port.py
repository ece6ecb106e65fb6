"""The flight runner's port pick: free, and out of the range the kernel hands sockets bound to port 0."""

from __future__ import annotations

import socket

import pytest

from sitl.flights import flight_run
from sitl.flights.flight_run import FlightError, free_port


@pytest.mark.parametrize("kind", [socket.SOCK_DGRAM, socket.SOCK_STREAM])
def test_a_picked_port_is_free_and_outside_the_kernels_ephemeral_range(kind):
    start, end = flight_run.ephemeral_port_range()
    for _ in range(20):
        port = free_port(kind)
        assert port >= flight_run.LOWEST_PICKED_PORT and not start <= port <= end
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(("127.0.0.1", port))


def test_the_ephemeral_range_is_read_from_the_kernel():
    with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
        assert flight_run.ephemeral_port_range() == tuple(int(word) for word in f.read().split())


def test_a_range_reaching_below_the_lowest_pick_leaves_the_ports_above_it(monkeypatch):
    monkeypatch.setattr(flight_run, "ephemeral_port_range", lambda: (1024, 60999))
    assert flight_run.pickable_ports() == list(range(61000, 65536))
    assert all(free_port() >= 61000 for _ in range(20))


def test_a_range_covering_every_port_is_named(monkeypatch):
    monkeypatch.setattr(flight_run, "ephemeral_port_range", lambda: (1024, 65535))
    with pytest.raises(FlightError, match="the kernel's ephemeral range 1024-65535 covers every port from 10000 up"):
        free_port()


def test_no_free_port_left_to_pick_is_one_line(monkeypatch):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        monkeypatch.setattr(flight_run, "LOWEST_PICKED_PORT", port)
        monkeypatch.setattr(flight_run, "ephemeral_port_range", lambda: (port + 1, 65535))
        with pytest.raises(FlightError, match=f"no free port on 127.0.0.1 from {port} up outside"):
            free_port()
