"""Flight metrics on synthetic records (no flight): definitions of sitl.flights.metrics."""

import math

import numpy as np
import pytest

from analysis import flight_metrics
from analysis.tlog_reader import read_tlog
from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink, new_mav
from m4.mavlink.tlog import TlogWriter
from m4.mission import Landing, Mission, Waypoint
from m4.scenario import Fault, Scenario, Start
from sitl.flights import metrics
from sitl.flights.records import FaultStatusLog, NmpcLog, read_fault_status
from m4.fault_kind import FaultKind
from sitl.plant.truth import Truth

AF = load_airframe()
HOVER_N = AF.hover_thrust_per_rotor_n
DT = 0.01


def _truth(duration_s=4.0, z=-2.0, wall_rate=1.0, **over) -> Truth:
    t = np.arange(0.0, duration_s + DT / 2, DT)
    n = len(t)
    com = np.tile([0.0, 0.0, z], (n, 1))
    fields = {"time_s": t, "wall_s": t / wall_rate, "pos_ned_m": com.copy(), "com_ned_m": com,
              "vel_ned_m_s": np.zeros((n, 3)), "euler_rad": np.zeros((n, 3)), "rates_frd_rad_s": np.zeros((n, 3)),
              "hip_rad": np.full((n, 4), AF.nominal_hip_rad), "thrust_cmd_n": np.full((n, 4), HOVER_N),
              "thrust_n": np.full((n, 4), HOVER_N), "thrust_limit_n": np.full((n, 4), AF.thrust_max_n),
              "on_ground": np.zeros(n, bool)}
    fields.update(over)
    return Truth(**fields)


def _status(rows) -> FaultStatusLog:
    """rows: (t_s, rotor, state, estimate for that rotor)."""
    est = np.full((len(rows), 4), AF.thrust_max_n)
    for k, (_, rotor, _, e) in enumerate(rows):
        if rotor:
            est[k, rotor - 1] = e
    return FaultStatusLog(time_s=np.array([r[0] for r in rows], float), rotor=np.array([r[1] for r in rows]),
                          state=np.array([r[2] for r in rows]), thrust_max_estimate_n=est,
                          detected_s=np.array([r[0] for r in rows], float), kind=np.zeros(len(rows), int))


HOVER = Scenario(name="hover", duration_s=4.0, start=Start(ned_m=(0.0, 0.0, -2.0)),
                 faults=(Fault(at_s=1.0, rotor=4, loss=1.0),))


def test_tilt_is_the_angle_between_body_z_and_the_vertical():
    e = np.radians([[30.0, 0.0, 70.0], [0.0, -45.0, 0.0], [180.0, 0.0, 0.0]])
    expected = [30.0, 45.0, 180.0]
    assert metrics.tilt_deg(e) == pytest.approx(expected)
    both = np.radians([[30.0, 40.0, 0.0]])
    assert metrics.tilt_deg(both)[0] == pytest.approx(math.degrees(math.acos(math.cos(math.radians(30))
                                                                              * math.cos(math.radians(40)))))


def test_ground_contact_before_the_landing_is_a_crash_and_after_it_a_touchdown():
    t = np.arange(0.0, 5.0, 0.5)
    tilt = np.zeros_like(t)
    late = t >= 4.0
    assert metrics.touchdown_index(t, late, land_s=3.0) == 8
    assert not metrics.crashed(t, late, tilt, land_s=3.0, airborne_end=8)
    early = t == 1.0
    assert metrics.crashed(t, early, tilt, land_s=3.0, airborne_end=len(t) - 1)
    assert metrics.crashed(t, late, tilt, land_s=None, airborne_end=len(t) - 1)     # no landing planned
    upside_down = np.where(t == 2.0, 120.0, 0.0)
    assert metrics.crashed(t, np.zeros_like(late), upside_down, land_s=None, airborne_end=len(t) - 1)


def test_altitude_loss_counts_only_drops_below_the_reference_after_the_fault():
    t = np.arange(0.0, 3.0, DT)
    ref_z = np.full_like(t, -2.0)
    z = ref_z.copy()
    z[(t > 0.2) & (t < 0.4)] += 0.8          # before the fault: ignored
    z[(t > 1.5) & (t < 1.7)] += 0.3          # 0.3 m below after it
    z[(t > 2.0) & (t < 2.2)] -= 0.6          # above the reference: not a loss
    assert metrics.altitude_loss_m(t, z, ref_z, from_s=1.0, airborne_end=len(t) - 1) == pytest.approx(0.3)
    assert metrics.altitude_loss_m(t, ref_z - 0.1, ref_z, from_s=1.0, airborne_end=len(t) - 1) == 0.0


