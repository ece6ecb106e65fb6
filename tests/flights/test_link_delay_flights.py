"""The hover rotor loss behind a slow, lossy link (issue 10), flown by `m4-sitl fly` with the
link emulated in simulated time (deterministic, whatever the machine's load): 50 ms each way
and 20 % of the datagrams lost both ways, the issue's target. The companion plans from the
state predicted to when its setpoint acts, and the FC closes the rate feedback around the
plan and covers the rotor its ESCs show falling short; before the cover this flight lost
0.63 m, before the prediction and the feedback it crashed."""

from __future__ import annotations

import pytest

from sitl.flights.flight_run import FlightOptions
from sitl.flights.fly import fly
from sitl.links.emulation import LinkEmulation

pytestmark = pytest.mark.flight


def test_the_hover_rotor_loss_survives_50_ms_each_way_and_20_percent_loss(tmp_path):
    m = fly("hover-rotor-loss", tmp_path, FlightOptions(link=LinkEmulation(delay_ms=50, loss=0.2)), figures=False,
            progress=False)
    assert m["survived"], m["checks"]
    assert m["altitude_loss_m"] <= 0.25 and m["max_tilt_deg_after_fault"] <= 30
    fault = m["faults"][0]
    assert fault["detected_rotor"] == 4 and fault["detected_at_s"] - fault["at_s"] <= 0.1
    assert m["link"]["setpoint_lead_ms"] == pytest.approx(100, abs=5)


def test_and_in_real_time_through_the_loopback_proxy(tmp_path):
    """The same through sitl/links/netem_proxy.py, paced by the wall clock: the lead jitters with the
    companion's step and setpoints land between the FC's frames. Both processes in
    SCHED_FIFO, as deployed, so other work on the machine does not decide the flight."""
    options = FlightOptions(realtime=True, link=LinkEmulation(delay_ms=50, loss=0.2), companion_priority=40,
                            sitl_priority=40)
    m = fly("hover-rotor-loss", tmp_path, options, figures=False, progress=False)
    assert m["link"]["mode"] == "proxy"
    assert m["survived"], m["checks"]
    assert m["faults"][0]["detected_rotor"] == 4
    assert 100 <= m["link"]["setpoint_lead_ms"] <= 130
