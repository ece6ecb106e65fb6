"""The fault detector on synthetic ESC telemetry (RPM, current, voltage) at 50 Hz: the rotor,
the kind, the ceiling, a sagging battery, an intermittent fault and a second one."""

import math
import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from m4.airframe import ROTOR_COUNT, load_airframe
from companion.core import rom
from companion.core.esc_evidence import EscSample, PropellerModel, RotorCondition, read_escs
from companion.core.fault_detector import FaultDetector, FaultState
from m4.fault_kind import FaultKind

AF = load_airframe()
HOVER_N = AF.hover_thrust_per_rotor_n
DT = 0.02
PROP = PropellerModel(thrust_coefficient_n_s2=4.4e-5, speed_max_rad_s=math.sqrt(30.0 / 4.4e-5), voltage_nominal_v=14.8)
LOAD = 9.0e-10          # current * voltage / rpm^3 of a loaded propeller (about 150 W at hover)


class Escs:
    """Four rotors whose speed follows the command (as thrust) through the motor lag, within a
    per-rotor speed ceiling; a propeller can be missing (the motor then runs 25 % faster, unloaded)
    or chipped (blade_share of its thrust and load left at a speed: it runs 18 % x the share lost
    faster on its lighter load). stale_current_a: a current the ESC reports instead of its load's
    (NaN: none), e.g. one sampled while it braked the rotor, held until the next poll."""

    def __init__(self, voltage_v=14.8):
        self.rpm = PROP.rpm(np.full(ROTOR_COUNT, HOVER_N))
        self.rpm_max = np.full(ROTOR_COUNT, np.inf)
        self.unloaded = np.zeros(ROTOR_COUNT, dtype=bool)
        self.blade_share = np.ones(ROTOR_COUNT)
        self.stale_current_a = np.full(ROTOR_COUNT, np.nan)
        self.voltage_v = voltage_v

    def step(self, t_s, cmd_n) -> EscSample:
        ceiling_rpm = PROP.rpm(np.full(ROTOR_COUNT, PROP.ceiling_n(self.voltage_v)))
        overspeed = np.where(self.unloaded, 1.25, 1.0 + 0.18 * (1.0 - self.blade_share))
        goal = np.minimum(np.minimum(PROP.rpm(cmd_n), self.rpm_max), ceiling_rpm) * overspeed
        self.rpm = goal + (self.rpm - goal) * math.exp(-DT / AF.motor_time_constant_s)
        current = np.where(self.unloaded, 1.0, self.blade_share * LOAD * self.rpm**3 / self.voltage_v)
        current = np.where(np.isfinite(self.stale_current_a), self.stale_current_a, current)
        return EscSample(time_s=t_s, rpm=self.rpm.copy(), current_a=current, voltage_v=np.full(ROTOR_COUNT, self.voltage_v))

    def thrust_n(self):
        return np.where(self.unloaded, 0.0, self.blade_share * PROP.thrust_n(self.rpm))


STEP = rom.build_rom(AF, DT, 4).step


def flown(x, before_n, after_n):
    """The ROM moved over one frame by the thrusts the rotors delivered (their average)."""
    u = np.zeros(rom.NU)
    u[rom.THRUST] = (before_n + after_n) / 2
    return np.array(STEP(x, u, np.zeros(rom.ND))).ravel()


def fly(escs, commands, events=(), said=None):
    """The robot moved by what the rotors deliver, the detector reading it and the ESCs;
    events: {frame: fn(escs)}, applied at the start of that frame's interval; said: a list to
    which each frame's cannot_confirm() before it is read is appended."""
    det = FaultDetector(AF, propeller=PROP)
    x, statuses = rom.hover_state(AF), []
    for k, cmd in enumerate(commands):
        if k in events:
            events[k](escs)
        if said is not None:
            said.append(det.cannot_confirm(k * DT, np.full(ROTOR_COUNT, AF.thrust_max_n)))
        before = escs.thrust_n()
        sample = escs.step(k * DT, cmd)
        x = flown(x, before, escs.thrust_n())
        statuses.append(det.update(k * DT, x, cmd, esc=sample))
    return statuses


