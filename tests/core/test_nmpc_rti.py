"""The real-time iteration: its feedback is the QP built at the arrived state, to first order;
it reaches the SQP's optimum on a held problem; whatever comes in, a bounded command."""

from unittest import mock

import numpy as np
import pytest

from m4.airframe import load_airframe
from companion.core import rom, rti_compiled
from companion.core.nmpc import Nmpc
from companion.core.nmpc_config import NmpcConfig

AF = load_airframe()
N = 5
PERIOD_S = 0.02
FULL = np.full(4, AF.thrust_max_n)
ROTOR_4_OFF = np.array([AF.thrust_max_n] * 3 + [0.0])
WIND = np.array([2.0, -1.0, 1.0, 0.02, -0.02, 0.0])


@pytest.fixture(scope="module")
def rti():
    return Nmpc(AF, NmpcConfig(control_period_s=PERIOD_S, scheme="rti"))


def hover_ref():
    return np.tile(rom.hover_state(AF), (N + 1, 1))


def moving_state():
    x = rom.hover_state(AF)
    x[rom.V] += (0.4, -0.3, 0.2)
    x[rom.RATES] += (0.6, -0.4, 0.1)
    return x


def prepared(rti, x0, d):
    """The QP the RTI prepares after a solve at x0: at x0 one control period on, along the plan shifted."""
    rti.reset()
    rti.solve(x0, hover_ref(), FULL, d)
    rti.prepare(hover_ref(), FULL, d)
    return rti._prepared


def moved(rti, x0, x_ref, d, bound=FULL):
    """The prepared QP's feedback at (x0, x_ref, d): (gradient, upper, lower, states (N+1, 20)):
    the states as the plan of a zero step gives them."""
    grad, upper, lower = (a.copy() for a in rti._feedback.qp(x0, x_ref, d, *rti.input_bounds(bound))[:3])
    return grad, upper, lower, plan(rti, np.zeros(N * rom.NU))[1]


def plan(rti, step):
    """(inputs, states, cost) after the step (N*8,) from the QP the last `moved` moved: the
    feedback's own `plan` evaluated as its Python route evaluates it, then `planned`."""
    rti._feedback._plan.evaluate(step)
    return rti._feedback.planned()


def offset(rng, scale):
    dx = np.zeros(rom.NX)
    dx[rom.V] = rng.uniform(-1, 1, 3) * 0.1 * scale
    dx[rom.EULER] = rng.uniform(-1, 1, 3) * 0.05 * scale
    dx[rom.RATES] = rng.uniform(-1, 1, 3) * 0.2 * scale
    return dx, rng.uniform(-1, 1, 6) * np.r_[1.0, 1.0, 1.0, 0.02, 0.02, 0.02] * scale


def test_the_feedback_moves_the_predicted_states_to_the_arrived_state_and_disturbance_to_first_order(rti):
    # Sign or block errors in the sensitivities to the state or the disturbance leave a
    # first-order error; a right embedding leaves a second-order one: a 10x smaller change,
    # about 100x less error against the model's own rollout.
    prep = prepared(rti, moving_state(), WIND)
    rollout = rom.rk4_step(rti.rom.f, rti.config.dt_s)

    def error(scale):
        dx, dd = offset(np.random.default_rng(0), scale)
        states = moved(rti, prep.x0 + dx, hover_ref(), prep.d + dd)[3]
        x = prep.x0 + dx
        errors = []
        for k in range(N):
            x = np.asarray(rollout(x, prep.us[k], prep.d + dd)).ravel()
            errors.append(np.abs(states[k + 1] - x).max())
        return max(errors)

    assert error(0.1) < error(1.0) / 50


def test_the_feedback_moves_the_gradient_exactly_with_the_states_and_the_targets(rti):
    prep = prepared(rti, moving_state(), WIND)
    x0, x_ref = prep.x0 + offset(np.random.default_rng(1), 1.0)[0], hover_ref() + 0.3
    d = prep.d + np.r_[1.0, 0.0, -2.0, 0.0, 0.0, 0.0]
    grad, _, _, states = moved(rti, x0, x_ref, d)
    ref, u_ref = rti.targets(x0, x_ref, d)
    _, expected = rti.cost.gauss_newton(prep.gamma, states, prep.us, ref, u_ref)
    assert grad == pytest.approx(expected, rel=1e-9, abs=1e-9)


