"""The FC's gyro measure of a shortfall (sitl/fc/gyro_shortfall.py): the angular acceleration the
robot lacks, explained by the rotors that fall short, so that the FC covers a failing rotor
without ESC telemetry."""

from __future__ import annotations

import numpy as np
import pytest

from companion.core.rate_feedback import RateFeedbackDesign
from m4.airframe import load_airframe
from m4.mavlink import mavlink
from sitl.fc.flight_controller import TICK_MS
from sitl.fc.gyro_shortfall import DifferentiatingFilter, rotor_shortfall_n
from m4.fault_kind import FaultKind
from m4.scenario import PlantOptions, Scenario
from sitl.vehicle import Vehicle
from tests.sitl.fc.test_fc_rate_feedback import THRUST_N, _from_companion

AF = load_airframe()
COVER = RateFeedbackDesign(AF, 20.0, shortfall_cover=True).cover(np.full(4, AF.nominal_hip_rad), False)
EFFECTIVENESS = COVER.effectiveness_frd_rad_s2_per_n


@pytest.mark.parametrize("short", [[0.0, 0.0, 7.0, 0.0], [3.0, 0.0, 2.0, 0.0], [0.0, 4.0, 0.0, 1.0], [0.0] * 4])
def test_what_the_robot_lacks_is_put_on_the_fewest_rotors_that_explain_it(short):
    """One rotor's loss names it alone; a lack between two rotors' effects is theirs."""
    lacking = EFFECTIVENESS @ np.array(short)
    assert rotor_shortfall_n(EFFECTIVENESS, lacking) == pytest.approx(short, abs=1e-9)


def test_the_filter_settles_on_a_held_input_and_differentiates_a_ramp():
    """Within a few per cent: it takes the ramp as a staircase, held over each tick."""
    tick_s = TICK_MS / 1000.0
    f = DifferentiatingFilter(tick_s)
    value, derivative = f.update([2.0])
    assert (value[0], derivative[0]) == (2.0, 0.0)
    for k in range(1, 100):
        value, derivative = f.update([2.0 + 3.0 * k * tick_s])
    assert derivative[0] == pytest.approx(3.0, rel=0.06)


@pytest.mark.parametrize("damping", [1.0, 1.5, 0.0])
def test_the_filter_refuses_a_damping_it_does_not_solve_in_one_line(damping):
    with pytest.raises(ValueError, match="0 < damping < 1"):
        DifferentiatingFilter(0.004, damping=damping)


def _fly(effectiveness, fail_rotor: int | None):
    """Hover on a FC without ESC telemetry, the setpoint carrying the cover with or without the
    effectiveness, rotor `fail_rotor` stopping as it arrives; the commanded thrusts 300 ms later
    and the body's roll and pitch acceleration (rad/s^2) over the 100 ms before."""
    vehicle = Vehicle(Scenario(name="hover", duration_s=1.0, plant=PlantOptions(esc_telemetry=False)), AF)
    vehicle.start(lambda msgs: None)
    vehicle.advance_to(100, lambda msgs: None)
    if fail_rotor is not None:
        vehicle.fc.set_rotor_loss(fail_rotor, 1.0, FaultKind.MOTOR)
    sp = mavlink.MAVLink_m4_setpoint_message(1, 1, 100, 20, [THRUST_N] * 4, [AF.nominal_hip_rad] * 4, [0.0] * 4, 0,
                                             shortfall_gain=COVER.gain.ravel(),
                                             effectiveness_frd_rad_s2_per_n=np.ravel(effectiveness, order="F"))
    vehicle.handle([_from_companion(sp)], lambda msgs: None)
    rates = []
    for t_ms in (300, 400):
        vehicle.advance_to(t_ms, lambda msgs: None)
        rates.append(vehicle.fc.plant.state().rates_frd_rad_s[:2])
    return vehicle.fc.plant.state().thrust_cmd_n, np.linalg.norm(rates[1] - rates[0]) / 0.1


def test_without_esc_telemetry_the_fc_covers_a_stopped_rotor_from_its_gyro():
    """Rotor 4 stops: its diagonal partner, rotor 3, gives way and rotors 1 and 2 take the sum;
    the robot is left with a small fraction of the angular acceleration it has with no measure
    (what the deadband leaves uncovered)."""
    thrust, accel_rad_s2 = _fly(EFFECTIVENESS, fail_rotor=4)
    thrust_unmeasured, accel_unmeasured_rad_s2 = _fly(np.zeros((2, 4)), fail_rotor=4)
    assert thrust_unmeasured == pytest.approx([THRUST_N] * 4, abs=1e-5)
    assert thrust[2] < THRUST_N - 10.0 and min(thrust[:2]) > THRUST_N + 10.0 and thrust[3] == pytest.approx(THRUST_N)
    assert accel_rad_s2 < 0.2 * accel_unmeasured_rad_s2


def test_a_healthy_hover_is_not_covered():
    thrust, _ = _fly(EFFECTIVENESS, fail_rotor=None)
    assert thrust == pytest.approx([THRUST_N] * 4, abs=1e-5)


def _expm(a: np.ndarray) -> np.ndarray:
    """The matrix exponential by scaling and squaring a Taylor series (numpy only)."""
    squarings = max(0, int(np.ceil(np.log2(max(np.abs(a).sum(axis=1).max(), 1e-300)))) + 1)
    scaled, term, out = a / 2 ** squarings, np.eye(len(a)), np.eye(len(a))
    for k in range(1, 30):
        term = term @ scaled / k
        out = out + term
    for _ in range(squarings):
        out = out @ out
    return out


@pytest.mark.parametrize("tick_s, cutoff_rad_s, damping", [(0.004, 188.0, 0.7), (0.001, 60.0, 0.3), (0.01, 300.0, 0.9)])
def test_the_filter_steps_as_the_exponential_of_its_held_input_system(tick_s, cutoff_rad_s, damping):
    """y'' = w^2 (u - y) - 2 zeta w y' with u held over a tick: the closed form against exp(A tick_s)
    of the system with u as a third, constant state."""
    w = cutoff_rad_s
    step = _expm(np.array([[0.0, 1.0, 0.0], [-w * w, -2.0 * damping * w, w * w], [0.0, 0.0, 0.0]]) * tick_s)
    f = DifferentiatingFilter(tick_s, cutoff_rad_s, damping)
    inputs = [[1.0, -2.0], [3.0, 0.5], [-1.0, 4.0], [0.0, 0.0]]
    y, dy = f.update(inputs[0])
    for u in inputs[1:]:
        expected = [step @ np.array([a, b, c]) for a, b, c in zip(y, dy, u)]
        y, dy = f.update(u)
        for (ey, edy, _), got_y, got_dy in zip(expected, y, dy):
            assert got_y == pytest.approx(ey, rel=1e-9, abs=1e-12)
            assert got_dy == pytest.approx(edy, rel=1e-9, abs=1e-9)