def hover(n):
    return [np.full(ROTOR_COUNT, HOVER_N)] * n


def first_confirmed(statuses):
    return next((k, s) for k, s in enumerate(statuses) if s.state is FaultState.CONFIRMED)


def test_a_stopped_motor_is_confirmed_within_two_frames_with_its_kind_and_a_zero_ceiling():
    def stop(e):
        e.rpm_max[2] = 0.0
    statuses = fly(Escs(), hover(20), {5: stop})
    k, s = first_confirmed(statuses)
    assert s.rotor == 3 and s.kind is FaultKind.MOTOR and s.message == "thrust loss rotor 3 (motor)"
    assert (k - 5 + 1) * DT <= 0.05 + 1e-9               # the fault acts during the interval ending at frame 5
    assert s.thrust_max_estimate_n[2] == pytest.approx(0.0, abs=0.5)
    assert s.thrust_bound_n[2] == pytest.approx(s.thrust_max_estimate_n[2] + 2.0)
    assert np.allclose(np.delete(s.thrust_max_estimate_n, 2), AF.thrust_max_n)


def test_a_lost_propeller_overspeeds_its_motor_and_is_told_from_a_stopped_one():
    def lose(e):
        e.unloaded[0] = True
    statuses = fly(Escs(), hover(20), {5: lose})
    k, s = first_confirmed(statuses)
    assert s.rotor == 1 and s.kind is FaultKind.PROPELLER
    assert (k - 5 + 1) * DT <= 0.10 + 1e-9
    assert s.thrust_max_estimate_n[0] == pytest.approx(AF.thrust_min_n)


def chip(e):
    e.blade_share[1] = 0.5


def test_a_damaged_propeller_is_sized_by_the_thrust_it_gives_at_its_speed():
    """Rotor 2's propeller loses half its blade: half the thrust at a speed, 9 % faster on the
    lighter load; its ESC sees nothing wrong, the residual does: a damaged propeller, its ceiling
    what a full command now gives, within 10 % of hover thrust from confirmation on."""
    statuses = fly(Escs(), hover(40), {5: chip})
    k, s = first_confirmed(statuses)
    assert s.rotor == 2 and s.kind is FaultKind.DAMAGE and (k - 5 + 1) * DT <= 0.12 + 1e-9
    ceiling_n = 0.5 * 1.09**2 * AF.thrust_max_n
    assert all(abs(s.thrust_max_estimate_n[1] - ceiling_n) <= 0.1 * HOVER_N for s in statuses[k:])


def test_a_damaged_propeller_stays_damaged_when_a_current_read_while_braking_says_unloaded():
    """The damaged propeller above, confirmed; then its ESC reports a current sampled while it
    braked the rotor (0.3 A, held until the next poll 0.1 s on): on a rotor turning fast that
    reads as unloaded, yet the residual measures half its thrust: it stays a damaged propeller
    with its estimate, never a lost one."""
    def brake(e):
        e.stale_current_a[1] = 0.3
    def poll(e):
        e.stale_current_a[1] = np.nan
    statuses = fly(Escs(), hover(40), {5: chip, 20: brake, 25: poll})
    k, _ = first_confirmed(statuses)
    assert k < 20
    assert all(s.kind is FaultKind.DAMAGE and s.message == "thrust loss rotor 2 (damage)" for s in statuses[k:])
    assert min(s.thrust_max_estimate_n[1] for s in statuses[k:]) >= 0.3 * AF.thrust_max_n


