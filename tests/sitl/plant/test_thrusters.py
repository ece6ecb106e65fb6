"""The thrusters: motor, propeller and ESC per rotor, each failure kind's signature, the battery."""


import numpy as np
import pytest

from m4.airframe import ROTOR_COUNT, load_airframe
from sitl.plant.mujoco_plant import Plant, PlantOptions
from m4.scenario import Fault, Scenario
from m4.fault_kind import INJECTABLE, FaultKind
from sitl.plant.thrusters import HEALTHY, Thrusters, figures
from sitl.plant.truth import TruthRecorder, load_truth
from sitl.vehicle import Vehicle

AF = load_airframe()
HOVER_N = AF.hover_thrust_per_rotor_n
NOMINAL = np.full(ROTOR_COUNT, AF.nominal_hip_rad)
V_NOM = AF.battery_nominal_voltage_v


def settled(kind=None, loss=1.0, thrust_n=HOVER_N, voltage_v=V_NOM):
    rotors = Thrusters(AF, HOVER_N, voltage_v)
    if kind is not None:
        rotors.set_fault(3, loss, kind)
    rotors.command(np.full(ROTOR_COUNT, thrust_n))
    rotors.update(voltage_v)
    rotors.advance(50 * AF.motor_time_constant_s)
    return rotors


def test_hover_and_full_throttle_figures_are_the_airframes():
    hover = settled()
    assert hover.thrust_n == pytest.approx(np.full(ROTOR_COUNT, HOVER_N))
    assert hover.thrust_ceiling_n(AF.thrust_max_n) == pytest.approx(np.full(ROTOR_COUNT, AF.thrust_max_n))
    full = settled(thrust_n=AF.thrust_max_n)
    assert full.speed_rad_s == pytest.approx(np.full(ROTOR_COUNT, AF.rotor_speed_max_rad_s))
    assert full.thrust_n == pytest.approx(np.full(ROTOR_COUNT, AF.thrust_max_n))
    assert full.current_a[0] > 2.0 * hover.current_a[0] > 0.0
    # the yaw reaction figures hold: drag torque / thrust is the airframe's k_m
    assert AF.drag_torque_coefficient_n_m_s2 / AF.thrust_coefficient_n_s2 == pytest.approx(AF.moment_coefficient_m)


def test_failure_kinds_leave_their_speed_thrust_and_current_signatures():
    hover = settled()
    w0, i0 = hover.speed_rad_s[3], hover.current_a[3]
    prop = settled(FaultKind.PROPELLER)
    assert prop.thrust_n[3] == 0.0
    assert prop.speed_rad_s[3] > 1.1 * w0                        # the unloaded motor overspeeds
    assert prop.current_a[3] < 0.1 * i0                          # and draws about its no-load current
    motor = settled(FaultKind.MOTOR)
    assert motor.speed_rad_s[3] < 1e-6 * w0 and motor.thrust_n[3] < 1e-9 and motor.current_a[3] == 0.0
    damage = settled(FaultKind.DAMAGE, 0.4)
    assert w0 < damage.speed_rad_s[3] < 1.1 * w0                 # a lighter load: a little faster
    assert damage.thrust_n[3] == pytest.approx(0.6 * AF.thrust_coefficient_n_s2 * damage.speed_rad_s[3] ** 2)
    assert 0.5 * i0 < damage.current_a[3] < i0
    degraded = settled(FaultKind.DEGRADED, 0.4, thrust_n=AF.thrust_max_n)
    assert degraded.thrust_n[3] == pytest.approx(0.6 * HOVER_N)
    assert degraded.thrust_ceiling_n(AF.thrust_max_n)[3] == pytest.approx(0.6 * HOVER_N)
    for rotors in (prop, motor, damage, degraded):              # the other rotors are untouched
        assert rotors.thrust_n[:3] == pytest.approx(settled(thrust_n=rotors._speed_cmd[0] ** 2 * AF.thrust_coefficient_n_s2).thrust_n[:3])


@pytest.mark.parametrize("kind", INJECTABLE)
def test_in_the_plant_propeller_loss_raises_rpm_and_drops_current_motor_stop_drops_both(kind):
    plant = Plant(AF)
    before = plant.state()
    plant.set_rotor_loss(4, 1.0, kind)
    plant.step(0.2)
    s = plant.state()
    assert s.thrust_n[3] < 1e-3 and s.fault_kind[3] == kind and list(s.fault_kind[:3]) == [HEALTHY] * 3
    w0, i0 = before.rotor_speed_rad_s[3], before.esc_current_a[3]
    if kind == FaultKind.PROPELLER:
        assert s.rotor_speed_rad_s[3] > 1.1 * w0 and s.esc_current_a[3] < 0.15 * i0
    elif kind == FaultKind.MOTOR:
        assert s.rotor_speed_rad_s[3] < 0.01 * w0 and s.esc_current_a[3] == 0.0
    plant.set_rotor_loss(4, 0.0)
    plant.step(0.3)
    s = plant.state()
    assert s.fault_kind[3] == HEALTHY and s.rotor_speed_rad_s[3] == pytest.approx(w0, rel=1e-3)


