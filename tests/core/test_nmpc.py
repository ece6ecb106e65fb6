"""The NMPC's SQP against its specification: bounds, constraints, fallback, warm start, IPOPT
(the real-time iteration: test_nmpc_rti.py)."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from m4.airframe import load_airframe
from companion.core import nmpc as nmpc_module
from companion.core import rom
from companion.core.nmpc import Nmpc
from companion.core.nmpc_config import NmpcConfig, NmpcWeights
from research.nmpc_ipopt import IpoptReference

AF = load_airframe()
N = 5
FULL = np.full(4, AF.thrust_max_n)
ROTOR_4_OFF = np.array([AF.thrust_max_n] * 3 + [0.0])
RIGHT, LEFT = AF.same_side_pairs


@pytest.fixture(scope="module")
def nmpc():
    return Nmpc(AF, NmpcConfig(scheme="sqp"))


@pytest.fixture(scope="module")
def fixed():
    return Nmpc(AF, NmpcConfig(scheme="sqp", fixed_hip_rad=math.radians(45)))


def hover_ref():
    return np.tile(rom.hover_state(AF), (N + 1, 1))


def perturbed(rng, scale=1.0):
    x = rom.hover_state(AF)
    x[rom.P] += scale * rng.uniform(-1, 1, 3)
    x[rom.EULER] += scale * rng.uniform(-0.4, 0.4, 3)
    x[rom.V] += scale * rng.uniform(-2, 2, 3)
    x[rom.RATES] += scale * rng.uniform(-3, 3, 3)
    x[rom.HIP_RATE] += scale * rng.uniform(-2, 2, 4)
    return x


def assert_within(nmpc, res, thrust_bound):
    lo, hi = nmpc.input_bounds(thrust_bound)
    assert np.all(np.isfinite(res.u)) and np.all(np.isfinite(res.u_pred)) and np.all(np.isfinite(res.x_pred))
    assert np.all(res.u_pred >= lo - 1e-9) and np.all(res.u_pred <= hi + 1e-9)


def test_commands_stay_within_the_bounds_from_rough_states(nmpc):
    rng = np.random.default_rng(1)
    nmpc.reset()
    for k in range(12):
        thrust_bound = ROTOR_4_OFF if k % 2 else rng.uniform(5.0, AF.thrust_max_n, 4)
        res = nmpc.solve(perturbed(rng), hover_ref(), thrust_bound)
        assert res.ok and not res.fallback
        assert_within(nmpc, res, thrust_bound)


ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(state_noise=st.lists(st.one_of(st.floats(-3, 3), ANY_FLOAT), min_size=rom.NX, max_size=rom.NX),
       thrust_bound=st.lists(st.one_of(st.floats(-5, 40), ANY_FLOAT), min_size=4, max_size=4),
       disturbance=st.lists(st.one_of(st.floats(-20, 20), ANY_FLOAT), min_size=6, max_size=6))
def test_whatever_it_is_given_the_command_is_finite_and_within_the_bounds(nmpc, state_noise, thrust_bound,
                                                                             disturbance):
    x0 = rom.hover_state(AF) + np.array(state_noise)
    res = nmpc.solve(x0, hover_ref(), thrust_bound, disturbance)
    lo, hi = nmpc.input_bounds(thrust_bound)
    assert np.all(np.isfinite(res.u)) and np.all(res.u >= lo) and np.all(res.u <= hi)
    assert np.all(np.isfinite(res.u_pred))
    assert res.fallback == (not res.ok)


def test_a_lost_rotor_is_only_a_lower_bound_and_gets_no_thrust(nmpc):
    nmpc.reset()
    res = nmpc.solve(rom.hover_state(AF), hover_ref(), ROTOR_4_OFF)
    assert res.ok
    assert np.all(res.u_pred[:, 3] == pytest.approx(0.0, abs=1e-9))
    assert res.u[:3].sum() > 0.85 * AF.total_mass_kg * AF.gravity_m_s2   # the others carry the weight


@pytest.mark.parametrize("where", ["x0", "x_ref"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_state_or_reference_gives_a_bounded_fallback(nmpc, where, bad):
    x0, ref = rom.hover_state(AF), hover_ref()
    (x0 if where == "x0" else ref)[3] = bad
    res = nmpc.solve(x0, ref, ROTOR_4_OFF)
    assert res.fallback and not res.ok and res.status == "invalid_input"
    assert_within(nmpc, res, ROTOR_4_OFF)


def test_a_state_too_wild_to_roll_out_gives_a_bounded_fallback(nmpc):
    x0 = rom.hover_state(AF)
    x0[rom.RATES] = 1e200
    nmpc.reset()
    res = nmpc.solve(x0, hover_ref(), ROTOR_4_OFF)
    assert res.fallback and not res.ok
    assert_within(nmpc, res, ROTOR_4_OFF)


def test_non_finite_bounds_and_disturbance_are_survived(nmpc):
    nmpc.reset()
    res = nmpc.solve(rom.hover_state(AF), hover_ref(), [math.nan, math.inf, 20.0, -5.0],
                     disturbance=[math.nan, 0, 0, 0, math.inf, 0])
    assert res.ok
    assert_within(nmpc, res, [AF.thrust_max_n, AF.thrust_max_n, 20.0, 0.0])
    assert res.u[3] == pytest.approx(0.0, abs=1e-9)      # a negative limit means off


def test_solver_failure_falls_back_to_a_bounded_command_that_stops_the_legs(nmpc, monkeypatch):
    def failing(*args, **kwargs):
        return np.full(N * rom.NU, np.nan), math.nan, -2, {"lam": np.zeros(1)}

    monkeypatch.setattr(nmpc_module.daqp, "solve", failing)
    x0 = rom.hover_state(AF)
    x0[rom.HIP_RATE] = [3.0, -3.0, 0.1, -0.1]
    res = nmpc.solve(x0, hover_ref(), ROTOR_4_OFF)
    assert res.fallback and not res.ok and res.status == "qp_failed"
    assert_within(nmpc, res, ROTOR_4_OFF)
    assert np.all(np.sign(res.u[rom.HIP_ACCEL]) == -np.sign(x0[rom.HIP_RATE]))   # braking


def test_side_sum_and_hip_range_hold_in_the_predictions(nmpc):
    # Right-side legs swinging out fast: with no braking the sum would pass 110 deg.
    x0 = rom.hover_state(AF)
    a, b = RIGHT
    x0[rom.HIP.start + a], x0[rom.HIP.start + b] = math.radians(60), math.radians(40)
    x0[rom.HIP_RATE.start + a], x0[rom.HIP_RATE.start + b] = 3.0, 3.0
    coasting = x0[rom.HIP] + N * 0.1 * x0[rom.HIP_RATE]
    assert coasting[a] + coasting[b] > AF.same_side_sum_max_rad + 0.5
    nmpc.reset()
    res = nmpc.solve(x0, hover_ref(), ROTOR_4_OFF)
    hips = res.x_pred[1:, rom.HIP]
    assert res.ok
    assert np.all(hips >= AF.hip_min_rad - 1e-6) and np.all(hips <= AF.hip_max_rad + 1e-6)
    for side in (RIGHT, LEFT):
        sums = hips[:, side[0]] + hips[:, side[1]]
        assert np.all(sums <= AF.same_side_sum_max_rad + 1e-6)
    right = hips[:, a] + hips[:, b]
    assert right.max() > AF.same_side_sum_max_rad - math.radians(2)    # the constraint was active


def test_roll_and_pitch_limits_hold_in_the_predictions():
    limit = math.radians(8)
    m = Nmpc(AF, NmpcConfig(scheme="sqp", roll_pitch_max_rad=limit))
    x0 = rom.hover_state(AF)
    x0[rom.P] += [3.0, -3.0, 0.0]                 # far away: the unconstrained plan tilts a lot more
    res = m.solve(x0, hover_ref(), FULL)
    assert res.ok
    tilt = np.abs(res.x_pred[1:, rom.EULER.start:rom.EULER.start + 2])
    assert tilt.max() <= limit + math.radians(0.2)
    assert tilt.max() >= limit - math.radians(1)


def test_warm_start_gives_the_same_answer_as_a_cold_start(nmpc):
    rng = np.random.default_rng(4)
    x0 = perturbed(rng, 0.5)
    nmpc.reset()
    cold = nmpc.solve(x0, hover_ref(), ROTOR_4_OFF)
    warm = nmpc.solve(x0, hover_ref(), ROTOR_4_OFF)
    assert cold.ok and warm.ok
    assert warm.u[rom.THRUST] == pytest.approx(cold.u[rom.THRUST], abs=0.2)           # N
    # rad/s^2, of +-50: the cost is flat along the hips (1.5 rad/s^2 here moves it by < cost_tol_rel)
    assert warm.u[rom.HIP_ACCEL] == pytest.approx(cold.u[rom.HIP_ACCEL], abs=2.0)
    assert warm.cost == pytest.approx(cold.cost, rel=1e-4)


def test_fixed_posture_variant_never_moves_the_legs(fixed):
    res = fixed.solve(rom.hover_state(AF), hover_ref(), ROTOR_4_OFF)
    assert res.ok
    assert np.all(res.u_pred[:, rom.HIP_ACCEL] == 0.0)
    assert res.x_pred[:, rom.HIP] == pytest.approx(np.full((N + 1, 4), math.radians(45)))


def test_posture_moves_the_legs_after_a_rotor_loss_when_it_lowers_the_thrust(nmpc):
    nmpc.reset()
    res = nmpc.solve(rom.hover_state(AF), hover_ref(), ROTOR_4_OFF)
    assert np.abs(res.u[rom.HIP_ACCEL]).max() > 10.0


@pytest.mark.parametrize("case", ["offset", "rotor_loss", "wind", "fixed_rotor_loss"])
def test_converged_cost_matches_ipopt_on_the_same_problem(nmpc, fixed, case):
    rng = np.random.default_rng(7)
    solver = fixed if case.startswith("fixed") else nmpc
    x0 = perturbed(rng, 0.3)
    thrust = ROTOR_4_OFF if "rotor_loss" in case else FULL
    d = np.array([2.0, -1.0, 3.0, 0.05, -0.05, 0.0]) if case == "wind" else np.zeros(6)
    solver.reset()
    ours = solver.solve(x0, hover_ref(), thrust, d)
    ref = IpoptReference(solver).solve(x0, hover_ref(), thrust, d)
    assert ours.status == "converged" and ref.ok
    assert abs(ours.cost - ref.cost) <= 1e-3 * abs(ref.cost)


def test_the_uncompiled_route_solves_the_same_problem(nmpc):
    vm = Nmpc(AF, NmpcConfig(scheme="sqp", codegen=False))
    x0 = perturbed(np.random.default_rng(2), 0.3)
    nmpc.reset()
    a, b = nmpc.solve(x0, hover_ref(), FULL), vm.solve(x0, hover_ref(), FULL)
    assert b.ok and b.u == pytest.approx(a.u, abs=1e-6)


@pytest.mark.parametrize("kwargs, field", [({"horizon": 0}, "horizon"), ({"dt_s": -0.1}, "dt_s"),
                                           ({"weights": NmpcWeights(thrust=0.0)}, "thrust"),
                                           ({"weights": NmpcWeights(horizontal_saturated_scale=1.5)},
                                            "horizontal_saturated_scale"),
                                           ({"fixed_hip_rad": math.radians(120)}, "fixed_hip_rad")])
def test_bad_settings_are_rejected_by_name(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Nmpc(AF, NmpcConfig(**kwargs))


def test_wrong_shapes_are_rejected_by_name(nmpc):
    with pytest.raises(ValueError, match="x_ref"):
        nmpc.solve(rom.hover_state(AF), hover_ref()[:3], FULL)
    with pytest.raises(ValueError, match="thrust_bound_n"):
        nmpc.solve(rom.hover_state(AF), hover_ref(), FULL[:3])


def test_re_solved_faster_than_its_step_it_keeps_the_hips_in_range_between_nodes(nmpc):
    # At 50 Hz with a 0.1 s model the robot only flies the first 20 ms of each plan: the hip
    # bound must hold there too, not only at the 0.1 s nodes. Rotor 2's leg, folding fast
    # towards its 0 deg stop (where the best posture after losing rotor 4 wants it).
    tau, leg = 0.02, rom.HIP.start + 1
    x0 = rom.hover_state(AF)
    x0[leg], x0[rom.HIP_RATE.start + 1] = 0.012, -1.0

    def hip_after_first_period(solver):
        solver.reset()
        res = solver.solve(x0, hover_ref(), ROTOR_4_OFF)
        assert res.ok
        return res, x0[leg] + tau * x0[rom.HIP_RATE.start + 1] + 0.5 * tau ** 2 * res.u[rom.HIP_ACCEL.start + 1]

    _, node_only = hip_after_first_period(nmpc)
    assert node_only < AF.hip_min_rad - 1e-3          # nodes alone let the leg pass its stop
    m = Nmpc(AF, NmpcConfig(scheme="sqp", control_period_s=tau))
    res, hip = hip_after_first_period(m)
    assert hip >= AF.hip_min_rad - 1e-6
    ref = IpoptReference(m).solve(x0, hover_ref(), ROTOR_4_OFF)
    assert abs(res.cost - ref.cost) <= 1e-3 * abs(ref.cost)


def test_a_solve_stops_iterating_within_its_time_budget_and_its_plan_is_used():
    """A budget far below one iteration: one SQP iteration, then the plan so far (bounded,
    finite, better than the start) instead of the iterations a rough start needs."""
    budgeted = Nmpc(AF, NmpcConfig(scheme="sqp", control_period_s=0.02, time_budget_share=1e-6))
    unbounded = Nmpc(AF, NmpcConfig(scheme="sqp", control_period_s=0.02, time_budget_share=0.0))
    x = perturbed(np.random.default_rng(3))
    full = unbounded.solve(x, hover_ref(), [AF.thrust_max_n] * 4)
    res = budgeted.solve(x, hover_ref(), [AF.thrust_max_n] * 4)
    assert full.iterations > 1
    assert res.status == "time_budget" and res.iterations == 1 and res.ok and not res.fallback
    assert_within(budgeted, res, [AF.thrust_max_n] * 4)
    assert NmpcConfig(control_period_s=0.02, time_budget_share=0.5).time_budget_s == pytest.approx(0.01)
    assert NmpcConfig(time_budget_share=0.0).time_budget_s is None