def test_a_damaged_propeller_spinning_up_on_a_current_from_before_is_not_taken_for_a_lost_one():
    """Rotor 2's propeller loses half its blade while the controller asks it for 60 % more (the
    campaign's rotor 2 in hover). Its ESC's serial current is the one it measured at the hover
    speed, held for the 0.1 s until the next poll while the rotor spins up: against the new speed
    its load index is 0.19 of the others', a collapsed load on a rotor turning 9 % fast. Judged
    against the speed it was measured at, it is half a load: a damaged propeller, sized as one."""
    def chip_on_a_held_current(e):
        chip(e)
        e.stale_current_a[1] = 0.5 * LOAD * PROP.rpm(HOVER_N) ** 3 / e.voltage_v
    def poll(e):
        e.stale_current_a[1] = np.nan
    commands = hover(5) + [np.array([HOVER_N, 1.6 * HOVER_N, HOVER_N, HOVER_N])] * 35
    statuses = fly(Escs(), commands, {5: chip_on_a_held_current, 10: poll})
    k, s = first_confirmed(statuses)
    assert s.rotor == 2 and (k - 5 + 1) * DT <= 0.12 + 1e-9
    assert all(s.kind is FaultKind.DAMAGE for s in statuses[k:])
    assert min(s.thrust_max_estimate_n[1] for s in statuses[k:]) >= 0.3 * AF.thrust_max_n


def test_a_motor_that_cannot_reach_its_speed_is_sized_by_the_speed_it_reaches():
    ceiling_n = 0.5 * HOVER_N
    def weaken(e):
        e.rpm_max[1] = PROP.rpm(ceiling_n)
    statuses = fly(Escs(), hover(20), {5: weaken})
    _, s = first_confirmed(statuses)
    assert s.rotor == 2 and s.kind is FaultKind.DEGRADED
    assert s.thrust_max_estimate_n[1] == pytest.approx(ceiling_n, abs=0.1 * HOVER_N)


def test_a_sagging_battery_that_caps_every_rotor_is_no_rotors_fault():
    """Rotor 1 asked for 28 N while the pack has sagged so far that a full command gives 21 N:
    it falls 7 N short, alone, but at the ceiling every rotor shares."""
    escs = Escs(voltage_v=14.8 * math.sqrt(21.0 / 30.0))
    cmd = np.array([28.0, HOVER_N, HOVER_N, 10.0])
    statuses = fly(escs, [cmd] * 30)
    assert escs.thrust_n()[0] == pytest.approx(21.0, abs=0.1)
    assert all(s.state is FaultState.HEALTHY for s in statuses)


def test_fast_command_steps_the_motor_lag_delays_raise_no_alarm():
    step = np.full(ROTOR_COUNT, HOVER_N)
    step[0] = AF.thrust_max_n
    statuses = fly(Escs(), hover(5) + [step] * 10 + hover(10))
    assert all(s.state is FaultState.HEALTHY for s in statuses)


def test_an_intermittent_fault_is_followed_back_up_and_a_second_fault_is_caught():
    """Rotor 4 stops, comes back 0.4 s later and the estimate climbs back while the controller
    asks it for its bound up to a hover share; healthy again, then rotor 2 loses its propeller."""
    det = FaultDetector(AF, propeller=PROP)
    escs = Escs()
    events = {5: lambda e: e.rpm_max.__setitem__(3, 0.0), 25: lambda e: e.rpm_max.__setitem__(3, np.inf),
              80: lambda e: e.unloaded.__setitem__(1, True)}
    statuses = []
    for k in range(100):
        if k in events:
            events[k](escs)
        bound = det.status.thrust_bound_n
        cmd = np.minimum(np.full(ROTOR_COUNT, HOVER_N), bound)
        cmd[3] = min(bound[3], HOVER_N)
        sample = escs.step(k * DT, cmd)   # the robot held level: the ESCs' evidence decides
        statuses.append(det.update(k * DT, rom.hover_state(AF), cmd, esc=sample))
    assert statuses[10].state is FaultState.CONFIRMED and statuses[10].rotor == 4
    back = next(k for k in range(25, 100) if statuses[k].state is FaultState.HEALTHY)
    assert (back - 25) * DT <= 0.8
    assert all(s.state is FaultState.HEALTHY for s in statuses[back:80])
    k, s = first_confirmed(statuses[80:])
    assert s.rotor == 2 and s.kind is FaultKind.PROPELLER and k * DT <= 0.1


