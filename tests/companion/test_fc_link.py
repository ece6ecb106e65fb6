"""The companion's link to its FC: lock-on, strays, signing, interval requests over loopback UDP;
its events (locked, telemetry, lost, rebooted) on a socket-free transport."""

from __future__ import annotations

import time

import numpy as np
import pytest

from companion.core.control_types import FaultState, FaultStatus
from m4.fault_kind import FaultKind
from companion.fc_link import FcLink, LinkEvent, mission_progress
from companion.telemetry import REQUESTED
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink, new_mav
from m4.mavlink.link import UdpLink
from m4.mavlink.signing import setup_signing
from m4.mission_plan import MissionProgress, PlanProgress, PlanState
from m4.setpoint import Setpoint
from support.fake_transport import FakeTransport

KEY = bytes(range(32))
SETPOINT = Setpoint(thrust_n=np.full(4, 14.7), hip_rad=np.full(4, 0.8), hip_rate_rad_s=np.zeros(4))


def heartbeat():
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, 4, 3)


def position(t_ms, x=0.0):
    return mavlink.MAVLink_local_position_ned_message(t_ms, x, 0.0, -2.0, 0.0, 0.0, 0.0)


def received(fc_link: FcLink):
    """fc_link.receive as a function of nothing, giving the messages (for drain)."""
    return lambda: fc_link.receive(time.monotonic()).messages


def drain(receive, want: int = 1, timeout_s: float = 2.0) -> list:
    """What `receive()` returns until `want` messages came or timeout_s passed."""
    got, deadline = [], time.monotonic() + timeout_s
    while len(got) < want and time.monotonic() < deadline:
        got += receive()
        time.sleep(0.005)
    return got


@pytest.fixture
def links(request):
    """(companion FcLink, FC link, stray link): the FC and the stray both claim system 1 component 1."""
    key_of = getattr(request, "param", {})
    companion = FcLink(UdpLink("udpin:127.0.0.1:0", FC_SYSTEM_ID, COMPANION_COMPONENT_ID, key=key_of.get("companion")))
    url = f"udpout:127.0.0.1:{companion.link.local_port}"
    fc = UdpLink(url, FC_SYSTEM_ID, FC_COMPONENT_ID, key=key_of.get("fc"))
    stray = UdpLink(url, FC_SYSTEM_ID, FC_COMPONENT_ID, key=key_of.get("stray"))
    yield companion, fc, stray
    for link in (companion.link, fc, stray):
        link.close()


def test_nothing_is_sent_before_the_fc_is_heard_and_its_first_message_locks_on(links):
    """Its telemetry as well as its HEARTBEAT: a restarted companion need not wait up to a
    second for the next HEARTBEAT to take control."""
    companion, fc, _ = links
    companion.tick(0.0)
    assert not companion.locked and companion.link.peer is None
    fc.send(position(10))
    assert [m.get_type() for m in drain(received(companion))] == ["LOCAL_POSITION_NED"]
    assert companion.locked and companion.fc_address[1] == fc.local_port


def test_waiting_for_the_fc_does_not_spin(links):
    companion, _, _ = links
    assert companion.next_due_s(5.0) >= 5.5


def test_on_a_link_with_a_fixed_peer_our_heartbeat_goes_first_so_the_fc_learns_of_us():
    fc = UdpLink("udpin:127.0.0.1:0", FC_SYSTEM_ID, FC_COMPONENT_ID)
    companion = FcLink(UdpLink(f"udpout:127.0.0.1:{fc.local_port}", FC_SYSTEM_ID, COMPANION_COMPONENT_ID),
                       heartbeat_before_lock=True)
    try:
        companion.tick(0.0)
        assert [m.get_type() for m in drain(fc.receive)] == ["HEARTBEAT"]
        fc.send(heartbeat())                # a udpin FC answers whoever wrote: us
        drain(received(companion))
        assert companion.locked
    finally:
        fc.close()
        companion.link.close()


