"""The simulated vehicle's clock: what the observers (the truth log) see does not depend on
the streams' timing, which a companion's MAV_CMD_SET_MESSAGE_INTERVAL changes at a
wall-clock-dependent instant. A scenario's fault is announced as a command's is."""

from __future__ import annotations

from m4.airframe import load_airframe
from m4.fault_kind import FaultKind
from m4.mavlink import mavlink
from m4.scenario import Fault, Scenario
from sitl.vehicle import OBSERVED_GRID_MS, Vehicle


def _observed_instants(attitude_interval_us: float | None) -> list[int]:
    vehicle = Vehicle(Scenario(name="hover", duration_s=1.0), load_airframe())
    seen = []
    vehicle.observers.append(lambda t_ms, plant: seen.append(t_ms))
    vehicle.start(lambda msgs: None)
    if attitude_interval_us is not None:
        for msg_id in (mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
            vehicle.fc.schedule.set_interval_us(msg_id, attitude_interval_us, 0)
    vehicle.advance_to(100, lambda msgs: None)
    return [t for t in seen if t % OBSERVED_GRID_MS == 0]


def test_the_observed_grid_is_there_whatever_the_stream_intervals():
    grid = list(range(0, 101, OBSERVED_GRID_MS))
    assert _observed_instants(None) == grid
    assert _observed_instants(20000.0) == grid
    assert _observed_instants(33000.0) == grid


def test_a_scenario_fault_and_its_end_are_announced_as_an_injected_fault_is():
    """So every log of the flight, the companion's too, carries the fault's instant and kind."""
    fault = Fault(at_s=0.05, rotor=3, loss=1.0, kind=FaultKind.PROPELLER, until_s=0.08)
    vehicle = Vehicle(Scenario(name="hover", duration_s=1.0, faults=(fault,)), load_airframe())
    said = []
    send = lambda msgs: said.extend((vehicle.now_ms, m.text) for m in msgs if m.get_type() == "STATUSTEXT")  # noqa: E731
    vehicle.start(send)
    vehicle.advance_to(100, send)
    assert [(t, text) for t, text in said if "rotor" in text] == [(50, "rotor 3 propeller loss injected"),
                                                                 (80, "rotor 3 restored")]