def test_tilt_recovery_is_when_the_tilt_stays_within_10_deg():
    t = np.arange(0.0, 4.0, DT)
    tilt = np.where((t >= 1.0) & (t < 1.5), 40.0, 2.0)
    assert metrics.tilt_recovered_s(t, tilt, from_s=1.0, airborne_end=len(t) - 1) == pytest.approx(0.5, abs=DT)
    still_tilted = np.where(t >= 1.0, 25.0, 0.0)
    assert metrics.tilt_recovered_s(t, still_tilted, from_s=1.0, airborne_end=len(t) - 1) is None


def test_yaw_saturation_time_is_when_the_spin_reaches_90_percent_of_its_final_rate():
    t = np.arange(0.0, 8.0, DT)
    tau = 0.5
    r = np.where(t >= 1.0, -10.0 * (1.0 - np.exp(-(t - 1.0) / tau)), 0.0)
    final = metrics.yaw_rate_final(t, r, until_s=8.0)
    assert final == pytest.approx(-10.0, abs=0.01)
    assert metrics.time_to_yaw_saturation(t, r, 1.0, final) == pytest.approx(tau * math.log(10.0), abs=0.02)
    assert metrics.time_to_yaw_saturation(t, 0.1 * r, 1.0, 0.1 * final) is None     # 1 rad/s: not a spin


LOE = Scenario(name="loe", duration_s=30.0, faults=(Fault(7.0, 4, 0.33), Fault(14.0, 4, 0.66), Fault(21.0, 4, 1.0)))
LOE_STATUS = [(7.1, 4, 1, AF.thrust_max_n), (7.3, 4, 2, 0.67 * HOVER_N), (14.0, 4, 2, 0.67 * HOVER_N),
              (14.6, 4, 2, 0.34 * HOVER_N), (21.0, 4, 2, 0.34 * HOVER_N), (21.4, 4, 2, 0.02)]


def test_each_loss_of_effectiveness_is_detected_when_the_bound_reflects_it():
    """A confirmation still sizing the previous loss is no detection of the next."""
    found = metrics.detections(LOE, _status(LOE_STATUS), AF)
    assert [f["detected_at_s"] for f in found] == [7.3, 14.6, 21.4]
    assert {f["detected_rotor"] for f in found} == {4}
    missed = metrics.detections(LOE, _status([(7.3, 2, 2, 0.67 * HOVER_N)]), AF)
    assert missed[0]["detected_rotor"] == 2 and missed[1]["detected_at_s"] is None


