"""The simulated FC's parameters over real loopback MAVLink: a ground station on a second link
lists, reads and sets them, is told why a set is refused, and what it set survives a restart."""

from __future__ import annotations

import time

import pytest

from m4.airframe import load_airframe
from m4.fault_kind import FaultKind
from m4.mavlink import mavlink, new_mav
from m4.params import NAME_MAX
from m4.scenario import Scenario
from sitl.fc.params import STREAMS
from sitl.serve import ServeError, ServeOptions, Server
from sitl.standin_companion import StandInCompanion, served
from sitl.vehicle import Vehicle
from support.ground_station import GroundStation
from support.packets import packed

HOVER = Scenario(name="hover", duration_s=600.0)


@pytest.fixture
def gcs():
    g = GroundStation()
    yield g
    g.close()


def _serve(gcs: GroundStation, **options):
    return served(StandInCompanion(), ServeOptions(scenario=HOVER, realtime=True, **options), more_urls=(gcs.url,))


def test_a_ground_station_lists_every_parameter_with_its_index_and_count(gcs):
    with _serve(gcs) as server:
        table = server.vehicle.fc.params.table
        values = gcs.ask(mavlink.MAVLink_param_request_list_message(1, 0), "PARAM_VALUE", count=len(table))
    assert len(table) == len(values) >= 9 + len(STREAMS)
    assert sorted(v.param_index for v in values) == list(range(len(table)))
    assert {v.param_count for v in values} == {len(table)}
    by_name = {v.param_id: v for v in values}
    assert all(len(name) <= NAME_MAX for name in by_name)
    assert by_name["FS_SP_TIMEOUT"].param_value == pytest.approx(0.3)
    assert by_name["FS_SP_TIMEOUT"].param_type == mavlink.MAV_PARAM_TYPE_REAL32
    assert by_name["M4_ESC_CHK"].param_type == mavlink.MAV_PARAM_TYPE_INT8
    assert by_name["M4_ESC_CHK"].param_value == 1.0                   # cast to float, as ArduPilot sends
    assert by_name["SR_ATTITUDE"].param_value == pytest.approx(100.0)


def test_a_set_is_answered_with_the_value_in_force_and_acts(gcs):
    with _serve(gcs) as server:
        fc = server.vehicle.fc
        assert gcs.set("FS_SP_TIMEOUT", 0.5).param_value == pytest.approx(0.5)
        assert fc.stale_min_ms == 500
        assert gcs.set("M4_ESC_CHK", 0, mavlink.MAV_PARAM_TYPE_INT8).param_value == 0.0
        assert not fc.rotor_watch.enabled
        answer = gcs.set("SR_ATTITUDE", 30.0)                # 33 ms on the FC's millisecond clock
        assert answer.param_value == pytest.approx(1000.0 / 33, rel=1e-6)
        read = gcs.ask(mavlink.MAVLink_param_request_read_message(1, 1, b"", answer.param_index), "PARAM_VALUE")
        assert read[0].param_id == "SR_ATTITUDE"
        attitude = gcs.wait("ATTITUDE", count=20)
    gaps = {b.time_boot_ms - a.time_boot_ms for a, b in zip(attitude[-10:], attitude[-9:])}
    assert gaps == {33}


