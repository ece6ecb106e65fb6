"""A real ground-station library, MAVSDK-Python's mission_raw plugin, plans a mission against
`m4-sitl serve --realtime` over loopback: the docs' example mission file (docs/missions.md)
imported, uploaded and downloaded back item for item; an unsupported item refused; the mission
cleared."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

import pytest
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
from mavsdk.plugins.mission_raw import MissionItem, MissionRawError, MissionRawResult

from m4.mavlink import mavlink
from support.loopback import free_udp_port, mavsdk_ground_station

pytestmark = pytest.mark.flight

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "mission.waypoints"


def _fields(item) -> tuple:
    return (item.seq, item.frame, item.command, item.param1, item.param2, item.x, item.y, item.z)


async def _plan_with_mavsdk(port: int):
    async with mavsdk_ground_station(port, timeout_s=60.0) as system:
        mission = MissionRawAsync(system)
        planned = (await mission.import_mission_planner_mission_from_string(EXAMPLE.read_text())).mission_items
        await mission.upload_mission(planned)
        downloaded = await mission.download_mission()
        loiter = MissionItem(1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink.MAV_CMD_NAV_LOITER_UNLIM, 0, 1,
                             0.0, 0.0, 0.0, 0.0, 0, 0, 2.0, mavlink.MAV_MISSION_TYPE_MISSION)
        with pytest.raises(MissionRawError) as refused:
            await mission.upload_mission([planned[0], loiter])
        kept = await mission.download_mission()
        await mission.clear_mission()
        cleared = await mission.download_mission()
        return planned, downloaded, refused.value.result, kept, cleared


def test_mavsdk_uploads_the_example_mission_downloads_it_and_is_refused_an_unsupported_item():
    port = free_udp_port()
    server = subprocess.Popen([sys.executable, "-m", "sitl.cli", "serve", "--realtime", "--duration", "120",
                               "--mavlink", f"udpout:127.0.0.1:{port}"], stderr=subprocess.PIPE, text=True)
    try:
        planned, downloaded, refused, kept, cleared = asyncio.run(asyncio.wait_for(_plan_with_mavsdk(port), 110))
    finally:
        server.terminate()
        server.communicate(timeout=30)
    assert [item.command for item in planned] == [16, 16, 178, 16, 21]
    assert [_fields(item) for item in downloaded[1:]] == [_fields(item) for item in planned[1:]]
    assert downloaded[0].command == mavlink.MAV_CMD_NAV_WAYPOINT and downloaded[0].seq == 0    # the FC's home
    assert refused == MissionRawResult.UNSUPPORTED
    assert [_fields(item) for item in kept] == [_fields(item) for item in downloaded]     # the mission before stays
    assert len(cleared) == 1                                                                   # home alone
