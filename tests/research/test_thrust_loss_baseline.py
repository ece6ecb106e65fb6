"""The ArduCopter-style thrust-loss check: it fires after a second of saturated, level descent and names no rotor."""

import numpy as np
import pytest

from m4.airframe import load_airframe
from companion.core import rom
from companion.core.control_types import FaultState
from research.thrust_loss_baseline import ThrustLossCheck

AF = load_airframe()
DT = 0.1


def test_baseline_fires_after_a_second_of_saturated_level_descent_without_naming_a_rotor():
    check = ThrustLossCheck(AF)
    x = rom.hover_state(AF)
    x[rom.V] = (0.0, 0.0, 0.4)              # sinking
    cmd = np.array([28.0, 20.0, 20.0, 0.0])  # one rotor at the top of its range
    statuses = [check.update(k * DT, x, cmd) for k in range(12)]
    assert statuses[9].state is FaultState.SUSPECT
    assert statuses[10].state is FaultState.CONFIRMED and statuses[10].detected_at_s == pytest.approx(1.0)
    assert statuses[10].rotor is None
    assert np.allclose(statuses[10].thrust_max_estimate_n, AF.thrust_max_n)


def test_baseline_restarts_its_timer_whenever_the_robot_stops_sinking():
    check = ThrustLossCheck(AF)
    x = rom.hover_state(AF)
    cmd = np.array([28.0, 20.0, 20.0, 0.0])
    for k in range(30):
        x[rom.V] = (0.0, 0.0, 0.4 if k % 8 else -0.1)
        status = check.update(k * DT, x, cmd)
    assert status.state is not FaultState.CONFIRMED