def test_a_stray_sender_with_the_fc_ids_is_ignored_and_cannot_redirect_our_replies(links):
    companion, fc, stray = links
    fc.send(heartbeat())
    drain(received(companion))
    for t_ms in (20, 40):
        stray.send(heartbeat())
        stray.send(position(t_ms, x=99.0))
    fc.send(position(60, x=1.0))
    got = drain(received(companion))
    assert [(m.get_type(), m.x) for m in got] == [("LOCAL_POSITION_NED", 1.0)]
    assert companion.health().foreign == 4 == companion.health().second_sender
    companion.send_setpoint(60, 20, SETPOINT, 0.0)
    got = drain(fc.receive, want=3)
    assert [m.get_type() for m in got] == ["STATUSTEXT", "M4_SETPOINT", "TIMESYNC"]     # the stray reported, once
    assert got[0].text == "companion: second sender as 1/1 (other address)"
    time.sleep(0.05)
    assert stray.receive() == []


def test_the_setpoint_its_fault_status_and_timesync_go_in_one_datagram(links):
    companion, fc, _ = links
    fc.send(heartbeat())
    drain(received(companion))
    ceiling_n = np.array([30.0, 30.0, 30.0, 0.0])
    fault = FaultStatus(state=FaultState.CONFIRMED, rotor=4, kind=FaultKind.PROPELLER, thrust_max_estimate_n=ceiling_n,
                        thrust_bound_n=ceiling_n, detected_at_s=1.04, message="thrust loss rotor 4 (propeller)",
                        deficit_n=np.zeros(4))
    companion.send_setpoint(60, 20, SETPOINT, 0.0, fault)
    datagrams = drain(lambda: [msgs for _, msgs in fc.receive_from()])
    assert [[m.get_type() for m in msgs] for msgs in datagrams] == [["M4_SETPOINT", "M4_FAULT_STATUS", "TIMESYNC"]]
    status = datagrams[0][1]
    assert (status.time_boot_ms, status.rotor, status.state, status.kind, status.detected_time_boot_ms) == \
        (60, 4, mavlink.M4_FAULT_STATE_CONFIRMED, int(FaultKind.PROPELLER), 1040)


def test_other_systems_and_components_are_dropped_and_counted(links):
    companion, _, _ = links
    other = UdpLink(f"udpout:127.0.0.1:{companion.link.local_port}", 7, FC_COMPONENT_ID)
    gimbal = UdpLink(f"udpout:127.0.0.1:{companion.link.local_port}", FC_SYSTEM_ID, 154)
    try:
        other.send(heartbeat())
        gimbal.send(heartbeat())
        time.sleep(0.05)
        assert companion.receive(time.monotonic()).messages == [] and not companion.locked
        assert companion.health().foreign == 2
    finally:
        other.close()
        gimbal.close()


@pytest.mark.parametrize("links", [{"companion": KEY, "fc": KEY}], indirect=True)
def test_with_a_key_unsigned_and_badly_signed_traffic_is_dropped_and_counted(links):
    companion, fc, _ = links
    liar = UdpLink(f"udpout:127.0.0.1:{companion.link.local_port}", FC_SYSTEM_ID, FC_COMPONENT_ID,
                   key=bytes(32))
    unsigned = UdpLink(f"udpout:127.0.0.1:{companion.link.local_port}", FC_SYSTEM_ID, FC_COMPONENT_ID)
    try:
        unsigned.send(heartbeat())          # unsigned heartbeats pass signing, but do not lock us on
        time.sleep(0.05)
        companion.receive(time.monotonic())
        assert not companion.locked
        fc.send(heartbeat())
        drain(received(companion))
        assert companion.locked and companion.fc_address[1] == fc.local_port
        liar.send(position(20, x=5.0))      # another key, and from another address
        fc.mav.signing.sign_outgoing = False
        fc.send(position(40, x=6.0))        # the FC's own address, unsigned
        fc.mav.signing.sign_outgoing = True
        fc.send(position(60, x=7.0))
        got = drain(received(companion))
        assert [m.x for m in got] == [7.0]
        health = companion.health()
        assert health.bad_signature == 1 and health.foreign >= 1
    finally:
        liar.close()
        unsigned.close()


@pytest.mark.parametrize("links", [{"companion": KEY, "fc": KEY}], indirect=True)
def test_our_setpoints_are_signed_with_the_key(links):
    companion, fc, _ = links
    fc.send(heartbeat())
    drain(received(companion))
    companion.send_setpoint(0, 20, SETPOINT, 0.0)
    got = drain(fc.receive)
    assert [m.get_type() for m in got] == ["M4_SETPOINT", "TIMESYNC"] and all(m.get_signed() for m in got)
    assert fc.signing_counters().signed_ok >= 1


