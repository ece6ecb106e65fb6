"""When setpoints stop, the FC holds, then lands at 0.5 m/s and cuts the thrust; it never
flies on stale setpoints."""

from __future__ import annotations

import math

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.scenario import PlantOptions, Scenario, Start
from sitl.fc.failsafe import LAND_AFTER_S, LAND_SPEED_M_S
from sitl.fc.flight_controller import STALE_MIN_MS, FcMode
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served
from sitl.vehicle import Vehicle

STOP_MS = 1000


def _time_of(msgs, index):
    """Simulated time of msgs[index]: the stamp of the next message that has one."""
    return next(m.time_boot_ms for m in msgs[index:] if hasattr(m, "time_boot_ms"))


@pytest.fixture(scope="module")
def silent_after_one_second():
    """Lockstep; the companion answers until t = 1 s, then goes silent; 8 s simulated."""
    companion = StandInCompanion(period_ms=20, until_ms=STOP_MS)
    options = ServeOptions(scenario=Scenario(name="hover", duration_s=60.0), duration_s=8.0, lockstep_timeout_s=0.2)
    with served(companion, options):
        assert companion.wait_for("M4_THRUSTER_STATUS", lambda m: m.time_boot_ms >= 8000, 60.0)
    return list(companion.received)


def test_stale_setpoints_announce_hold_then_land_then_landed(silent_after_one_second):
    msgs = silent_after_one_second
    texts = [(i, m.text) for i, m in enumerate(msgs) if m.get_type() == "STATUSTEXT"]
    assert [t for _, t in texts] == ["FC failsafe HOLD: no fresh setpoints", "FC: flying companion setpoints",
                                     "FC failsafe HOLD: no fresh setpoints", "FC failsafe LAND: setpoints stale for 2 s",
                                     "FC LANDED: thrust cut", "FC disarmed"]
    hold_ms, land_ms = _time_of(msgs, texts[2][0]), _time_of(msgs, texts[3][0])
    last_setpoint_ms = STOP_MS - 20
    assert last_setpoint_ms + STALE_MIN_MS <= hold_ms <= last_setpoint_ms + STALE_MIN_MS + 10
    assert land_ms - hold_ms == pytest.approx(LAND_AFTER_S * 1000, abs=10)
    modes = [m.custom_mode for m in msgs if m.get_type() == "HEARTBEAT"]
    assert modes[-1] == FcMode.LANDED


def test_land_descends_at_half_a_metre_per_second_and_cuts_thrust_on_the_ground(silent_after_one_second):
    msgs = silent_after_one_second
    positions = {m.time_boot_ms: m for m in msgs if m.get_type() == "LOCAL_POSITION_NED"}
    land_ms = next(_time_of(msgs, i) for i, m in enumerate(msgs)
                   if m.get_type() == "STATUSTEXT" and "LAND:" in m.text)
    hold_z = positions[land_ms - land_ms % 20].z
    assert hold_z == pytest.approx(-2.0, abs=0.1)
    one_second_later = positions[land_ms - land_ms % 20 + 2000]
    assert one_second_later.vz == pytest.approx(LAND_SPEED_M_S, abs=0.1)
    final = [m for m in msgs if m.get_type() == "M4_THRUSTER_STATUS"][-1]
    assert list(final.thrust_cmd_n) == [0.0] * 4
    assert positions[8000].z > -0.3 and abs(positions[8000].vz) < 0.05


def test_before_any_setpoint_the_fc_holds_its_start_pose_and_never_lands():
    af = load_airframe()
    start = Start(ned_m=(3.0, -1.0, -4.0), yaw_deg=30.0)
    vehicle = Vehicle(Scenario(name="wait", duration_s=60.0, start=start,
                               plant=PlantOptions(sensor_noise=True)), af, seed=1)
    sent = []
    vehicle.start(sent.extend)
    vehicle.advance_to(5000, sent.extend)
    state = vehicle.plant.state()
    assert vehicle.fc.mode == FcMode.HOLD
    assert np.linalg.norm(state.pos_ned_m - np.array(start.ned_m)) < 0.1
    assert state.euler_rad[2] == pytest.approx(math.radians(30.0), abs=math.radians(2.0))
    assert [m.text for m in sent if m.get_type() == "STATUSTEXT"] == ["FC failsafe HOLD: no fresh setpoints"]
