"""The simulated vehicle's clock: what the observers (the truth log) see does not depend on
the streams' timing, which a companion's MAV_CMD_SET_MESSAGE_INTERVAL changes at a
wall-clock-dependent instant."""

from __future__ import annotations

from m4.airframe import load_airframe
from m4.mavlink import mavlink
from m4.scenario import Scenario
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
