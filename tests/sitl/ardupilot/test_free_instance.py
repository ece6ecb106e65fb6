"""The arducopter instance a test or benchmark flight picks: one whose ports are all free."""

from __future__ import annotations

import socket

import pytest

from sitl.ardupilot import flight
from sitl.ardupilot.flight import free_instance


def test_an_instance_with_a_port_taken_is_passed_over():
    taken = free_instance()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as physics:
        physics.bind(("127.0.0.1", 9002 + 10 * taken))          # its JSON physics port, taken
        assert all(free_instance() != taken for _ in range(50))


def test_no_instance_free_is_named(monkeypatch):
    monkeypatch.setattr(flight, "_port_free", lambda kind, port: False)
    with pytest.raises(flight.FlightError, match=r"^no arducopter instance 1\.\.99 has its ports free on 127\.0\.0\.1$"):
        free_instance()
