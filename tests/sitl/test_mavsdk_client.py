"""A real third-party client, MAVSDK-Python, sees `m4-sitl serve --realtime` as an autopilot
and commands it as a ground station (issue 22), on the FC's second link: attitude, position
around home, arming, a motor failure injected with the standard command, and, while a
companion flies on the first link, its hold and land buttons."""

from __future__ import annotations

import asyncio

import pytest
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.failure import FailureAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.failure import FailureType, FailureUnit

from m4.fc_mode import FcMode
from m4.mavlink import mavlink
from m4.scenario import Scenario
from sitl.fc.telemetry import Home
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served
from support.loopback import free_udp_port, mavsdk_ground_station

pytestmark = pytest.mark.flight
m = mavlink
MAVSDK = (245, 190)          # MAVSDK's ids as a ground station


async def _first(subscription, timeout_s=10.0):
    async def first():
        async for value in subscription:
            return value
    return await asyncio.wait_for(first(), timeout_s)


def _with_mavsdk(companion: StandInCompanion, port: int):
    """`m4-sitl serve --realtime` (its server, in this process): the companion's link, then MAVSDK's."""
    options = ServeOptions(scenario=Scenario(name="hover", duration_s=120.0), realtime=True)
    return served(companion, options, more_urls=(f"udpout:127.0.0.1:{port}",))


async def _look_arm_and_fail_rotor_2(port: int):
    async with mavsdk_ground_station(port, timeout_s=30.0) as system:
        telemetry = TelemetryAsync(system)
        attitude = await _first(telemetry.subscribe_attitude_euler())
        position = await _first(telemetry.subscribe_position())
        await ActionAsync(system).arm()                                         # raises unless ACCEPTED
        await FailureAsync(system).inject(FailureUnit.SYSTEM_MOTOR, FailureType.OFF, 2)
        return attitude, position


def test_mavsdk_as_a_ground_station_arms_and_injects_a_motor_failure():
    port = free_udp_port()
    silent = StandInCompanion(until_ms=0)                # no setpoints: the FC holds on its own
    with _with_mavsdk(silent, port) as server:
        attitude, position = asyncio.run(_look_arm_and_fail_rotor_2(port))
        stopped = silent.wait_for("ESC_TELEMETRY_1_TO_4", lambda e: e.rpm[1] == 0, timeout_s=20.0)  # its motor lag
        acked = server.vehicle.fc.counters.commands_acked
        refused = server.vehicle.fc.counters.commands_refused
    home = Home()
    assert abs(attitude.roll_deg) < 5.0 and abs(attitude.pitch_deg) < 5.0
    assert position.latitude_deg == pytest.approx(home.lat_deg, abs=1e-5)
    assert position.longitude_deg == pytest.approx(home.lon_deg, abs=1e-5)
    assert position.relative_altitude_m == pytest.approx(2.0, abs=0.3)
    assert stopped is not None and acked >= 2 and refused == 0


async def _hold_then_land(port: int):
    async with mavsdk_ground_station(port, timeout_s=30.0) as system:
        action = ActionAsync(system)
        await action.hold()               # DO_SET_MODE as PX4's AUTO.LOITER; raises unless ACCEPTED
        await asyncio.sleep(0.3)
        await action.land()               # MAV_CMD_NAV_LAND


def test_mavsdk_holds_and_lands_while_a_companion_flies():
    port = free_udp_port()
    companion = StandInCompanion()
    with _with_mavsdk(companion, port) as server:
        asyncio.run(_hold_then_land(port))
        fc = server.vehicle.fc
        told = companion.wait_for("CURRENT_MODE", lambda c: c.intended_custom_mode == FcMode.LAND, timeout_s=5.0)
        mode, selected = fc.mode, fc.selected
    held = [c for c in companion.of_type("CURRENT_MODE") if c.intended_custom_mode == FcMode.HOLD]
    assert held and held[0].custom_mode == FcMode.HOLD        # flown by the companion: it was flying
    assert told is not None and (mode, selected) == (FcMode.LAND, FcMode.LAND)
