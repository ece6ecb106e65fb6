"""End to end: a ground station (pymavlink, here) uploads a mission to `m4-sitl serve` (lockstep,
a subprocess) by the mission protocol: two waypoints, a speed change and a landing. The
companion (this process, no mission file) downloads it and flies it; rotor 4 stops on the way
(the scenario's fault); the robot holds (the default fault policy), lands when the mission
would have, and the ground station hears the progress: MISSION_ITEM_REACHED, MISSION_CURRENT
up to COMPLETE. Everything over MAVLink 2 on 127.0.0.1; figures from the SITL's tlog."""

from __future__ import annotations

import dataclasses
import itertools
import logging
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from companion.app import close_app, open_app
from companion.config import parse_config
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink, mavutil
from support.loopback import free_udp_port, tlog_messages
from support.missions import GCS, MISSION

pytestmark = pytest.mark.flight

m = mavlink
FAULT_AT_S = 5.5                  # on the leg to the second waypoint
SCENARIO = """
name = "uploaded-mission-rotor-loss"
duration_s = 15.0
[start]
ned_m = [0.0, 0.0, -2.0]
"""


def _upload(gcs, items) -> int:
    """The mission protocol's upload as a ground station runs it; the MISSION_ACK's result."""
    gcs.mav.mission_count_send(FC_SYSTEM_ID, FC_COMPONENT_ID, len(items), m.MAV_MISSION_TYPE_MISSION)
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline:
        msg = gcs.recv_match(type=["MISSION_REQUEST_INT", "MISSION_ACK"], blocking=True, timeout=1.0)
        if msg is None or (msg.target_system, msg.target_component) != GCS:
            continue
        if msg.get_type() == "MISSION_ACK":
            return msg.type
        gcs.mav.send(items[msg.seq].message(FC_SYSTEM_ID, FC_COMPONENT_ID))
    raise AssertionError("the flight controller never acknowledged the upload")


def _inject_at(gcs, at_s: float) -> int:
    """The ground station stops rotor 4 (MAV_CMD_INJECT_FAILURE) once the FC's clock reaches
    at_s; the COMMAND_ACK's result."""
    sent, deadline = False, time.monotonic() + 240.0
    while time.monotonic() < deadline:
        msg = gcs.recv_match(type=["LOCAL_POSITION_NED", "COMMAND_ACK"], blocking=True, timeout=1.0)
        if msg is None:
            continue
        if msg.get_type() == "LOCAL_POSITION_NED" and msg.time_boot_ms >= at_s * 1000 and not sent:
            sent = True
            gcs.mav.command_long_send(FC_SYSTEM_ID, FC_COMPONENT_ID, m.MAV_CMD_INJECT_FAILURE, 0,
                                      m.FAILURE_UNIT_SYSTEM_MOTOR, m.FAILURE_TYPE_OFF, 4, 0, 0, 0, 0)
        elif msg.get_type() == "COMMAND_ACK" and msg.command == m.MAV_CMD_INJECT_FAILURE:
            return msg.result
    raise AssertionError("the flight controller never acknowledged the injected failure")


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fc-mission")
    scenario, tlog = tmp / "scenario.toml", tmp / "flight.tlog"
    scenario.write_text(SCENARIO)
    config = parse_config({"link": {"fc_url": "udpin:127.0.0.1:0", "signing": False},
                           "log": {"dir": str(tmp / "logs")}}, "test")
    app = open_app(config)
    gcs_port = free_udp_port()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", dialect="m4", source_system=GCS[0],
                                     source_component=GCS[1])
    server = subprocess.Popen([sys.executable, "-m", "sitl.cli", "serve", "--scenario", str(scenario), "--duration",
                               "15", "--tlog", str(tlog), "--mavlink", f"udpout:127.0.0.1:{app.fc.link.local_port}",
                               "--mavlink", f"udpout:127.0.0.1:{gcs_port}"], stderr=subprocess.PIPE, text=True)
    thread = threading.Thread(target=app.run, daemon=True)
    try:
        assert gcs.wait_heartbeat(timeout=30) is not None, "no HEARTBEAT from the SITL"
        result = _upload(gcs, MISSION)            # at t = 0: the SITL waits for the companion's first setpoint
        thread.start()
        injected = _inject_at(gcs, FAULT_AT_S)  # from the ground station, on the leg to the second waypoint
        announced = []
        while server.poll() is None:
            msg = gcs.recv_match(type="STATUSTEXT", blocking=True, timeout=0.5)
            if msg is not None and msg.severity <= m.MAV_SEVERITY_CRITICAL:
                announced.append((msg.get_srcComponent(), msg.text))
        _, stderr = server.communicate(timeout=300)
    finally:
        server.kill() if server.poll() is None else None
        app.stop()
        if thread.is_alive():
            thread.join(5.0)
        close_app(app)
        gcs.close()
    assert server.returncode == 0, stderr
    assert injected == m.MAV_RESULT_ACCEPTED
    return result, tlog, announced