def test_esc_frames_without_speed_or_too_old_are_not_evidence():
    det = FaultDetector(AF, propeller=PROP)
    cmd = np.full(ROTOR_COUNT, HOVER_N)
    dead = EscSample(time_s=0.0, rpm=np.zeros(ROTOR_COUNT), current_a=np.zeros(ROTOR_COUNT),
                     voltage_v=np.full(ROTOR_COUNT, 14.8))
    for k in range(20):                       # the same old frame, repeated: read once, then too old
        status = det.update(k * DT, rom.hover_state(AF), cmd, esc=dead)
    assert status.state is FaultState.HEALTHY


def test_a_collapsed_load_marks_a_rotor_turning_fast_unloaded_but_a_stale_current_alone_does_not():
    """Rotor 3 turns 8 % fast on 1 A: its propeller is gone before the overspeed threshold.
    Rotor 2 turns as asked on a current from before (serial telemetry is polled in turn), and
    rotor 4's current was never polled (0): both normal."""
    rpm = PROP.rpm(np.full(ROTOR_COUNT, HOVER_N))
    current = LOAD * rpm**3 / 14.8
    rpm[2] *= 1.08
    current[1], current[2], current[3] = 1.0, 1.0, 0.0
    reading = read_escs(EscSample(0.0, rpm, current, np.full(ROTOR_COUNT, 14.8)), np.full(ROTOR_COUNT, HOVER_N), PROP)
    assert reading.condition == (RotorCondition.NORMAL, RotorCondition.NORMAL, RotorCondition.UNLOADED,
                                 RotorCondition.NORMAL)
    assert reading.thrust_n[2] == 0.0 and reading.thrust_n[1] == pytest.approx(HOVER_N)


FOUR_NUMBERS = st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=4, max_size=4).map(np.array)


@given(rpm=FOUR_NUMBERS, current=FOUR_NUMBERS, voltage=FOUR_NUMBERS)
def test_any_numbers_are_read_without_overflow_and_no_thrust_is_infinite(rpm, current, voltage):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        reading = read_escs(EscSample(0.0, rpm, current, voltage), np.full(ROTOR_COUNT, HOVER_N), PROP)
    assert not np.any(np.isinf(reading.thrust_n))


def test_a_speed_no_esc_telemetry_can_carry_is_not_reported():
    rpm = PROP.rpm(np.full(ROTOR_COUNT, HOVER_N))
    current = LOAD * rpm**3 / 14.8
    rpm[0], rpm[1] = 1e200, -3000.0
    reading = read_escs(EscSample(0.0, rpm, current, np.full(ROTOR_COUNT, 14.8)), np.full(ROTOR_COUNT, HOVER_N), PROP)
    assert np.all(np.isnan(reading.thrust_n[:2])) and reading.condition[:2] == (RotorCondition.NORMAL,) * 2
    assert reading.thrust_n[2] == pytest.approx(HOVER_N)


def test_a_rotor_commanded_down_to_nothing_spins_down_as_fast_as_its_speed_lag_without_alarm():
    """The FC's cover drops the lost rotor's diagonal partner to nothing between our frames: its
    speed follows the motor lag, so its thrust (speed squared) falls at twice that rate; that
    is no shortfall."""
    drop = np.full(ROTOR_COUNT, HOVER_N)
    drop[1] = AF.thrust_min_n
    statuses = fly(Escs(), hover(5) + [drop] * 10)
    assert all(s.state is FaultState.HEALTHY for s in statuses)


def test_while_a_damaged_propeller_is_confirmed_its_frames_are_read_before_the_solve_a_lost_ones_after():
    """A damaged propeller's frame may lower its ceiling at once or find it lost after all: it
    must bound its own setpoint. A stopped motor's ceiling is the least already: its frames may
    wait until after the send."""
    said_damaged, said_stopped = [], []
    damaged = fly(Escs(), hover(30), {5: chip}, said_damaged)
    def stop(e):
        e.rpm_max[2] = 0.0
    stopped = fly(Escs(), hover(30), {5: stop}, said_stopped)
    k, s = first_confirmed(damaged)
    assert s.kind is FaultKind.DAMAGE and not any(said_damaged[k + 1:])
    k, s = first_confirmed(stopped)
    assert s.kind is FaultKind.MOTOR and all(said_stopped[k + 1:])
