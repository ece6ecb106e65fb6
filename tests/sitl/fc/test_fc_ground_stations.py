"""Ground stations command the simulated FC as they command an autopilot (issue 22): commands
from anyone (signed, with a key), setpoints from the paired companion only; each reply goes
back on the link its command came on, each link has its own stream rates, the companion's
critical texts reach the ground as the FC's own, and a refused command retried is answered
every time but logged once. The FC's modes are selected from the ground. Real loopback
sockets: the FC's first link goes to a stand-in companion, its second to a ground station."""

from __future__ import annotations

import contextlib

from m4.fc_mode import FcMode
from m4.mavlink import mavlink
from m4.scenario import Scenario
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served

m = mavlink
KEY = bytes(range(3, 35))
GCS = (255, 190)


@contextlib.contextmanager
def _fc_with_ground_station(key=None, gcs_key=None, realtime=False, until_ms=None):
    """(server, companion, ground station): the FC's links to the companion and to the station."""
    companion = StandInCompanion(key=key, until_ms=until_ms)
    gcs = StandInCompanion(key=gcs_key, until_ms=0, ids=GCS).start()
    options = ServeOptions(scenario=Scenario(name="hover", duration_s=60.0), realtime=realtime, signing_key=key)
    try:
        with served(companion, options, more_urls=(gcs.url,)) as server:
            gcs.wait_for("HEARTBEAT")
            yield server, companion, gcs
    finally:
        gcs.close()


def _command(sender, command, *params, timeout_s=5.0):
    """COMMAND_LONG from `sender`; the COMMAND_ACK that answers it (None: none came)."""
    before = len(sender.of_type("COMMAND_ACK"))
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    sender.send(m.MAVLink_command_long_message(1, 1, command, 0, *p))
    return sender.wait_for("COMMAND_ACK", lambda a: a in sender.of_type("COMMAND_ACK")[before:]
                           and a.command == command, timeout_s=timeout_s)


def _set_mode(sender, mode: int, sub_mode: int = 0):
    return _command(sender, m.MAV_CMD_DO_SET_MODE, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode, sub_mode)


