"""Loopback plumbing for the end-to-end tests: a free UDP port (the flight runner's pick), the messages of a tlog, and
MAVSDK as a ground station on a port."""

from __future__ import annotations

import contextlib

from m4.mavlink import mavutil
from sitl.flights.flight_run import free_port as free_udp_port


def tlog_messages(tlog) -> list:
    """Every message of a tlog, in order (the project's dialect)."""
    conn = mavutil.mavlink_connection(str(tlog), dialect="m4")
    out = []
    while (msg := conn.recv_match()) is not None:
        out.append(msg)
    return out


@contextlib.asynccontextmanager
async def mavsdk_ground_station(port: int, timeout_s: float):
    """MAVSDK as a ground station listening on 127.0.0.1:port; yields the autopilot it finds."""
    from mavsdk.asyncio import Configuration, Mavsdk
    from mavsdk.component_type import ComponentType

    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await mavsdk.first_autopilot(timeout_s=timeout_s)
        assert system is not None, "MAVSDK saw no autopilot"
        yield system
