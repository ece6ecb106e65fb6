"""A real third-party client, MAVSDK-Python, sees `m4-sitl serve --realtime` as an autopilot:
attitude, position around home, and a motor failure injected with the standard command."""

from __future__ import annotations

import asyncio
import subprocess
import sys

import pytest
from mavsdk.asyncio.plugins.failure import FailureAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.failure import FailureType, FailureUnit

from m4.mavlink import mavutil
from sitl.fc.telemetry import Home
from support.loopback import free_udp_port, mavsdk_ground_station

pytestmark = pytest.mark.flight


async def _first(subscription, timeout_s=10.0):
    async def first():
        async for value in subscription:
            return value
    return await asyncio.wait_for(first(), timeout_s)


async def _fly_with_mavsdk(port: int):
    async with mavsdk_ground_station(port, timeout_s=15.0) as system:
        telemetry = TelemetryAsync(system)
        attitude = await _first(telemetry.subscribe_attitude_euler())
        position = await _first(telemetry.subscribe_position())
        failure = FailureAsync(system)
        await failure.inject(FailureUnit.SYSTEM_MOTOR, FailureType.OFF, 4)     # raises unless ACCEPTED
        await asyncio.sleep(0.5)          # the rotor spins down through its motor lag
        return attitude, position


def test_mavsdk_sees_an_autopilot_and_injects_a_motor_failure(tmp_path):
    port = free_udp_port()
    tlog = tmp_path / "mavsdk.tlog"
    server = subprocess.Popen([sys.executable, "-m", "sitl.cli", "serve", "--realtime", "--duration", "30",
                               "--mavlink", f"udpout:127.0.0.1:{port}", "--tlog", str(tlog),
                               "--companion", "245:190"],            # MAVSDK as a ground station
                              stderr=subprocess.PIPE, text=True)
    try:
        attitude, position = asyncio.run(_fly_with_mavsdk(port))
    finally:
        server.terminate()
        _, stderr = server.communicate(timeout=10)
    assert server.returncode == 0, stderr
    home = Home()
    assert abs(attitude.roll_deg) < 5.0 and abs(attitude.pitch_deg) < 5.0
    assert position.latitude_deg == pytest.approx(home.lat_deg, abs=1e-5)
    assert position.longitude_deg == pytest.approx(home.lon_deg, abs=1e-5)
    assert position.relative_altitude_m == pytest.approx(2.0, abs=0.3)
    log = mavutil.mavlink_connection(str(tlog))
    acks, motor_off = [], None
    while (msg := log.recv_match(blocking=False)) is not None:
        if msg.get_type() == "COMMAND_ACK" and msg.command == 420:
            acks.append(msg.result)
        if msg.get_type() == "ESC_TELEMETRY_1_TO_4" and acks:
            motor_off = motor_off or msg.rpm[3] == 0
    assert acks and set(acks) == {0} and motor_off, "the failure was acknowledged but rotor 4 still turns"
