"""The FC's shortfall meter (sitl/fc/shortfall.py) reads, in its ESCs' speed, how far each rotor
falls short of its command, and the FC lets the others cover it when the setpoint asks."""

from __future__ import annotations

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.mavlink import mavlink
from sitl.fc.flight_controller import TICK_MS
from m4.scenario import Scenario
from sitl.fc.shortfall import DEADBAND_N, ShortfallMeter
from m4.fault_kind import FaultKind
from m4.units import RAD_S_TO_RPM
from sitl.plant.thrusters import Thrusters
from sitl.vehicle import Vehicle
from tests.sitl.fc.test_fc_rate_feedback import THRUST_N, _from_companion

AF = load_airframe()
TICK_S = TICK_MS / 1000.0
HOVER_N = AF.hover_thrust_per_rotor_n


def _meter_after(commands_n, fault=None, ticks=50):
    """Fly the plant's rotors through `commands_n` (one (4,) per tick, the last held), rotor 1
    failing as `fault` (loss, kind) from the start; the meter's last reading and the thrust
    the rotors truly give then."""
    rotors = Thrusters(AF, HOVER_N, 14.8)
    meter = ShortfallMeter(AF, TICK_S)
    if fault is not None:
        rotors.set_fault(0, *fault)
    delayed_rpm = [list(rotors.speed_rad_s * RAD_S_TO_RPM)]
    shortfall = None
    for k in range(ticks):
        command = commands_n[min(k, len(commands_n) - 1)]
        rotors.command(command)
        rotors.update(14.8)
        rotors.advance(TICK_S)
        shortfall = meter.update(command, delayed_rpm[-1])      # the speeds arrive a tick late
        delayed_rpm.append(list(rotors.speed_rad_s * RAD_S_TO_RPM))
    return np.array(shortfall), rotors.thrust_n


def test_healthy_rotors_following_steps_of_their_command_fall_short_of_nothing():
    steps = [np.full(4, HOVER_N)] * 5 + [np.array([25.0, 5.0, 14.7, 29.0])] * 10 + [np.array([2.0, 28.0, 14.7, 0.0])]
    for ticks in range(1, 40):
        assert np.all(_meter_after(steps, ticks=ticks)[0] == 0.0)


@pytest.mark.parametrize("kind, loss", [(FaultKind.MOTOR, 1.0), (FaultKind.PROPELLER, 1.0),
                                        (FaultKind.DEGRADED, 0.5), (FaultKind.DAMAGE, 0.5)])
def test_a_failed_rotor_falls_short_by_what_it_no_longer_gives(kind, loss):
    """Even a lighter (chipped) or missing propeller, on a motor that turns faster for it."""
    shortfall, thrust_n = _meter_after([np.full(4, HOVER_N)], (loss, kind))
    assert shortfall[0] == pytest.approx(HOVER_N - thrust_n[0] - DEADBAND_N, abs=0.1)
    assert thrust_n[0] < HOVER_N - 2 * DEADBAND_N
    assert np.all(shortfall[1:] == 0.0)


def _fly(cover_gain, fail_rotor: int | None):
    vehicle = Vehicle(Scenario(name="hover", duration_s=1.0), AF)
    vehicle.start(lambda msgs: None)
    vehicle.advance_to(100, lambda msgs: None)
    if fail_rotor is not None:
        vehicle.fc.set_rotor_loss(fail_rotor, 1.0, FaultKind.MOTOR)
    sp = mavlink.MAVLink_m4_setpoint_message(1, 1, 100, 20, [THRUST_N] * 4, [AF.nominal_hip_rad] * 4, [0.0] * 4, 0,
                                             shortfall_gain=cover_gain)
    vehicle.handle([_from_companion(sp)], lambda msgs: None)
    vehicle.advance_to(160, lambda msgs: None)
    return vehicle.fc.measured_state(160).thrust_cmd_n


COVER_4 = np.zeros((4, 4))
COVER_4[:, 3] = [1.0, 1.0, -1.0, 0.0]           # rotor 4 short: 1 and 2 up, 3 down


def test_the_fc_covers_a_rotor_its_escs_show_stopped_as_the_setpoint_asks():
    thrust = _fly(COVER_4.ravel(), fail_rotor=4)
    cover = thrust[0] - THRUST_N
    assert cover > 0.5 * (THRUST_N - DEADBAND_N)             # most of it within 60 ms
    assert thrust == pytest.approx([THRUST_N + cover, THRUST_N + cover, THRUST_N - cover, THRUST_N], abs=1e-3)


def test_no_cover_without_the_field_or_without_a_shortfall():
    assert _fly(np.zeros(16), fail_rotor=4) == pytest.approx([THRUST_N] * 4, abs=1e-5)
    assert _fly(COVER_4.ravel(), fail_rotor=None) == pytest.approx([THRUST_N] * 4, abs=1e-5)


def test_setpoints_arriving_at_the_fcs_ticks_do_not_make_a_healthy_rotor_slowing_down_look_short():
    """Each setpoint runs the FC's tick at its instant once more; a meter aged by that second
    tick expects rotor 4 slower than it is while the plan winds it down, reads it as unloaded
    and has the others cover it."""
    vehicle = Vehicle(Scenario(name="hover", duration_s=1.0), AF)
    vehicle.start(lambda msgs: None)
    covered = []
    for k, rotor_4_n in enumerate([THRUST_N, 8.0, 4.0, 2.0, 2.0, 2.0]):
        t_ms = 100 + 20 * k
        vehicle.advance_to(t_ms, lambda msgs: None)
        thrust = [THRUST_N, THRUST_N, THRUST_N, rotor_4_n]
        sp = mavlink.MAVLink_m4_setpoint_message(1, 1, t_ms, 20, thrust, [AF.nominal_hip_rad] * 4, [0.0] * 4, 0,
                                                 shortfall_gain=COVER_4.ravel())
        vehicle.handle([_from_companion(sp)], lambda msgs: None)
        for tick_ms in range(t_ms + TICK_MS, t_ms + 20, TICK_MS):
            vehicle.advance_to(tick_ms, lambda msgs: None)
            covered.append(vehicle.fc.measured_state(tick_ms).thrust_cmd_n[:3] - THRUST_N)
    assert np.abs(covered).max() < 1e-5            # THRUST_N as float32 carries it
