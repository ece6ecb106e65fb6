"""What a restarted companion can ask the FC (issue 10): the last M4_FAULT_STATUS its
companion sent, and TIMESYNC to measure the link's delay. Real loopback sockets."""

from __future__ import annotations

import time

from m4.mavlink import mavlink
from m4.scenario import Scenario
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served

m = mavlink


def _request_fault_status(companion):
    before = len(companion.of_type("COMMAND_ACK"))
    companion.send(m.MAVLink_command_long_message(1, 1, m.MAV_CMD_REQUEST_MESSAGE, 0,
                                                  float(m.MAVLINK_MSG_ID_M4_FAULT_STATUS), 0, 0, 0, 0, 0, 0))
    return companion.wait_for("COMMAND_ACK", lambda a: a in companion.of_type("COMMAND_ACK")[before:], 3.0)


def test_the_fc_keeps_the_companions_last_fault_status_and_sends_it_when_asked():
    companion = StandInCompanion()
    with served(companion, ServeOptions(scenario=Scenario(name="hover", duration_s=60.0), realtime=True)):
        assert _request_fault_status(companion).result == m.MAV_RESULT_FAILED       # nothing sent yet
        for rotor in (2, 3):
            companion.send(m.MAVLink_m4_fault_status_message(400, rotor, [30.0, 0.5, 30.0, 30.0], 380,
                                                             m.M4_FAULT_STATE_CONFIRMED))
        time.sleep(0.1)
        ack = _request_fault_status(companion)
        status = companion.wait_for("M4_FAULT_STATUS", timeout_s=3.0)
    assert ack.result == m.MAV_RESULT_ACCEPTED
    assert status.get_srcComponent() == 1
    assert (status.rotor, status.detected_time_boot_ms, status.state) == (3, 380, m.M4_FAULT_STATE_CONFIRMED)
    assert list(status.thrust_max_estimate_n) == [30.0, 0.5, 30.0, 30.0]


def test_the_fc_answers_a_timesync_request_with_its_clock():
    companion = StandInCompanion()
    with served(companion, ServeOptions(scenario=Scenario(name="hover", duration_s=60.0), realtime=True)):
        companion.wait_for("ATTITUDE", lambda a: a.time_boot_ms >= 500)
        companion.send(m.MAVLink_timesync_message(0, 123456789))
        reply = companion.wait_for("TIMESYNC", timeout_s=3.0)
        now_ms = companion.of_type("ATTITUDE")[-1].time_boot_ms
        companion.send(m.MAVLink_timesync_message(5, 42))                 # a reply, not a request: no answer
        time.sleep(0.2)
    assert reply.ts1 == 123456789
    assert abs(reply.tc1 / 1e6 - now_ms) < 100
    assert len(companion.of_type("TIMESYNC")) == 1


def test_the_fc_sends_back_every_field_it_kept_the_kind_and_the_missions_progress_too():
    """A restarted companion resumes its mission from these fields: a copy that dropped them
    would make it anchor the mission where it finds the robot."""
    companion = StandInCompanion()
    sent = m.MAVLink_m4_fault_status_message(2980, 4, [30.0, 30.0, 30.0, 0.0], 1040, m.M4_FAULT_STATE_CONFIRMED,
                                             m.M4_FAULT_KIND_MOTOR, m.M4_MISSION_STATE_FAULT_HOLD, 2960, 0,
                                             [0.0, 0.0, -2.0], 1060, [0.5, 0.0, -1.75])
    with served(companion, ServeOptions(scenario=Scenario(name="hover", duration_s=60.0), realtime=True)):
        companion.send(sent)
        time.sleep(0.1)
        _request_fault_status(companion)
        back = companion.wait_for("M4_FAULT_STATUS", timeout_s=3.0)
    assert back.get_srcComponent() == 1
    assert [getattr(back, f) for f in back.fieldnames] == [getattr(sent, f) for f in sent.fieldnames]


def test_arming_again_forgets_what_the_fc_kept_a_new_flight_starts_afresh():
    companion = StandInCompanion()
    with served(companion, ServeOptions(scenario=Scenario(name="hover", duration_s=60.0), realtime=True)):
        companion.send(m.MAVLink_m4_fault_status_message(400, 3, [30.0, 30.0, 0.0, 30.0], 380,
                                                         m.M4_FAULT_STATE_CONFIRMED, 0, m.M4_MISSION_STATE_LANDING))
        for arm, force in ((0.0, 21196.0), (1.0, 0.0)):
            before = len(companion.of_type("COMMAND_ACK"))
            companion.send(m.MAVLink_command_long_message(1, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, arm, force,
                                                          0, 0, 0, 0, 0))
            companion.wait_for("COMMAND_ACK", lambda a: a in companion.of_type("COMMAND_ACK")[before:], 3.0)
        assert _request_fault_status(companion).result == m.MAV_RESULT_FAILED
