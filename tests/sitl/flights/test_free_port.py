"""The flight runner's port pick: free, and out of the range the kernel hands sockets bound to port 0."""

from __future__ import annotations

import socket

import pytest

from sitl.flights import flight_run
from sitl.flights.flight_run import FlightError, free_port


@pytest.mark.parametrize("kind", [socket.SOCK_DGRAM, socket.SOCK_STREAM])
def test_a_picked_port_is_free_and_below_the_kernels_ephemeral_range(kind):
    start = flight_run._ephemeral_ports_start()
    for _ in range(20):
        port = free_port(kind)
        assert flight_run.LOWEST_PICKED_PORT <= port < start
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(("127.0.0.1", port))


def test_the_ephemeral_range_is_read_from_the_kernel():
    with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
        assert flight_run._ephemeral_ports_start() == max(int(f.read().split()[0]),
                                                          flight_run.LOWEST_PICKED_PORT + 1000)


def test_no_free_port_left_to_pick_is_one_line(monkeypatch):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        monkeypatch.setattr(flight_run, "LOWEST_PICKED_PORT", port)
        monkeypatch.setattr(flight_run, "_ephemeral_ports_start", lambda: port + 1)
        with pytest.raises(FlightError, match=f"no free port on 127.0.0.1 between {port} and {port}"):
            free_port()