def test_an_uploaded_mission_is_flown_through_a_failure_injected_from_the_ground_and_lands_with_progress_reported(flight):
    result, tlog, announced = flight
    assert result == m.MAV_MISSION_ACCEPTED
    assert any(src == FC_COMPONENT_ID and text.startswith("thrust loss rotor 4") for src, text in announced), \
        f"the ground station never saw the fault announced as the FC's: {announced}"
    msgs = tlog_messages(tlog)
    fc = [x for x in msgs if x.get_srcComponent() == FC_COMPONENT_ID]
    ours = [x for x in msgs if x.get_srcComponent() == COMPANION_COMPONENT_ID]
    assert any(x.get_type() == "MISSION_REQUEST_LIST" for x in ours), "the companion never downloaded the mission"
    assert [x.seq for x in ours if x.get_type() == "MISSION_SET_CURRENT"] == [1, 3, 4]
    reached = [x.seq for x in fc if x.get_type() == "MISSION_ITEM_REACHED"]
    assert [seq for seq, _ in itertools.groupby(reached)] == [1, 3, 4]       # the tlog has each once per link
    current = [x for x in fc if x.get_type() == "MISSION_CURRENT"]
    assert current[-1].mission_state == m.MISSION_STATE_COMPLETE and current[-1].seq == 4
    texts = [x.text for x in ours if x.get_type() == "STATUSTEXT" and x.severity <= m.MAV_SEVERITY_CRITICAL]
    assert texts and texts[0].startswith("thrust loss rotor 4") and not any("crash" in t for t in texts)
    pos = np.array([(x.time_boot_ms / 1000.0, x.x, x.y, x.z) for x in fc if x.get_type() == "LOCAL_POSITION_NED"])
    before, hold = pos[pos[:, 0] < FAULT_AT_S], pos[(pos[:, 0] > FAULT_AT_S) & (pos[:, 0] < FAULT_AT_S + 1.0)]
    assert np.min(np.hypot(before[:, 1] - 3.0, before[:, 2])) < 0.15, "the first waypoint (3 m north) never reached"
    assert np.max(hold[:, 3]) < -1.7, "the rotor loss took the robot down"
    assert pos[-1, 3] > -0.3, "it never came down"
    heartbeats = [x for x in fc if x.get_type() == "HEARTBEAT"]
    assert not heartbeats[-1].base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED, "not landed: still armed at the end"
    print(f"\nuploaded mission: the fault at {FAULT_AT_S} s, landed; items reached {sorted(set(reached))}")


def test_a_mission_file_takes_precedence_over_the_fcs_and_the_log_says_which_is_flown(caplog):
    caplog.set_level(logging.INFO, "m4-companion")
    config = parse_config({"link": {"fc_url": "udpin:127.0.0.1:0", "signing": False}}, "test")
    app = open_app(dataclasses.replace(config, mission_path=Path("my_mission.toml")))
    try:
        assert app.fc_mission is None
    finally:
        close_app(app)
    assert "flying the mission file my_mission.toml (it takes precedence over the flight controller's)" in caplog.text