def test_the_thrust_mujoco_applies_is_the_rotor_models_through_every_change():
    plant = Plant(AF)
    for k, (thrust, fault) in enumerate([(20.0, None), (5.0, (FaultKind.DAMAGE, 0.5)), (25.0, (FaultKind.MOTOR, 1)),
                                         (0.0, None), (30.0, (FaultKind.PROPELLER, 1))]):
        plant.command(np.full(ROTOR_COUNT, thrust), NOMINAL)
        if fault:
            plant.set_rotor_loss(k % 4 + 1, fault[1], fault[0])
        for _ in range(5):
            plant.step(0.007)
            assert plant.state().thrust_n == pytest.approx(plant.thrusters.thrust_n, rel=1e-9, abs=1e-12)


def test_a_full_pack_keeps_the_rated_ceiling_and_a_sagging_one_lowers_every_rotors_together():
    steady = Plant(AF)
    steady.step(2.0)
    assert steady.state().battery_voltage_v == V_NOM
    assert steady.state().thrust_limit_n == pytest.approx(np.full(ROTOR_COUNT, AF.thrust_max_n))
    assert steady.state().battery_consumed_mah > 0.0
    tired = Plant(AF, PlantOptions(battery=True, battery_charge=0.15))
    tired.step(0.1)
    first = tired.state()
    tired.step(2.0)
    later = tired.state()
    assert later.battery_voltage_v < first.battery_voltage_v < V_NOM
    assert np.all(later.thrust_limit_n < first.thrust_limit_n) and np.all(first.thrust_limit_n < 0.95 * AF.thrust_max_n)
    assert np.ptp(later.thrust_limit_n) < 1e-9                    # every rotor's ceiling together
    assert later.thrust_n == pytest.approx(np.full(ROTOR_COUNT, HOVER_N), rel=1e-3)   # below it: as commanded
    full = Plant(AF, PlantOptions(battery=True))
    full.step(0.1)
    assert full.state().battery_voltage_v > V_NOM
    assert full.state().thrust_limit_n == pytest.approx(np.full(ROTOR_COUNT, AF.thrust_max_n), rel=0.2)


def test_a_scenario_fault_ends_at_until_s_and_the_rotor_recovers_and_a_second_one_follows():
    faults = (Fault(at_s=0.3, rotor=2, loss=1.0, kind=FaultKind.PROPELLER, until_s=0.6),
              Fault(at_s=0.6, rotor=3, loss=1.0, kind=FaultKind.MOTOR, until_s=0.9))
    vehicle = Vehicle(Scenario(name="intermittent", duration_s=2.0, faults=faults), AF)
    seen = {}
    vehicle.observers.append(lambda t_ms, plant: seen.setdefault(t_ms, plant.state()))
    vehicle.start(lambda msgs: None)
    vehicle.advance_to(1200, lambda msgs: None)
    kinds = {t: tuple(s.fault_kind) for t, s in seen.items()}
    assert kinds[296] == (HEALTHY,) * 4
    assert kinds[300] == (HEALTHY, FaultKind.PROPELLER, HEALTHY, HEALTHY)
    assert kinds[600] == (HEALTHY, HEALTHY, FaultKind.MOTOR, HEALTHY)     # one ends, the next starts
    assert kinds[900] == (HEALTHY,) * 4
    assert seen[588].rotor_speed_rad_s[1] > 1.1 * seen[288].rotor_speed_rad_s[1]
    assert seen[888].rotor_speed_rad_s[2] < 0.01 * seen[288].rotor_speed_rad_s[2]
    assert seen[588].thrust_limit_n[1] == 0.0 and seen[888].thrust_limit_n[2] == 0.0
    assert seen[1200].thrust_limit_n == pytest.approx(np.full(ROTOR_COUNT, AF.thrust_max_n))   # both back


def test_every_rotors_truth_goes_to_the_truth_log(tmp_path):
    plant, recorder = Plant(AF), TruthRecorder(period_ms=10)
    plant.set_rotor_loss(1, 1.0, FaultKind.PROPELLER)
    for t_ms in range(0, 110, 10):
        recorder.observe(t_ms, plant)
        plant.step(0.01)
    recorder.save(tmp_path / "truth.npz")
    truth = load_truth(tmp_path / "truth.npz")
    assert truth.rotor_speed_rad_s.shape == truth.esc_current_a.shape == truth.fault_kind.shape == (11, 4)
    assert list(truth.fault_kind[-1]) == [FaultKind.PROPELLER, HEALTHY, HEALTHY, HEALTHY]
    assert truth.rotor_speed_rad_s[-1, 0] > truth.rotor_speed_rad_s[-1, 1]
    assert truth.esc_current_a[-1, 0] < truth.esc_current_a[-1, 1]
    assert truth.battery_voltage_v == pytest.approx(np.full(11, V_NOM))


def test_the_readme_figures_command_prints_the_settled_rotor_of_every_kind():
    rows = figures(AF)
    assert rows[3].startswith("| healthy | 14.71 N | 5,522 | 14.71 |")
    assert [r.split(" |")[0] for r in rows[5:]] == ["| motor", "| propeller", "| damage 0.5", "| degraded 0.5"]
