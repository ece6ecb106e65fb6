"""Parameters from a ground station, with real tools over loopback: the real companion
(m4-companion run) behind `m4-sitl serve --realtime`, a ground station on the FC's second
link. pymavlink lists, reads and sets the companion's parameters (component 191, reached
through the FC's routing) and is told why a set is refused; MAVSDK's param plugin gets and sets
the FC's and the companion's."""

from __future__ import annotations

import asyncio
import os
import select
import subprocess
import sys
import threading
import pytest
from mavsdk.asyncio import Configuration, Mavsdk
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.component_type import ComponentType
from mavsdk.plugins.param import ParamError, ParamResult, ProtocolVersion

from m4.mavlink import mavlink
from m4.scenario import Scenario
from sitl.flights.flight_run import free_port
from sitl.serve import ServeOptions, Server
from support.ground_station import GroundStation

pytestmark = pytest.mark.flight
COMPANION = 191


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """The companion (its configuration in a folder of its own) flying the SITL in real time,
    a pymavlink ground station and a port for MAVSDK on the FC's other links."""
    folder = tmp_path_factory.mktemp("companion")
    port, mavsdk_port = free_port(), free_port()
    config = folder / "companion.toml"
    config.write_text(f'[link]\nfc_url = "udpin:127.0.0.1:{port}"\nsigning = false\n')
    read_end, write_end = os.pipe()
    with (folder / "companion.log").open("w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(config),
                                 "--ready-fd", str(write_end)], stdout=subprocess.DEVNULL, stderr=log,
                                stdin=subprocess.DEVNULL, pass_fds=(write_end,))
    os.close(write_end)
    with os.fdopen(read_end) as ready:
        assert (ready.readline() if select.select([ready], [], [], 120.0)[0] else "").startswith("ready:")
    gcs = GroundStation()
    server = Server(ServeOptions(scenario=Scenario(name="hover", duration_s=3600.0), realtime=True,
                                 mavlink_urls=(f"udpout:127.0.0.1:{port}", gcs.url,
                                               f"udpout:127.0.0.1:{mavsdk_port}")))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        gcs.wait("HEARTBEAT", lambda m: m.get_srcComponent() == COMPANION)       # routed by the FC
        yield gcs, folder, mavsdk_port
    finally:
        server.stop()
        thread.join()
        server.close()
        gcs.close()
        proc.terminate()
        proc.wait(timeout=10)


def test_the_companion_lists_its_parameters_to_a_ground_station_through_the_fc(rig):
    gcs, _, _ = rig
    mine = gcs.ask(mavlink.MAVLink_param_request_list_message(1, COMPANION), "PARAM_VALUE",
                   lambda m: m.get_srcComponent() == COMPANION)
    count = mine[0].param_count
    mine = gcs.wait("PARAM_VALUE", lambda m: m.get_srcComponent() == COMPANION, count)
    assert sorted(m.param_index for m in mine) == list(range(count))
    assert not [m for m in gcs.heard if m.get_type() == "PARAM_VALUE" and m.get_srcComponent() == 1]
    values = {m.param_id: m.param_value for m in mine}
    assert values["NMPC_HORIZON"] == 5 and values["DET_CHI2_MIN"] == 25.0
    gcs.ask(mavlink.MAVLink_param_request_list_message(1, 0), "PARAM_VALUE",          # every component of system 1
            lambda m: m.get_srcComponent() == COMPANION, count)
    fc = gcs.wait("PARAM_VALUE", lambda m: m.get_srcComponent() == 1)
    assert fc[0].param_count >= 20


def test_a_settable_companion_parameter_is_set_and_kept_beside_its_configuration(rig):
    gcs, folder, _ = rig
    answer = gcs.ask(mavlink.MAVLink_param_set_message(1, COMPANION, b"DET_CONFIRM", 0.15,
                                                       mavlink.MAV_PARAM_TYPE_REAL32),
                     "PARAM_VALUE", lambda m: m.param_id == "DET_CONFIRM")[0]
    assert answer.get_srcComponent() == COMPANION and answer.param_value == pytest.approx(0.15)
    read = gcs.ask(mavlink.MAVLink_param_request_read_message(1, COMPANION, b"DET_CONFIRM", -1), "PARAM_VALUE")[0]
    assert read.param_value == pytest.approx(0.15)
    assert "DET_CONFIRM = 0.15\n" in (folder / "companion.params.toml").read_text()


def test_a_read_only_companion_parameter_is_refused_with_the_reason(rig):
    gcs, _, _ = rig
    answer = gcs.ask(mavlink.MAVLink_param_set_message(1, COMPANION, b"NMPC_HORIZON", 8, mavlink.MAV_PARAM_TYPE_INT32),
                     "PARAM_VALUE", lambda m: m.param_id == "NMPC_HORIZON")[0]
    assert answer.param_value == 5
    text = gcs.wait("STATUSTEXT", lambda m: "refused" in m.text)[0]
    assert text.get_srcComponent() == COMPANION and text.text == "companion: NMPC_HORIZON refused: read-only"


async def _with_mavsdk(port: int):
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await mavsdk.first_autopilot(timeout_s=15.0)
        fc = ParamAsync(system)
        before = await fc.get_param_float("FS_LAND_DELAY")
        await fc.set_param_float("FS_LAND_DELAY", 3.5)                   # raises unless answered with it
        after = await fc.get_param_float("FS_LAND_DELAY")
        companion = ParamAsync(system)
        try:
            await companion.select_component(COMPANION, ProtocolVersion.V1)
        except ParamError as e:          # MAVSDK-Python 4.1 says UNKNOWN whatever it is given, yet selects
            assert e.result == ParamResult.UNKNOWN
        chi2 = await companion.get_param_float("DET_CHI2_MIN")
        await companion.set_param_float("DET_CHI2_MIN", 30.0)
        return before, after, chi2, await companion.get_param_float("DET_CHI2_MIN")


def test_mavsdk_gets_and_sets_the_fcs_and_the_companions_parameters(rig):
    _, folder, port = rig
    before, after, chi2, chi2_after = asyncio.run(_with_mavsdk(port))
    assert (before, after) == (2.0, 3.5)
    assert (chi2, chi2_after) == (25.0, 30.0)
    assert "DET_CHI2_MIN = 30.0\n" in (folder / "companion.params.toml").read_text()
