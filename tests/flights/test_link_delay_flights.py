"""Rotor losses behind a slow, lossy link (issues 10 and 20), flown by `m4-sitl fly` with the
link emulated in simulated time (deterministic, whatever the machine's load): 50 ms each way
and 20 % of the datagrams lost both ways, the issues' target. The companion plans from the
state predicted to when its setpoint acts, and the FC closes the rate feedback around the
plan and covers the rotor its ESCs or its gyro show falling short; before the cover the hover
rotor loss lost 0.63 m, before the prediction and the feedback it crashed."""

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


@pytest.mark.parametrize("scenario, rotor", [("propeller-loss", 2), ("no-esc-motor-loss", 3)])
def test_a_lost_propeller_and_a_motor_stop_without_esc_telemetry_survive_it_too(tmp_path, scenario, rotor):
    """Issue 20: with sensor noise, the lost propeller lost 1.09 m at this seed (the start-up
    wobble of a plan made before the lead was measured left the legs off the symmetric
    posture), and without ESC telemetry the FC had no measure of the stopped motor at all and
    the robot crashed; the FC now measures the shortfall on its gyro too."""
    m = fly(scenario, tmp_path, FlightOptions(seed=1, link=LinkEmulation(delay_ms=50, loss=0.2)), figures=False,
            progress=False)
    assert m["survived"], m["checks"]
    assert m["altitude_loss_m"] < 0.5 and m["max_tilt_deg_after_fault"] <= 35
    assert m["faults"][0]["detected_rotor"] == rotor


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