def test_the_feedback_bounds_the_step_by_the_input_bounds_and_the_rows_at_the_moved_states(rti):
    prep = prepared(rti, moving_state(), WIND)
    x0, d = prep.x0 + offset(np.random.default_rng(2), 1.0)[0], prep.d + 0.1
    x0[rom.HIP_RATE] += 0.5                        # the first period's rows move with the hip rates
    _, upper, lower, states = moved(rti, x0, hover_ref(), d, ROTOR_4_OFF)
    want_upper, want_lower = rti._qp_bounds(x0, states, prep.us, *rti.input_bounds(ROTOR_4_OFF))
    assert upper == pytest.approx(want_upper, rel=1e-12, abs=1e-12)
    assert lower == pytest.approx(want_lower, rel=1e-12, abs=1e-12)


def test_the_plan_takes_the_step_within_the_bounds_and_costs_what_the_cost_says(rti):
    prep = prepared(rti, moving_state(), WIND)
    x0, x_ref, d = prep.x0 + 0.01, hover_ref(), prep.d
    step = np.random.default_rng(3).normal(scale=2.0, size=N * rom.NU)
    states = moved(rti, x0, x_ref, d, ROTOR_4_OFF)[3]
    us, xs, cost = plan(rti, step)
    lo, hi = rti.input_bounds(ROTOR_4_OFF)
    assert np.array_equal(us, np.clip(prep.us + step.reshape(N, rom.NU), lo, hi))
    assert xs[1:] == pytest.approx(states[1:] + (prep.gamma @ step).reshape(N, rom.NX), rel=1e-12, abs=1e-12)
    assert np.array_equal(xs[0], x0)
    assert cost == pytest.approx(rti.cost.value(xs, us, *rti.targets(x0, x_ref, d)), rel=1e-12)


def test_a_step_that_is_not_finite_falls_back_to_a_bounded_command(monkeypatch):
    with mock.patch.object(rti_compiled, "daqp_c_library", lambda: None):    # the Python route's DAQP
        python_route = Nmpc(AF, NmpcConfig(control_period_s=PERIOD_S, scheme="rti"))
    prepared(python_route, moving_state(), WIND)
    solve = python_route._feedback.solver.solve
    monkeypatch.setattr(python_route._feedback.solver, "solve",
                        lambda *qp: (np.full(N * rom.NU, np.nan), *solve(*qp)[1:]))
    res = python_route.solve(moving_state(), hover_ref(), FULL, WIND)
    lo, hi = python_route.input_bounds(FULL)
    assert res.status == "qp_failed" and res.fallback
    assert np.all(np.isfinite(res.u)) and np.all(res.u >= lo) and np.all(res.u <= hi)


def test_on_a_held_problem_it_reaches_the_sqp_optimum(rti):
    sqp = Nmpc(AF, NmpcConfig(control_period_s=PERIOD_S, max_iterations=50, cost_tol_rel=1e-10, scheme="sqp"))
    x0 = moving_state()
    step = rom.rk4_step(rti.rom.f, PERIOD_S)
    rti.reset()
    x = x0
    for _ in range(80):                     # a closed loop on the model itself, rotor 4 lost
        res = rti.solve(x, hover_ref(), ROTOR_4_OFF)
        assert res.ok and res.status in ("rti", "rti_unprepared")
        x = np.asarray(step(x, res.u, np.zeros(6))).ravel()
        rti.prepare(hover_ref(), ROTOR_4_OFF)
    res = rti.solve(x, hover_ref(), ROTOR_4_OFF)
    best = sqp.solve(x, hover_ref(), ROTOR_4_OFF)
    assert res.status == "rti" and best.ok
    assert res.u[rom.THRUST] == pytest.approx(best.u[rom.THRUST], abs=0.05)
    assert res.cost == pytest.approx(best.cost, rel=1e-3)


@pytest.mark.parametrize("bad", ["state", "reference", "bounds", "disturbance"])
def test_whatever_comes_in_the_command_is_finite_and_within_the_bounds(rti, bad):
    rng = np.random.default_rng(5)
    rti.reset()
    for k in range(6):
        x0, ref, bound, d = moving_state(), hover_ref(), rng.uniform(0.0, AF.thrust_max_n, 4), WIND.copy()
        if k % 2:
            {"state": x0, "reference": ref[2], "bounds": bound, "disturbance": d}[bad][k % 3] = np.nan
        rti.prepare(ref, bound, d)
        res = rti.solve(x0, ref, bound, d)
        lo, hi = rti.input_bounds(bound)
        assert np.all(np.isfinite(res.u)) and np.all(res.u >= lo) and np.all(res.u <= hi)
        assert np.all(np.isfinite(res.u_pred)) and res.fallback == (not res.ok)


def test_a_dropped_preparation_is_not_fed_back(rti):
    rti.reset()
    rti.solve(moving_state(), hover_ref(), FULL)
    rti.prepare(hover_ref(), FULL)
    rti.unprepare()
    assert rti.solve(moving_state(), hover_ref(), FULL).status == "rti_unprepared"