def _status_tlog(path, rows):
    """The companion's M4_FAULT_STATUS of `rows` (as _status's) in a tlog."""
    status = _status(rows)
    mav = new_mav(None, FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    with TlogWriter(path) as tlog:
        for k, t_s in enumerate(status.time_s):
            t_ms = round(t_s * 1000)
            msg = mavlink.MAVLink_m4_fault_status_message(t_ms, int(status.rotor[k]),
                                                          status.thrust_max_estimate_n[k].tolist(), t_ms,
                                                          int(status.state[k]))
            tlog.record(msg.pack(mav))
    return path


def test_a_tlog_alone_finds_the_detections_the_simulators_metrics_find(tmp_path):
    tlog = _status_tlog(tmp_path / "status.tlog", LOE_STATUS)
    truth_path = metrics.detections(LOE, read_fault_status(tlog), AF)
    tlog_path = flight_metrics.detections(read_tlog(tlog), metrics.detection_faults(LOE), HOVER_N)
    assert [f["detected_at_s"] for f in truth_path] == [7.3, 14.6, 21.4]
    assert tlog_path == truth_path


@pytest.mark.parametrize("kind, detected_at_s", [(FaultKind.DAMAGE, 2.1), (FaultKind.DEGRADED, 2.5),
                                                 (FaultKind.MOTOR, 2.9), (FaultKind.PROPELLER, 2.9)])
def test_a_detection_is_judged_against_the_ceiling_each_failure_kind_leaves(kind, detected_at_s):
    """Half a propeller gone leaves the rotor about half its limit (some 15-19 N, hover is 14.7 N):
    the detector's 15 N estimate sizes it, though it would not size a motor degraded to half
    hover thrust, nor a stopped one."""
    scenario = Scenario(name="kinds", duration_s=4.0, faults=(Fault(2.0, 3, 1.0 if kind in (
        FaultKind.MOTOR, FaultKind.PROPELLER) else 0.5, kind),))
    status = _status([(2.1, 3, 2, 0.5 * AF.thrust_max_n), (2.5, 3, 2, 0.5 * HOVER_N), (2.9, 3, 2, AF.thrust_min_n)])
    (found,) = metrics.detections(scenario, status, AF)
    assert (found["detected_at_s"], found["detected_rotor"]) == (detected_at_s, 3)
    healthy_estimate = metrics.detections(scenario, _status([(2.1, 3, 2, AF.thrust_max_n)]), AF)
    assert healthy_estimate[0]["detected_at_s"] is None


def test_nmpc_summary_gives_rate_percentiles_and_failures():
    t = np.arange(0.0, 5.0, 0.02)
    solve = np.linspace(1.0, 3.0, len(t))
    ok = np.ones(len(t), bool)
    ok[[3, 7]] = False
    s = metrics.nmpc_summary(NmpcLog(t, solve, ok))
    assert s["rate_hz"] == pytest.approx(50.0)
    assert s["solve_ms_median"] == pytest.approx(2.0)
    assert 2.9 < s["solve_ms_p99"] <= 3.0
    assert s["solve_failures"] == 2
    assert metrics.nmpc_summary(NmpcLog.empty())["rate_hz"] is None


def test_realtime_factor_is_simulated_over_wall_time_after_the_first_answer():
    t = np.arange(0.0, 10.0, 0.1)
    wall = t / 6.0
    wall[1:] += 30.0                       # the wait for the companion's first answer is not counted
    assert metrics.realtime_factor(t, wall) == pytest.approx(6.0)


def test_a_steady_hover_through_a_fault_survives_and_a_ground_contact_does_not():
    truth = _truth()
    status = _status([(1.2, 4, 2, 0.0)])
    ref = metrics.reference_track(HOVER, AF, truth, status)
    assert np.allclose(ref, truth.com_ned_m)
    m = metrics.flight_metrics(HOVER, "nmpc", AF, truth, ref, status, NmpcLog.empty())
    assert m["survived"] and not m["crashed"] and m["completed"]
    assert m["faults"][0]["detected_at_s"] == 1.2 and m["altitude_loss_m"] == 0.0
    assert m["position_rmse_m"] == 0.0 and m["time_to_yaw_saturation_s"] is None

    contact = truth.on_ground.copy()
    contact[250:] = True
    fallen = _truth(com_ned_m=np.where(contact[:, None], [0.0, 0.0, -0.2], truth.com_ned_m), on_ground=contact)
    m = metrics.flight_metrics(HOVER, "nmpc", AF, fallen, ref, status, NmpcLog.empty())
    assert m["crashed"] and not m["survived"]
    assert m["altitude_loss_m"] == pytest.approx(1.8)


def test_a_landing_is_soft_below_1_m_s_and_the_reference_follows_the_mission():
    mission = Mission(waypoints=(Waypoint((1.0, 0.0, -2.0), 1.0, 0.0),), land=Landing(at_s=2.0, descent_speed_m_s=0.5))
    scenario = Scenario(name="land", duration_s=4.0, mission=mission)
    t = np.arange(0.0, 4.0 + DT / 2, DT)
    ground = t >= 3.5
    vel = np.zeros((len(t), 3))
    vel[(t > 2.5) & (t < 3.5), 2] = 0.5
    truth = _truth(on_ground=ground, vel_ned_m_s=vel)
    ref = metrics.reference_track(scenario, AF, truth, FaultStatusLog.empty())
    assert ref[np.searchsorted(t, 1.9)][0] == pytest.approx(1.0, abs=0.01)     # at the waypoint before landing
    m = metrics.flight_metrics(scenario, "nmpc", AF, truth, ref, FaultStatusLog.empty(), NmpcLog.empty())
    assert m["landed"] and m["touchdown_speed_m_s"] == pytest.approx(0.5)
    assert m["checks"]["soft_landing"]
    vel[(t > 2.5) & (t < 3.5), 2] = 2.0
    hard = metrics.flight_metrics(scenario, "nmpc", AF, _truth(on_ground=ground, vel_ned_m_s=vel), ref,
                                  FaultStatusLog.empty(), NmpcLog.empty())
    assert not hard["checks"]["soft_landing"] and not hard["survived"]


def test_touchdown_speed_is_the_fastest_descent_just_before_contact_not_a_last_bob_upwards():
    from sitl.flights.metrics import touchdown_speed_m_s
    t = np.arange(0.0, 1.0, 0.01)
    vel = np.zeros((len(t), 3))
    vel[:, 2] = 0.4                      # descending at 0.4 m/s (NED: down is +)
    vel[49, 2] = -0.1                    # the hull bobs up on the sample before contact
    assert touchdown_speed_m_s(t, vel, 50) == pytest.approx(0.4)
    assert touchdown_speed_m_s(t, vel, None) is None