@pytest.mark.parametrize("name, value, param_type, reason", [
    ("FS_SP_TIMEOUT", 5.0, mavlink.MAV_PARAM_TYPE_REAL32, "out of range [0.1, 1]"),
    ("FS_LAND_SPEED", 1.0, mavlink.MAV_PARAM_TYPE_REAL32, "read-only"),
    ("M4_ESC_CHK", 0.5, mavlink.MAV_PARAM_TYPE_INT8, "wrong type: INT8 takes whole numbers"),
    ("M4_ESC_CHK", 0.0, mavlink.MAV_PARAM_TYPE_REAL64, "wrong type (MAV_PARAM_TYPE 10)"),
    ("FS_LAND_DELAY", float("nan"), mavlink.MAV_PARAM_TYPE_REAL32, "not a number"),
])
def test_a_refused_set_is_answered_with_the_unchanged_value_and_a_statustext_saying_why(gcs, name, value, param_type,
                                                                                        reason):
    with _serve(gcs) as server:
        before = server.vehicle.fc.params.table
        unchanged = before.value(before.params[before.index(name)])
        assert gcs.set(name, value, param_type).param_value == pytest.approx(unchanged, rel=1e-7)
        text = gcs.wait("STATUSTEXT", lambda m: "refused" in m.text)[0]
    assert text.text == f"FC: {name} refused: {reason}"[:50]
    assert text.severity == mavlink.MAV_SEVERITY_WARNING


def test_an_unknown_name_is_refused_when_addressed_to_the_fc_and_left_to_others_when_broadcast(gcs):
    with _serve(gcs):
        gcs.send(mavlink.MAVLink_param_request_read_message(1, 0, b"DET_CHI2_MIN", -1))   # the companion's, maybe
        gcs.send(mavlink.MAVLink_param_request_read_message(1, 1, b"NO_SUCH", -1))
        text = gcs.wait("STATUSTEXT", lambda m: "parameter" in m.text)[0]
        time.sleep(0.2)
        gcs.wait("HEARTBEAT")
    assert text.text == "FC: NO_SUCH: no such parameter"
    assert not [m for m in gcs.heard if m.get_type() == "PARAM_VALUE"]
    assert len([m for m in gcs.heard if m.get_type() == "STATUSTEXT" and "parameter" in m.text]) == 1


def test_with_signing_an_unsigned_set_is_dropped_and_a_signed_one_taken(tmp_path):
    key = bytes(range(1, 33))
    gcs, signed = GroundStation(), GroundStation(191, key)
    try:
        with served(StandInCompanion(key=key), ServeOptions(scenario=HOVER, realtime=True, signing_key=key),
                    more_urls=(gcs.url, signed.url)) as server:
            gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"FS_LAND_DELAY", 5.0, mavlink.MAV_PARAM_TYPE_REAL32))
            gcs.wait("HEARTBEAT")
            signed.send(mavlink.MAVLink_param_set_message(1, 1, b"FS_SP_TIMEOUT", 0.2, mavlink.MAV_PARAM_TYPE_REAL32))
            deadline = time.monotonic() + 10.0
            while server.vehicle.fc.stale_min_ms != 200 and time.monotonic() < deadline:
                time.sleep(0.05)
            fc = server.vehicle.fc
            assert fc.stale_min_ms == 200
            assert fc.failsafe.land_after_s == 2.0
    finally:
        gcs.close()
        signed.close()


def test_what_was_set_is_kept_in_the_params_file_and_in_force_after_a_restart(gcs, tmp_path):
    path = tmp_path / "fc.params.toml"
    with _serve(gcs, params_path=path):
        gcs.set("FS_LAND_DELAY", 4.5)
        gcs.set("M4_RATE_FB_ENA", 0, mavlink.MAV_PARAM_TYPE_INT8)
        gcs.set("FS_SP_TIMEOUT", 9.0)                       # refused: not kept
    assert "FS_LAND_DELAY = 4.5\n" in path.read_text() and "M4_RATE_FB_ENA = 0\n" in path.read_text()
    assert "FS_SP_TIMEOUT" not in path.read_text()
    with _serve(gcs, params_path=path) as server:
        fc = server.vehicle.fc
        assert fc.failsafe.land_after_s == 4.5 and not fc.rate_feedback_enabled
        gcs.set("FS_SP_TIMEOUT", 0.25)
    assert "FS_LAND_DELAY = 4.5\n" in path.read_text() and "FS_SP_TIMEOUT = 0.25\n" in path.read_text()


