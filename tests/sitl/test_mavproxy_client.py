"""MAVProxy, a real ground station, on the FC's second link while a companion flies on the
first (issue 22): it prints the companion's fault announcement (repeated by the FC as its own:
MAVProxy prints the autopilot's texts only), names the FC's modes (ArduCopter's numbers) and
sets them with its `mode` command."""

from __future__ import annotations

import pytest

from m4.fc_mode import FcMode
from m4.mavlink import mavlink
from m4.scenario import Scenario
from sitl.flights.flight_run import free_port
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served
from tests.support.mavproxy_console import MavProxy

pytestmark = pytest.mark.flight
m = mavlink


def test_mavproxy_prints_the_fault_and_sets_the_fcs_modes(tmp_path):
    port = free_port()
    companion = StandInCompanion()
    options = ServeOptions(scenario=Scenario(name="hover", duration_s=120.0), realtime=True)
    with served(companion, options, more_urls=(f"udpout:127.0.0.1:{port}",)) as server:
        mavproxy = MavProxy(f"udpin:127.0.0.1:{port}", tmp_path)
        try:
            online = mavproxy.wait_for("online system 1", 60.0)
            companion.send(m.MAVLink_statustext_message(m.MAV_SEVERITY_CRITICAL, b"thrust loss rotor 4 (motor)"))
            printed = mavproxy.wait_for("AP: thrust loss rotor 4 (motor)", 10.0)
            mavproxy.command("mode LOITER")
            held = mavproxy.wait_for("AP: FC HOLD: the companion holds", 10.0)
            named = mavproxy.wait_for("LOITER>", 30.0)          # its prompt, from the next HEARTBEAT
            selected_hold = server.vehicle.fc.selected
            mavproxy.command("mode LAND")
            landing = mavproxy.wait_for("AP: FC LAND: the companion lands", 10.0)
            selected_land = server.vehicle.fc.selected
        finally:
            out = mavproxy.close()
    assert online and printed, out
    assert held and landing and (selected_hold, selected_land) == (FcMode.HOLD, FcMode.LAND), out
    assert "GUIDED>" in out and named, out