def test_heartbeat_once_a_second_as_an_onboard_controller(links):
    companion, fc, _ = links
    fc.send(heartbeat())
    drain(received(companion))
    for now in (0.0, 0.5, 0.99, 1.0, 1.5):
        companion.tick(now)
    beats = [m for m in drain(fc.receive, want=20, timeout_s=0.3) if m.get_type() == "HEARTBEAT"]
    assert len(beats) == 2
    assert {(m.get_srcComponent(), m.type) for m in beats} == {(COMPANION_COMPONENT_ID,
                                                                 mavlink.MAV_TYPE_ONBOARD_CONTROLLER)}


def test_message_intervals_are_requested_one_at_a_time_until_acked(links):
    companion, fc, _ = links
    fc.send(heartbeat())
    drain(received(companion))
    companion.request_intervals(0.02)
    asked = []
    now = 0.0
    for _ in range(40):
        companion.tick(now)
        for m in drain(fc.receive, timeout_s=0.1):
            if m.get_type() != "COMMAND_LONG":
                continue
            asked.append((int(m.param1), m.param2))
            if len(asked) != 2:             # the second request goes unanswered once: resent
                fc.send(mavlink.MAVLink_command_ack_message(m.command, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 1, 191))
        drain(received(companion), want=1, timeout_s=0.05)
        now += 0.3
        if companion.health().commands_pending == 0:
            break
    ids = [i for i, _ in asked]
    assert ids[:3] == [REQUESTED[0], REQUESTED[1], REQUESTED[1]]
    assert sorted(set(ids)) == sorted(REQUESTED) and {us for _, us in asked} == {20000.0}
    assert companion.health().commands_acked == len(REQUESTED)


def test_an_ack_the_fc_sends_a_ground_station_does_not_answer_our_command(links):
    """The FC answers a ground station's command of the same number too: only the ack to us
    (its target our system and component) answers ours, as ArduPilot and MAVSDK match acks."""
    companion, fc, _ = links
    fc.send(heartbeat())
    drain(received(companion))
    companion.request_intervals(0.02)
    sent = []
    for now, to in ((0.0, (255, 190)), (0.6, (FC_SYSTEM_ID, COMPANION_COMPONENT_ID))):
        companion.tick(now)
        sent += [m for m in drain(fc.receive, timeout_s=0.5) if m.get_type() == "COMMAND_LONG"]
        fc.send(mavlink.MAVLink_command_ack_message(sent[-1].command, mavlink.MAV_RESULT_ACCEPTED, 0, 0, *to))
        drain(received(companion))
        if to[0] == 255:
            assert companion.health().commands_acked == 0
    assert [(m.param1, m.confirmation) for m in sent] == [(REQUESTED[0], 0), (REQUESTED[0], 1)]   # resent
    assert companion.health().commands_acked == 1


def test_acks_answer_the_ids_the_link_sends_as():
    """A companion on another component (a second onboard computer, 192) takes the FC's acks
    addressed to that component as answers to its commands: its own ids are its link's."""
    second = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER2
    companion = FcLink(UdpLink("udpin:127.0.0.1:0", FC_SYSTEM_ID, second))
    fc = UdpLink(f"udpout:127.0.0.1:{companion.link.local_port}", FC_SYSTEM_ID, FC_COMPONENT_ID)
    try:
        fc.send(heartbeat())
        drain(received(companion))
        companion.request_intervals(0.02)
        companion.tick(0.0)
        asked = [m for m in drain(fc.receive, timeout_s=0.5) if m.get_type() == "COMMAND_LONG"]
        assert asked and (asked[0].get_srcComponent(), asked[0].target_component) == (second, FC_COMPONENT_ID)
        fc.send(mavlink.MAVLink_command_ack_message(asked[0].command, mavlink.MAV_RESULT_ACCEPTED, 0, 0,
                                                    FC_SYSTEM_ID, second))
        drain(received(companion))
        assert companion.health().commands_acked == 1
        assert companion.own_ids == (FC_SYSTEM_ID, second)
    finally:
        companion.link.close()
        fc.close()