@pytest.mark.parametrize("text, message", [
    ("FS_NOPE = 1\n", "FS_NOPE: no such parameter"),
    ("FS_LAND_DELAY = 99\n", "FS_LAND_DELAY: out of range [0, 30], got 99"),
    ("FS_LAND_SPEED = 0.5\n", "FS_LAND_SPEED: read-only (the companion's landing joins"),
    ("M4_ESC_CHK = \"off\"\n", "M4_ESC_CHK must be a number, got 'off'"),
    ("FS_LAND_DELAY = \n", "not valid TOML"),
])
def test_a_bad_params_file_stops_the_start_naming_the_entry(tmp_path, text, message):
    path = tmp_path / "fc.params.toml"
    path.write_text(text)
    with pytest.raises(ServeError, match="parameters: " + str(path).replace(".", r"\.") + ".*") as e:
        Server(ServeOptions(scenario=HOVER, mavlink_urls=("udpout:127.0.0.1:9",), params_path=path))
    assert message in str(e.value)


def test_autopilot_version_says_parameters_go_out_cast_to_float_as_ardupilot_sends_them():
    companion = StandInCompanion()
    with served(companion, ServeOptions(scenario=HOVER, realtime=True)):
        companion.send(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                                            float(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION), *[0.0] * 6))
        capabilities = companion.wait_for("AUTOPILOT_VERSION").capabilities
    assert capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    assert capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    assert not capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE


def _as_received(msg, system: int, component: int):
    """msg as `system/component` sends it, decoded as the FC receives it."""
    return new_mav(None, 1, 1).parse_buffer(packed([msg], system, component)[0])[0]


def _vehicle_with(name: str, value: float, param_type: int) -> Vehicle:
    """A hovering vehicle at t = 100 ms whose FC a ground station has set `name` on."""
    vehicle = Vehicle(Scenario(name="hover", duration_s=5.0), load_airframe())
    vehicle.start(lambda msgs: None)
    vehicle.advance_to(100, lambda msgs: None)
    answers = []
    vehicle.handle([_as_received(mavlink.MAVLink_param_set_message(1, 1, name.encode(), value, param_type), 255, 190)],
                   answers.extend)
    assert [m.param_value for m in answers if m.get_type() == "PARAM_VALUE"] == [value]
    return vehicle


@pytest.mark.parametrize("enabled", [1, 0])
def test_with_m4_rate_fb_ena_0_the_fc_flies_the_setpoint_thrusts_without_its_rate_feedback(enabled):
    vehicle = _vehicle_with("M4_RATE_FB_ENA", enabled, mavlink.MAV_PARAM_TYPE_INT8)
    hip = [load_airframe().nominal_hip_rad] * 4
    gain = [2.0, 0.0, 0.0] + [0.0] * 9                      # rotor 1: 2 N per rad/s of roll-rate error
    sp = mavlink.MAVLink_m4_setpoint_message(1, 1, 100, 20, [14.7] * 4, hip, [0.0] * 4, 0, [1.0, 0.0, 0.0],
                                             [0.0, 0.0, 0.0], gain)
    vehicle.handle([_as_received(sp, 1, 191)], lambda msgs: None)
    vehicle.advance_to(100 + 2 * 4, lambda msgs: None)
    thrust = vehicle.fc.measured_state(vehicle.now_ms).thrust_cmd_n
    assert (thrust[0] > 14.7 + 1.0) == bool(enabled)


@pytest.mark.parametrize("enabled", [1, 0])
def test_with_m4_esc_chk_0_the_fc_no_longer_finds_a_stopped_motor_on_its_escs(enabled):
    vehicle = _vehicle_with("M4_ESC_CHK", enabled, mavlink.MAV_PARAM_TYPE_INT8)
    vehicle.fc.set_rotor_loss(4, 1.0, FaultKind.MOTOR)
    vehicle.advance_to(600, lambda msgs: None)
    assert vehicle.fc.lost_rotor() == (4 if enabled else None)