def test_a_ground_station_commands_the_fc_but_its_setpoints_are_refused():
    with _fc_with_ground_station() as (server, companion, gcs):
        fc = server.vehicle.fc
        version = _command(gcs, m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        injected = _command(gcs, m.MAV_CMD_INJECT_FAILURE, m.FAILURE_UNIT_SYSTEM_MOTOR, m.FAILURE_TYPE_OFF, 2)
        armed = _command(gcs, m.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert gcs.wait_for("AUTOPILOT_VERSION", timeout_s=2.0) is not None
        t_ms = companion.of_type("M4_THRUSTER_STATUS")[-1].time_boot_ms
        gcs.send(m.MAVLink_m4_setpoint_message(1, 1, t_ms, 20, [0.0] * 4, [0.78] * 4, [0.0] * 4, 0))
        companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= t_ms + 200)
        assert fc.counters.refused_foreign == 1 and fc.counters.setpoints_dropped == 0
    assert [a.result for a in (version, injected, armed)] == [m.MAV_RESULT_ACCEPTED] * 3
    assert all((a.target_system, a.target_component) == GCS for a in (version, injected, armed))
    assert any(t.text == "rotor 2 motor stop injected" for t in gcs.of_type("STATUSTEXT"))
    assert not companion.of_type("AUTOPILOT_VERSION")           # what the station asked for is the station's
    assert min(companion.of_type("M4_THRUSTER_STATUS")[-1].thrust_cmd_n) > 10.0     # the companion still flies


def test_with_a_key_a_ground_station_is_obeyed_only_when_it_signs():
    with _fc_with_ground_station(key=KEY, gcs_key=KEY) as (server, companion, gcs):
        signed = _command(gcs, m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        gcs.link.mav.signing.sign_outgoing = False
        unsigned = _command(gcs, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196, timeout_s=1.0)
        rejected = sum(link.signing_counters().rejected for link in server.links)
        armed = server.vehicle.fc.armed
    assert signed is not None and signed.result == m.MAV_RESULT_ACCEPTED
    assert unsigned is None and rejected >= 1 and armed


def test_replies_go_back_on_the_link_the_command_came_on():
    with _fc_with_ground_station() as (server, companion, gcs):
        for_companion = _command(companion, m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_HOME_POSITION)
        companion.send(m.MAVLink_timesync_message(0, 123456))
        for_gcs = _command(gcs, m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_HOME_POSITION)
        assert companion.wait_for("TIMESYNC", lambda t: t.ts1 == 123456, timeout_s=2.0) is not None
        gcs.wait_for("HEARTBEAT", lambda h: h in gcs.received[-10:])            # a little later
    assert for_companion.result == for_gcs.result == m.MAV_RESULT_ACCEPTED
    assert [(a.target_system, a.target_component) for a in gcs.of_type("COMMAND_ACK")] == [GCS]
    assert [(a.target_system, a.target_component) for a in companion.of_type("COMMAND_ACK")] == [(1, 191)]
    assert len(companion.of_type("HOME_POSITION")) == len(gcs.of_type("HOME_POSITION")) == 1
    assert not [t for t in gcs.of_type("TIMESYNC") if t.get_srcComponent() == 1]     # the FC's answer


def test_a_ground_station_sets_its_own_links_stream_rates():
    with _fc_with_ground_station(realtime=True) as (server, companion, gcs):
        ack = _command(gcs, m.MAV_CMD_SET_MESSAGE_INTERVAL, m.MAVLINK_MSG_ID_ATTITUDE, 500_000)
        t0_ms = companion.of_type("ATTITUDE")[-1].time_boot_ms
        companion.wait_for("ATTITUDE", lambda a: a.time_boot_ms >= t0_ms + 1500)
    assert ack.result == m.MAV_RESULT_ACCEPTED
    ground = [a.time_boot_ms for a in gcs.of_type("ATTITUDE") if a.time_boot_ms > t0_ms]
    onboard = [a.time_boot_ms for a in companion.of_type("ATTITUDE") if t0_ms < a.time_boot_ms <= t0_ms + 1500]
    assert 2 <= len(ground) <= 4                    # 2 Hz for the station
    assert len(onboard) >= 100                      # 100 Hz for the companion, unchanged


def test_the_companions_critical_text_reaches_the_ground_once_as_the_fcs_own():
    """A ground station prints every STATUSTEXT of the vehicle's components: the fault once,
    from the FC (before, the companion's original was routed as well: the fault twice)."""
    with _fc_with_ground_station() as (server, companion, gcs):
        companion.send(m.MAVLink_statustext_message(m.MAV_SEVERITY_CRITICAL, b"thrust loss rotor 4 (motor)"))
        companion.send(m.MAVLink_statustext_message(m.MAV_SEVERITY_WARNING, b"companion: link delay 80 ms"))
        gcs.wait_for("STATUSTEXT", lambda t: t.text == "companion: link delay 80 ms")
        gcs.wait_for("HEARTBEAT", lambda h: h in gcs.received[-10:])
    texts = [(t.get_srcComponent(), t.severity, t.text) for t in gcs.of_type("STATUSTEXT") if "FC" not in t.text]
    assert sorted(texts) == [(1, m.MAV_SEVERITY_CRITICAL, "thrust loss rotor 4 (motor)"),      # once, the FC's
                             (191, m.MAV_SEVERITY_WARNING, "companion: link delay 80 ms")]     # the rest as it came
    assert not [t for t in companion.of_type("STATUSTEXT") if t.text.startswith("thrust loss")]


def test_a_refused_command_retried_is_answered_every_time_and_logged_once(capfd):
    with _fc_with_ground_station() as (server, companion, gcs):
        acks = [_set_mode(gcs, FcMode.LANDED) for _ in range(5)]
        refused = server.vehicle.fc.counters.commands_refused
    log = capfd.readouterr().err
    assert [a.result for a in acks] == [m.MAV_RESULT_DENIED] * 5 and refused == 5
    assert log.count("MAV_CMD_DO_SET_MODE from 255/190 refused: DENIED, LANDED is not selectable") == 1
    told = [t.text for t in gcs.of_type("STATUSTEXT") if t.text.startswith("FC refused")]
    assert told == ["FC refused SET_MODE: LANDED is not selectable"]


def _current(sender, custom_mode, intended, after=0):
    return sender.wait_for("CURRENT_MODE", lambda c: c in sender.of_type("CURRENT_MODE")[after:]
                           and (c.custom_mode, c.intended_custom_mode) == (custom_mode, intended), timeout_s=3.0)


def test_a_ground_station_selects_hold_land_and_the_companions_mode():
    with _fc_with_ground_station() as (server, companion, gcs):
        hold = _command(gcs, m.MAV_CMD_DO_SET_STANDARD_MODE, m.MAV_STANDARD_MODE_POSITION_HOLD)
        told_hold = _current(companion, FcMode.HOLD, FcMode.HOLD)
        back = _set_mode(gcs, FcMode.COMPANION)
        told_back = _current(companion, FcMode.COMPANION, FcMode.COMPANION, after=1)
        px4_hold = _set_mode(gcs, 4, 3)                        # MAVSDK's action.hold()
        land = _command(gcs, m.MAV_CMD_NAV_LAND)               # MAVSDK's action.land()
        told_land = _current(gcs, FcMode.LAND, FcMode.LAND)
        px4_other = _set_mode(gcs, 4, 4)
        unknown = _set_mode(gcs, 1)                            # ArduCopter's ACRO: not ours
        assert server.vehicle.fc.mode == FcMode.LAND and server.vehicle.fc.selected == FcMode.LAND
    assert [a.result for a in (hold, back, px4_hold, land)] == [m.MAV_RESULT_ACCEPTED] * 4
    assert told_hold and told_back and told_land
    assert told_hold.standard_mode == m.MAV_STANDARD_MODE_POSITION_HOLD and told_land.standard_mode == m.MAV_STANDARD_MODE_LAND
    assert px4_other.result == unknown.result == m.MAV_RESULT_DENIED
    texts = [t.text for t in gcs.of_type("STATUSTEXT")]
    assert "FC HOLD: the companion holds" in texts and "FC LAND: the companion lands" in texts


def test_without_setpoints_only_land_is_selectable_and_the_failsafe_lands_at_once():
    with _fc_with_ground_station(realtime=True, until_ms=200) as (server, companion, gcs):
        gcs.wait_for("STATUSTEXT", lambda t: t.text == "FC failsafe HOLD: no fresh setpoints"
                     and t in gcs.of_type("STATUSTEXT")[1:])          # the second: stale after flying
        hold = _command(gcs, m.MAV_CMD_DO_SET_STANDARD_MODE, m.MAV_STANDARD_MODE_POSITION_HOLD)
        land = _command(gcs, m.MAV_CMD_DO_SET_STANDARD_MODE, m.MAV_STANDARD_MODE_LAND)
        landing = gcs.wait_for("STATUSTEXT", lambda t: t.text == "FC failsafe LAND: no fresh setpoints", 1.0)
        mode = server.vehicle.fc.mode
    assert hold.result == m.MAV_RESULT_TEMPORARILY_REJECTED and land.result == m.MAV_RESULT_ACCEPTED
    assert landing is not None and mode == FcMode.LAND
    assert "FC refused SET_STANDARD_MODE: no setpoints" in [t.text for t in gcs.of_type("STATUSTEXT")]


def test_a_disarmed_fc_takes_no_mode():
    with _fc_with_ground_station() as (server, companion, gcs):
        server.vehicle.fc.set_armed(False)
        refused = _command(gcs, m.MAV_CMD_NAV_LAND)
    assert refused.result == m.MAV_RESULT_TEMPORARILY_REJECTED
