"""ESC telemetry as an ArduPilot FC reports it: DShot RPM, serial current/voltage, delay, units."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.mavlink import mavlink
from sitl.fc.esc_telemetry import EscTelemetry, dshot_rpm
from sitl.plant.mujoco_plant import Plant
from m4.scenario import Fault, PlantOptions, Scenario
from sitl.serve import ServeOptions
from sitl.standin_companion import StandInCompanion, served
from m4.fault_kind import FaultKind
from m4.units import RAD_S_TO_RPM

AF = load_airframe()
m = mavlink


def test_dshot_rpm_is_the_period_encoding_a_few_tenths_of_a_percent_fine_and_zero_when_too_slow():
    rpm = np.array([5522.5, 7885.0, 0.0, 40.0])
    decoded = dshot_rpm(rpm, AF.motor_pole_pairs)
    assert decoded[:2] == pytest.approx(rpm[:2], rel=3e-3) and list(decoded[:2]) != list(rpm[:2])
    assert list(decoded[2:]) == [0.0, 0.0]             # stopped; 40 rpm is beyond the 16-bit period
    steps = np.unique(dshot_rpm(np.linspace(5500.0, 5545.0, 400), AF.motor_pole_pairs))
    assert 2 <= len(steps) <= 10                        # a few quantisation steps over 45 rpm


def test_samples_reach_the_fc_after_the_telemetry_delay_and_serial_data_at_its_own_rate():
    esc, plant = EscTelemetry(AF, tick_ms=4), Plant(AF)
    truth = plant.state()
    delay_ms = round(AF.esc_telemetry_delay_s * 1000)
    esc.sample(0, truth)
    assert esc.report(delay_ms - 1).rpm == [0] * 4
    hover_rpm = int(dshot_rpm(truth.rotor_speed_rad_s * RAD_S_TO_RPM, AF.motor_pole_pairs)[0])
    assert esc.report(delay_ms).rpm == [hover_rpm] * 4
    faster = dataclasses.replace(truth, rotor_speed_rad_s=1.2 * truth.rotor_speed_rad_s)
    for t_ms in range(4, 1001, 4):
        esc.sample(t_ms, faster)
        esc.sample(t_ms, truth)                         # a second call at one instant is ignored
    report = esc.report(1000 + delay_ms)
    assert report.rpm[0] > 1.19 * hover_rpm
    assert all(AF.esc_serial_telemetry_hz <= c <= AF.esc_serial_telemetry_hz + 1 for c in report.count)   # 1 s
    assert report.voltage == [int(100 * AF.battery_nominal_voltage_v)] * 4
    assert report.current == [int(100 * truth.esc_current_a[0])] * 4
    assert report.totalcurrent[0] == int(truth.esc_current_a[0] * 1.0 / 3.6)   # ESC 1 polled at 1 s: mAh of 1 s
    assert report.temperature == [int(AF.esc_ambient_temperature_c)] * 4      # degC: warming by a quarter degree
    for t_ms in range(1004, 60_001, 4):
        esc.sample(t_ms, truth)
    warm = AF.esc_ambient_temperature_c + AF.esc_temperature_rise_c_per_a * truth.esc_current_a[0] * (1 - np.exp(-1))
    assert esc.report(60_000 + delay_ms).temperature[0] == pytest.approx(warm, abs=1.0)    # a minute: one time constant


def test_the_rpm_read_alone_is_the_reports_at_every_instant():
    """The FC reads the RPM at every tick without the rest of the report (EscTelemetry.rpm)."""
    alone, whole, plant = EscTelemetry(AF, tick_ms=4), EscTelemetry(AF, tick_ms=4), Plant(AF)
    truth = plant.state()
    for t_ms in range(0, 200, 4):
        faster = dataclasses.replace(truth, rotor_speed_rad_s=(1.0 + t_ms / 1000.0) * truth.rotor_speed_rad_s)
        alone.sample(t_ms, faster)
        whole.sample(t_ms, faster)
        for now_ms in (t_ms, t_ms + 1, t_ms + 3):
            assert alone.rpm(now_ms) == whole.report(now_ms).rpm
    assert alone.rpm(200) != [0] * 4


def _serve(scenario: Scenario, seconds: float):
    companion = StandInCompanion(period_ms=20)
    with served(companion, ServeOptions(scenario=scenario, duration_s=seconds)):
        assert companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= round(seconds * 1000), 60.0)
    return companion


def _esc_by_instant(companion):
    """ESC_TELEMETRY_1_TO_4 keyed by the time of the frame that follows it (it has no timestamp)."""
    out, pending = {}, []
    for msg in companion.received:
        if msg.get_type() == "ESC_TELEMETRY_1_TO_4":
            pending.append(msg)
        elif msg.get_type() == "ATTITUDE" and pending:
            out[msg.time_boot_ms] = pending[-1]
            pending = []
    return out


def test_the_fc_streams_esc_telemetry_over_udp_in_arduPilot_units_and_a_lost_propeller_shows():
    scenario = Scenario(name="prop", duration_s=60.0,
                        faults=(Fault(at_s=0.6, rotor=2, loss=1.0, kind=FaultKind.PROPELLER),))
    companion = _serve(scenario, 0.8)
    esc = _esc_by_instant(companion)
    assert 38 <= sum(1 for t in esc if 0 < t <= 800) <= 42                # 50 Hz
    hover_rpm = np.sqrt(AF.hover_thrust_per_rotor_n / AF.thrust_coefficient_n_s2) * RAD_S_TO_RPM
    before, after = esc[580], esc[780]
    assert before.rpm == pytest.approx([hover_rpm] * 4, rel=0.01)
    assert before.voltage == [int(100 * AF.battery_nominal_voltage_v)] * 4      # cV
    assert 1000 < before.current[1] < 2500                                      # cA: about 15 A at hover
    assert min(before.count) >= 4 and before.totalcurrent[1] >= 1               # mAh
    assert after.rpm[1] > 1.1 * before.rpm[1]                                   # the motor overspeeds
    assert after.current[1] < 0.2 * before.current[1]                           # with no load to carry
    pack = companion.of_type("SYS_STATUS")[0]                                   # the power module
    assert pack.voltage_battery == round(1000 * AF.battery_nominal_voltage_v)
    assert pack.current_battery == pytest.approx(4 * before.current[1], rel=0.01) and pack.battery_remaining == 100


def test_without_esc_telemetry_the_fc_never_sends_it():
    scenario = Scenario(name="no-esc", duration_s=60.0, plant=PlantOptions(esc_telemetry=False))
    companion = _serve(scenario, 0.5)
    assert not companion.of_type("ESC_TELEMETRY_1_TO_4")
    assert companion.of_type("M4_THRUSTER_STATUS")                              # the commands still go out