def test_the_sqp_scheme_prepares_nothing():
    sqp = Nmpc(AF, NmpcConfig(control_period_s=PERIOD_S, scheme="sqp"))
    sqp.solve(moving_state(), hover_ref(), FULL)
    sqp.prepare(hover_ref(), FULL)
    assert sqp.solve(moving_state(), hover_ref(), FULL).status == "converged"


def test_an_unknown_scheme_is_rejected_by_name():
    with pytest.raises(ValueError, match="scheme"):
        NmpcConfig(scheme="fast").validate()


def test_a_yaw_that_wrapped_past_south_since_the_preparation_is_a_small_turn(rti):
    """Prepared heading just west of south (yaw pi - 0.005), the state arrives just east of it:
    as -pi + 0.005 on the wire. The command is the one for the same heading written pi + 0.005,
    not the wild one a 2 pi turn through the linearisation gives (a false rotor alarm in
    moderate turbulence, fault-free: docs/fault-detection.md)."""
    x = moving_state()
    x[rom.EULER.stop - 1] = np.pi - 0.005

    def command(yaw_rad):
        prep = prepared(rti, x, WIND)
        arrived = prep.x0.copy()
        arrived[rom.EULER.stop - 1] = yaw_rad
        return rti.solve(arrived, hover_ref(), FULL, WIND).u
    assert command(-np.pi + 0.005) == pytest.approx(command(np.pi + 0.005), abs=1e-6)


def test_the_uncompiled_feedback_computes_what_the_compiled_one_does():
    vm = Nmpc(AF, NmpcConfig(control_period_s=PERIOD_S, scheme="rti", codegen=False))
    with mock.patch.object(rti_compiled, "daqp_c_library", lambda: None):    # the same DAQP: the binding
        compiled = Nmpc(AF, NmpcConfig(control_period_s=PERIOD_S, scheme="rti"))
    step = rom.rk4_step(compiled.rom.f, PERIOD_S)
    x = moving_state()
    for _ in range(5):
        a, b = compiled.solve(x, hover_ref(), ROTOR_4_OFF, WIND), vm.solve(x, hover_ref(), ROTOR_4_OFF, WIND)
        assert b.status == a.status and b.u == pytest.approx(a.u, abs=1e-9) and b.cost == pytest.approx(a.cost)
        x = np.asarray(step(x, a.u, WIND)).ravel()
        compiled.prepare(hover_ref(), ROTOR_4_OFF, WIND)
        vm.prepare(hover_ref(), ROTOR_4_OFF, WIND)
        compiled_qp, vm_qp = moved(compiled, x, hover_ref(), WIND), moved(vm, x, hover_ref(), WIND)
        for a, b in zip(compiled_qp, vm_qp, strict=True):
            assert a == pytest.approx(b, rel=1e-12, abs=1e-12)


def test_the_feedback_takes_the_weights_of_the_cost_it_was_prepared_for(rti):
    prep = prepared(rti, moving_state(), WIND)
    rti.altitude_first.active = True                # the horizontal weights scaled down
    try:
        prep = rti._prepare_at(prep.x0, hover_ref(), prep.d, *rti.input_bounds(FULL))
        assert prep.cost is rti.cost is not rti._costs[0]
        x0 = prep.x0 + 0.01
        grad, _, _, states = moved(rti, x0, hover_ref(), prep.d)
        ref, u_ref = rti.targets(x0, hover_ref(), prep.d)
        assert grad == pytest.approx(rti.cost.gauss_newton(prep.gamma, states, prep.us, ref, u_ref)[1], rel=1e-9)
        us, xs, cost = plan(rti, np.zeros(N * rom.NU))
        assert cost == pytest.approx(rti.cost.value(xs, us, ref, u_ref), rel=1e-12)
    finally:
        rti.reset()


def test_altitude_before_place_reads_the_plan_after_the_send_before_the_next_plan(rti, monkeypatch):
    """The plan's saturation picks the cost of the plans after it: read at the preparation,
    after the setpoint left, not between the state and the setpoint."""
    seen = []
    monkeypatch.setattr(rti.altitude_first, "update", lambda thrust_n, *_: seen.append(thrust_n.copy()))
    rti.reset()
    res = rti.solve(moving_state(), hover_ref(), ROTOR_4_OFF, WIND)
    assert seen == []
    rti.prepare(hover_ref(), ROTOR_4_OFF, WIND)
    assert len(seen) == 1 and np.array_equal(seen[0], res.u[rom.THRUST])
    res = rti.solve(moving_state(), hover_ref(), ROTOR_4_OFF, WIND)
    rti.solve(moving_state(), hover_ref(), ROTOR_4_OFF, WIND)        # no preparation between: read then
    assert len(seen) == 2 and np.array_equal(seen[1], res.u[rom.THRUST])
