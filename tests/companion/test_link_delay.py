"""The setpoints' lead and the link's round trip, measured with TIMESYNC through a loopback
proxy that delays every datagram 50 ms each way (sitl.links.netem_proxy)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from companion.fc_link import FcLink
from companion.link_delay import LinkDelay
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.link import UdpLink
from m4.setpoint import Setpoint
from sitl.links.netem_proxy import Impairment, Netem

SETPOINT = Setpoint(thrust_n=np.full(4, 14.7), hip_rad=np.full(4, 0.8), hip_rate_rad_s=np.zeros(4))


def test_the_lead_is_the_fc_time_from_the_answered_instant_to_the_setpoints_arrival():
    """The FC (its clock: ms since it started) sends telemetry stamped with its clock; the
    companion answers each at once with a setpoint and, every 0.1 s, a TIMESYNC; the FC
    answers those with its clock. Through 50 ms each way the lead is about 100 ms."""
    companion = FcLink(UdpLink("udpin:127.0.0.1:0", FC_SYSTEM_ID, COMPANION_COMPONENT_ID))
    proxy = Netem(("127.0.0.1", 0), ("127.0.0.1", companion.link.local_port), Impairment(delay_ms=50.0)).start()
    fc = UdpLink(f"udpout:127.0.0.1:{proxy.listen_port}", FC_SYSTEM_ID, FC_COMPONENT_ID)
    boot = time.monotonic()
    fc_ms = lambda: round((time.monotonic() - boot) * 1000)       # noqa: E731 - the FC's clock
    try:
        fc.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, 0, 0, 0, 4, 3))
        next_frame = 0.0
        while time.monotonic() - boot < 2.0 and companion.delay.samples < 8:
            if time.monotonic() - boot >= next_frame:
                fc.send(mavlink.MAVLink_local_position_ned_message(fc_ms(), 0.0, 0.0, -2.0, 0.0, 0.0, 0.0))
                next_frame += 0.02
            for msg in fc.receive():
                if msg.get_type() == "TIMESYNC":
                    fc.send(mavlink.MAVLink_timesync_message(fc_ms() * 1_000_000, msg.ts1))
            for msg in companion.receive(time.monotonic()).messages:
                if msg.get_type() == "LOCAL_POSITION_NED":
                    companion.send_setpoint(msg.time_boot_ms, 20, SETPOINT, time.monotonic())
            time.sleep(0.002)
        lead, rtt = companion.delay.lead_s, companion.delay.round_trip_s
        print(f"\nthrough 50 ms each way: setpoint lead {1e3 * lead:.0f} ms, TIMESYNC round trip {1e3 * rtt:.0f} ms "
              f"({companion.delay.samples} samples)")
        assert companion.delay.samples >= 8
        assert 0.095 <= lead <= 0.16 and 0.095 <= rtt <= 0.16
    finally:
        proxy.close()
        fc.close()
        companion.link.close()


def test_replies_to_requests_we_did_not_send_are_ignored_and_a_reboot_forgets():
    delay = LinkDelay()
    assert delay.request_due(0)
    ts1 = delay.requested(1000, now_s=5.0)
    assert not delay.request_due(1060) and delay.request_due(1100)
    assert delay.request_due(20)                                                   # the FC's clock went back
    assert not delay.answered(tc1_ns=2_000_000_000, ts1_ns=ts1 + 1, now_s=5.2)      # not ours
    assert delay.answered(tc1_ns=1_080_000_000, ts1_ns=ts1, now_s=5.1)
    assert not delay.answered(tc1_ns=1_080_000_000, ts1_ns=ts1, now_s=5.1)         # answered already
    assert delay.lead_s == pytest.approx(0.08) and delay.round_trip_s == pytest.approx(0.1)
    delay.reset()
    assert delay.lead_s is None and delay.round_trip_s is None