def test_the_fault_status_carries_the_missions_progress_and_it_reads_back():
    plan = PlanProgress(PlanState.FAULT_HOLD, 0.02, (0.0, 0.0, -2.0), 1.06, (0.5, 0.0, -1.9))
    progress = MissionProgress(2.98, plan)
    transport = FakeTransport(FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    healthy = FaultStatus(state=FaultState.HEALTHY, rotor=None, kind=FaultKind.UNKNOWN, thrust_max_estimate_n=np.full(4, 30.0),
                          thrust_bound_n=np.full(4, 30.0), detected_at_s=None, message="", deficit_n=np.zeros(4))
    FcLink(transport).send_setpoint(3000, 20, SETPOINT, 0.0, healthy, progress)
    status = next(m for m in transport.sent_messages() if m.get_type() == "M4_FAULT_STATUS")
    back = mission_progress(status)
    assert back.time_s == pytest.approx(2.98) and back.plan.state is PlanState.FAULT_HOLD
    assert back.plan.start_time_s == pytest.approx(0.02) and back.plan.change_time_s == pytest.approx(1.06)
    assert back.plan.start_ned_m == pytest.approx((0.0, 0.0, -2.0))
    assert back.plan.change_ned_m == pytest.approx((0.5, 0.0, -1.9))
    FcLink(transport).send_setpoint(3000, 20, SETPOINT, 0.0, healthy)        # before the flight starts
    assert mission_progress([m for m in transport.sent_messages() if m.get_type() == "M4_FAULT_STATUS"][-1]) is None
    assert {s.name: int(s) for s in PlanState} == {
        name.removeprefix("M4_MISSION_STATE_"): value for name, value in vars(mavlink).items()
        if name.startswith("M4_MISSION_STATE_") and name != "M4_MISSION_STATE_ENUM_END"}


# -- events, on a socket-free transport ----------------------------------------------------------------
FC = ("10.0.0.1", 14555)
FC_MAV = new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID)


