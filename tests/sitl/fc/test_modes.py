"""The FC's modes as a ground station reads them: pymavlink/MAVProxy read them through
ArduCopter's table, so they are numbered as ArduCopter's modes of the same meaning; the
standard modes protocol names them too."""

from __future__ import annotations

import pytest

from m4.airframe import load_airframe
from m4.mavlink import mavlink, mavutil, new_mav
from sitl.fc.modes import MODES, FcMode, available_modes, base_mode
from sitl.fc.telemetry import Snapshot, Telemetry
from tests.support.packets import packed

m = mavlink



def _heartbeat_as_received(mode: FcMode, armed: bool):
    (packet,) = packed([Telemetry(load_airframe()).heartbeat(Snapshot(0, None, int(mode), armed, not armed))])
    return new_mav(None, 255, 190).parse_char(packet)


@pytest.mark.parametrize("mode, shown", [(FcMode.COMPANION, "GUIDED"), (FcMode.HOLD, "LOITER"),
                                         (FcMode.LAND, "LAND"), (FcMode.LANDED, "Mode(100)")])
def test_every_mode_reads_in_pymavlink_as_the_ardupilot_mode_of_its_meaning(mode, shown):
    hb = _heartbeat_as_received(mode, armed=mode != FcMode.LANDED)
    assert mavutil.mode_string_v10(hb) == shown
    assert hb.autopilot == m.MAV_AUTOPILOT_GENERIC and hb.base_mode & m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert hb.custom_mode == mode
    assert bool(hb.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED) == (mode != FcMode.LANDED)


def test_base_flags_tell_who_flies():
    assert base_mode(FcMode.COMPANION, True) & m.MAV_MODE_FLAG_GUIDED_ENABLED
    for mode in (FcMode.HOLD, FcMode.LAND):
        assert base_mode(mode, True) & m.MAV_MODE_FLAG_AUTO_ENABLED
        assert not base_mode(mode, True) & m.MAV_MODE_FLAG_GUIDED_ENABLED


def test_available_modes_list_every_mode_once_standard_ones_without_a_name():
    every = available_modes(0)
    assert [(a.mode_index, a.number_modes) for a in every] == [(i, len(MODES)) for i in range(1, len(MODES) + 1)]
    assert {a.custom_mode for a in every} == set(FcMode)
    by_mode = {FcMode(a.custom_mode): a for a in every}
    assert by_mode[FcMode.HOLD].standard_mode == m.MAV_STANDARD_MODE_POSITION_HOLD and not by_mode[FcMode.HOLD].mode_name
    assert by_mode[FcMode.LAND].standard_mode == m.MAV_STANDARD_MODE_LAND
    assert by_mode[FcMode.COMPANION].mode_name == "COMPANION"
    assert available_modes(2) == [every[1]] and available_modes(len(MODES) + 1) is None