@pytest.fixture
def fake():
    transport = FakeTransport(FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    return FcLink(transport, telemetry_timeout_s=0.3), transport


def test_the_events_of_a_flight_locked_telemetry_lost_and_back(fake):
    fc_link, transport = fake
    transport.deliver(FC, heartbeat(), mav=FC_MAV)
    assert fc_link.receive(10.0).events == (LinkEvent.LOCKED,)
    transport.deliver(FC, position(100), mav=FC_MAV)
    got = fc_link.receive(10.02)
    assert got.events == (LinkEvent.TELEMETRY,) and [m.x for m in got.messages] == [0.0]
    transport.deliver(FC, position(120), mav=FC_MAV)
    assert fc_link.receive(10.04).events == ()
    assert fc_link.next_due_s(10.05) <= 10.34
    assert fc_link.receive(10.33).events == ()
    assert fc_link.receive(10.34).events == (LinkEvent.LOST,) and not fc_link.connected
    assert fc_link.receive(10.5).events == ()
    transport.deliver(FC, position(900), mav=FC_MAV)
    assert fc_link.receive(11.0).events == (LinkEvent.TELEMETRY,) and fc_link.fc_time_ms == 900


def test_a_clock_that_goes_back_after_a_silence_is_a_reboot_and_within_the_stream_it_is_not(fake):
    fc_link, transport = fake
    transport.deliver(FC, heartbeat(), position(5000), mav=FC_MAV)
    fc_link.receive(10.0)
    transport.deliver(FC, position(4000), mav=FC_MAV)          # out of order, no silence
    assert fc_link.receive(10.1).events == () and fc_link.fc_time_ms == 5000
    assert fc_link.receive(10.4).events == (LinkEvent.LOST,)
    transport.deliver(FC, position(20), mav=FC_MAV)            # after 0.4 s of silence: a new boot
    assert fc_link.receive(10.5).events == (LinkEvent.REBOOTED, LinkEvent.TELEMETRY)
    assert fc_link.fc_time_ms == 20


def test_nothing_from_another_address_passes_once_locked_even_in_the_same_read(fake):
    fc_link, transport = fake
    stray = ("10.0.0.66", 14555)
    transport.deliver(FC, heartbeat(), mav=FC_MAV)
    transport.deliver(stray, heartbeat(), position(40, x=9.0), mav=FC_MAV)
    transport.deliver(FC, position(60, x=1.0), mav=FC_MAV)
    got = fc_link.receive(10.0)
    assert [m.get_type() for m in got.messages] == ["HEARTBEAT", "LOCAL_POSITION_NED"]
    assert got.messages[1].x == 1.0 and fc_link.fc_address == FC
    assert fc_link.health().foreign == 2             # both of the stray's messages


def test_nothing_from_another_address_passes_even_in_the_read_that_locks_on(links):
    companion, fc, stray = links
    fc.send(heartbeat())
    stray.send(position(20, x=9.0))
    fc.send(position(40, x=1.0))
    time.sleep(0.05)                           # the three datagrams wait: one read takes them all
    got = companion.receive(time.monotonic()).messages
    assert [m.get_type() for m in got] == ["HEARTBEAT", "LOCAL_POSITION_NED"] and got[1].x == 1.0
    assert companion.fc_address[1] == fc.local_port and companion.health().foreign == 1


@pytest.mark.parametrize("links", [{"companion": KEY, "fc": KEY}], indirect=True)
def test_with_a_key_a_forger_first_in_the_same_read_is_not_locked_on_to(links):
    """A forged unsigned HEARTBEAT with the FC's ids and garbage arrive before the real FC's
    signed HEARTBEAT, all in one read: the companion locks on to the real FC only."""
    companion, fc, stray = links
    stray.send(heartbeat())
    stray.sock.sendto(bytes(range(256)) * 2, ("127.0.0.1", companion.link.local_port))
    stray.send(position(20, x=9.0))
    fc.send(heartbeat())
    fc.send(position(40, x=1.0))
    time.sleep(0.05)
    got = companion.receive(time.monotonic()).messages
    assert companion.fc_address[1] == fc.local_port
    assert [m.get_type() for m in got] == ["HEARTBEAT", "LOCAL_POSITION_NED"] and got[1].x == 1.0
    companion.tick(0.0)
    time.sleep(0.05)
    assert stray.receive() == [] and [m.get_type() for m in fc.receive()] == ["HEARTBEAT"]


def test_after_the_telemetry_is_lost_an_fc_elsewhere_takes_over_with_its_first_message(fake):
    fc_link, transport = fake
    other = ("10.0.0.2", 14555)
    transport.deliver(FC, heartbeat(), position(100), mav=FC_MAV)
    fc_link.receive(10.0)
    transport.deliver(other, heartbeat(), position(120, x=9.0), mav=FC_MAV)     # while ours is alive: no
    assert fc_link.receive(10.1).events == () and fc_link.fc_address == FC
    assert fc_link.receive(10.4).events == (LinkEvent.LOST,) and transport.hear_others
    transport.deliver(other, position(20, x=4.0), mav=FC_MAV)
    got = fc_link.receive(10.5)
    assert got.events == (LinkEvent.LOCKED, LinkEvent.REBOOTED, LinkEvent.TELEMETRY)
    assert fc_link.fc_address == other and fc_link.previous_address == FC and [m.x for m in got.messages] == [4.0]
    assert transport.locked_peer == other and not transport.hear_others


def test_with_a_key_after_the_telemetry_is_lost_only_a_signed_fc_elsewhere_takes_over():
    transport = FakeTransport(FC_SYSTEM_ID, COMPANION_COMPONENT_ID, key=KEY)
    fc_link, signed = FcLink(transport, telemetry_timeout_s=0.3), new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID)
    setup_signing(signed, KEY)
    other = ("10.0.0.2", 14555)
    transport.deliver(FC, heartbeat(), position(100), mav=signed)
    fc_link.receive(10.0)
    assert fc_link.receive(10.4).events == (LinkEvent.LOST,)
    transport.deliver(other, heartbeat(), position(5, x=3.0), mav=FC_MAV)         # unsigned: no proof
    assert fc_link.receive(10.5).messages == [] and fc_link.fc_address == FC
    transport.deliver(other, position(20, x=4.0), mav=signed)
    assert fc_link.receive(10.6).events == (LinkEvent.LOCKED, LinkEvent.REBOOTED, LinkEvent.TELEMETRY)
    assert fc_link.fc_address == other
