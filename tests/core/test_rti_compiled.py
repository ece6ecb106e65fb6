"""The RTI's feedback as one compiled call (moved, CasADi's DAQP, plan in C): it plans what the
Python route (DAQP's binding) plans; without its library the Python route flies, and says so."""

import logging
import subprocess
import sys
import threading
from unittest import mock

import numpy as np
import pytest

from companion.core import rom, rti_compiled
from companion.core.codegen_cache import CodegenError, compiled_library
from companion.core.feedback_qp import FeedbackQp
from companion.core.nmpc import Nmpc
from companion.core.nmpc_config import NmpcConfig
from companion.core.rti_compiled import CompiledFeedback
from tests.core.test_nmpc_rti import AF, FULL, N, PERIOD_S, ROTOR_4_OFF, WIND, hover_ref

NOT_CHECKED = (f"the compiled route flies on CasADi {', '.join(sorted(rti_compiled.CHECKED_CASADI))} only, "
               f"not {rti_compiled.ca.__version__}")
compiled_route = pytest.mark.skipif(rti_compiled.ca.__version__ not in rti_compiled.CHECKED_CASADI, reason=NOT_CHECKED)


def rti_nmpc() -> Nmpc:
    return Nmpc(AF, NmpcConfig(control_period_s=PERIOD_S, scheme="rti"))


def python_route() -> Nmpc:
    with mock.patch.object(rti_compiled, "daqp_c_library", lambda: None):
        return rti_nmpc()


def prepared_at_hover(nmpc: Nmpc) -> np.ndarray:
    """The hover state, after a solve there from a reset and the preparation of the next."""
    x = rom.hover_state(AF)
    nmpc.reset()
    nmpc.solve(x, hover_ref(), FULL, WIND)
    nmpc.prepare(hover_ref(), FULL, WIND)
    return x


@pytest.fixture(scope="module")
def routes():
    if rti_compiled.ca.__version__ not in rti_compiled.CHECKED_CASADI:
        pytest.skip(NOT_CHECKED)
    compiled, python = rti_nmpc(), python_route()
    assert isinstance(compiled._feedback.solver, CompiledFeedback)
    assert isinstance(python._feedback.solver, FeedbackQp)
    return compiled, python


def fly_both(routes, bounds, kick_every=4):
    """Both routes on the same closed loop on the model (the compiled route's commands flown),
    the thrust bound of each step from `bounds`: the largest difference of their plans (N) and states."""
    compiled, python = routes
    step = rom.rk4_step(compiled.rom.f, PERIOD_S)
    for nmpc in routes:
        nmpc.reset()
    x, du, dx = rom.hover_state(AF), 0.0, 0.0
    for k, bound in enumerate(bounds):
        if k % kick_every == 0:
            x[rom.V] += (0.3, -0.2, 0.2)
            x[rom.RATES] += (0.4, -0.3, 0.1)
        a, b = compiled.solve(x, hover_ref(), bound, WIND), python.solve(x, hover_ref(), bound, WIND)
        assert (a.status, a.ok) == (b.status, b.ok)
        du, dx = max(du, np.abs(a.u_pred - b.u_pred).max()), max(dx, np.abs(a.x_pred - b.x_pred).max())
        for nmpc in routes:
            nmpc.prepare(hover_ref(), bound, WIND)
        x = np.asarray(step(x, a.u, WIND)).ravel()
    return du, dx


def test_it_plans_what_the_python_route_plans_to_rounding_while_no_row_binds(routes):
    du, dx = fly_both(routes, [FULL] * 12, kick_every=100)
    assert du < 1e-9 and dx < 1e-9


def test_through_a_rotor_loss_and_back_it_plans_what_the_python_route_plans(routes):
    # The lost rotor's thrust bounds are equal: an equality for DAQP, activated when they become
    # equal and released when they part again. The rows that bind then are soft: the two DAQPs
    # weigh them alike but for the binding's per-row weights (rti_feedback.c): 4.4e-5 N apart.
    du, dx = fly_both(routes, [FULL] * 4 + [ROTOR_4_OFF] * 8 + [FULL] * 8)
    assert du < 1e-3 and dx < 1e-3


def test_equalities_that_make_the_last_active_set_singular_start_the_solve_from_themselves(routes):
    # The last solve leaves rows active; then every input's bounds are equal: 40 equalities, which
    # with those rows are more than 40 constraints on 40 unknowns (DAQP: EXIT_OVERDETERMINED_INITIAL).
    x = rom.hover_state(AF)
    x[rom.V] += (2.4, -2.3, 1.2)
    x[rom.RATES] += (3.6, -2.4, 1.1)
    active = []
    for nmpc in routes:
        nmpc.reset()
        nmpc.solve(x, hover_ref(), ROTOR_4_OFF, WIND)
        nmpc.prepare(hover_ref(), ROTOR_4_OFF, WIND)
        assert np.count_nonzero(nmpc._duals[N * rom.NU:]) > 0          # rows active
        lo, hi = nmpc.input_bounds(FULL)
        held = (lo + hi) / 2
        assert nmpc._feedback.solve(x, hover_ref(), WIND, held, held) == 2     # soft rows violated
        active.append(np.flatnonzero(nmpc._feedback.duals))
    assert np.array_equal(active[0], active[1]) and active[0].size > N * rom.NU


def test_a_hessian_daqp_cannot_factorise_falls_back_and_the_next_preparation_flies_again(routes):
    compiled, python = routes
    x = rom.hover_state(AF)
    for nmpc in routes:
        nmpc.reset()
        nmpc.solve(x, hover_ref(), FULL, WIND)
        nmpc.prepare(hover_ref(), FULL, WIND)
        prep = nmpc._prepared
        nmpc._feedback.solver.load(-prep.hess, prep.rows, warm=True)     # not positive definite
        res = nmpc.solve(x, hover_ref(), FULL, WIND)
        lo, hi = nmpc.input_bounds(FULL)
        assert res.status == "qp_failed" and res.fallback
        assert np.all(np.isfinite(res.u)) and np.all(res.u >= lo) and np.all(res.u <= hi)
        assert nmpc.solve(x, hover_ref(), FULL, WIND).status == "rti_unprepared"   # set up anew
        nmpc.prepare(hover_ref(), FULL, WIND)
    a, b = compiled.solve(x, hover_ref(), FULL, WIND), python.solve(x, hover_ref(), FULL, WIND)
    assert a.status == b.status == "rti" and a.u == pytest.approx(b.u, abs=1e-9)


@compiled_route
def test_a_feedback_before_any_load_is_refused_with_a_negative_flag():
    solver = rti_nmpc()._feedback.solver                # built, nothing loaded into DAQP yet
    assert isinstance(solver, CompiledFeedback)
    assert solver.feedback() == -1                      # as the Python route's FeedbackQp before a load


def test_crossed_input_bounds_are_infeasible_before_the_solve(routes):
    compiled, _ = routes
    x = prepared_at_hover(compiled)
    lo, hi = compiled.input_bounds(FULL)
    lo = lo.copy()
    lo[0] = hi[0] + 1.0
    assert compiled._feedback.solve(x, hover_ref(), WIND, lo, hi) == -1     # DAQP's EXIT_INFEASIBLE
    # DAQP's next load checks the bounds the last feedback left: uncrossed again for the next tests.
    assert compiled._feedback.solve(x, hover_ref(), WIND, *compiled.input_bounds(FULL)) > 0


def test_a_step_that_is_not_finite_falls_back_to_a_bounded_command(routes):
    compiled, _ = routes
    x = prepared_at_hover(compiled)
    grad = compiled._prepared.grad.copy()
    grad[3] = np.nan                     # DAQP's step then is not finite, its exitflag 1
    compiled._feedback._moved.set_parameters(grad_p=grad)
    res = compiled.solve(x, hover_ref(), FULL, WIND)
    lo, hi = compiled.input_bounds(FULL)
    assert res.status == "qp_failed" and res.fallback
    assert np.all(np.isfinite(res.u)) and np.all(res.u >= lo) and np.all(res.u <= hi)


def test_an_input_that_is_not_finite_is_named_invalid(routes):
    compiled, _ = routes
    x = prepared_at_hover(compiled)
    x[rom.V.start] = np.nan
    res = compiled.solve(x, hover_ref(), FULL, WIND)
    assert res.status == "invalid_input" and np.all(np.isfinite(res.u))


def test_the_compiled_feedback_keeps_the_gil_through_its_call(routes):
    # A thread waiting for the GIL takes it whenever a call gives it up (ctypes.CDLL's calls do:
    # the answer then waits for it back up to a switch interval). With the interval far longer
    # than the test, the waiting thread runs only if a call gives the GIL up.
    compiled, _ = routes
    prepared_at_hover(compiled)
    solver, ran, waiting = compiled._feedback.solver, [], threading.Lock()
    waiting.acquire()
    thread = threading.Thread(target=lambda: (waiting.acquire(), ran.append(True)))
    interval = sys.getswitchinterval()
    sys.setswitchinterval(100.0)
    try:
        thread.start()
        waiting.release()                 # the thread now waits for the GIL alone
        for _ in range(1000):
            solver.feedback()
        assert not ran
    finally:
        sys.setswitchinterval(interval)
        thread.join()


@pytest.mark.parametrize("name, shape", [("hess", (N * rom.NU - 1, N * rom.NU)), ("rows", (3, N * rom.NU))])
def test_a_hessian_or_rows_of_another_shape_is_refused_by_name(routes, name, shape):
    solver = routes[0]._feedback.solver
    good = {"hess": np.eye(N * rom.NU), "rows": np.zeros((routes[0]._qp_rows.count, N * rom.NU))}
    good[name] = np.zeros(shape)
    with pytest.raises(ValueError, match=rf"^CompiledFeedback: {name} must have shape \(\d+, \d+\), got \(\d+, \d+\)$"):
        solver.load(good["hess"], good["rows"], warm=False)


@pytest.fixture
def fresh_notices(caplog):
    rti_compiled._say_once.cache_clear()
    caplog.set_level(logging.WARNING, logger=rti_compiled.__name__)
    yield caplog
    rti_compiled._say_once.cache_clear()


@compiled_route
def test_without_casadis_daqp_the_python_route_flies_and_says_so_once(fresh_notices):
    first, second = python_route(), python_route()
    assert isinstance(first._feedback.solver, FeedbackQp) and isinstance(second._feedback.solver, FeedbackQp)
    casadi_dir = rti_compiled.Path(rti_compiled.ca.__file__).parent
    assert [r.getMessage() for r in fresh_notices.records] == [
        f"the RTI feedback calls DAQP from Python: CasADi's wheel has no DAQP C headers and libdaqpstat.a under {casadi_dir}"]


@compiled_route
def test_a_feedback_library_the_compiler_cannot_build_leaves_the_python_route_flying(fresh_notices):
    def fail(*args, **kwargs):
        raise CodegenError("compiling m4_rti_feedback failed: no daqp")

    with mock.patch.object(rti_compiled, "compiled_library", fail):
        nmpc = rti_nmpc()
    assert isinstance(nmpc._feedback.solver, FeedbackQp)
    assert [r.getMessage() for r in fresh_notices.records] == [
        "the RTI feedback calls DAQP from Python: compiling m4_rti_feedback failed: no daqp"]


@compiled_route
def test_without_our_c_source_the_python_route_flies_and_says_so(fresh_notices, tmp_path):
    missing = tmp_path / "rti_feedback.c"
    with mock.patch.object(rti_compiled, "SOURCE", missing):
        nmpc = rti_nmpc()
    assert isinstance(nmpc._feedback.solver, FeedbackQp)
    assert [r.getMessage() for r in fresh_notices.records] == [
        f"the RTI feedback calls DAQP from Python: [Errno 2] No such file or directory: '{missing}'"]


@compiled_route
def test_a_feedback_library_that_does_not_load_leaves_the_python_route_flying(fresh_notices, tmp_path):
    broken = tmp_path / "m4_rti_feedback.so"
    broken.write_bytes(b"not a shared library")
    with mock.patch.object(rti_compiled, "compiled_library", lambda *args: broken):
        nmpc = rti_nmpc()
    assert isinstance(nmpc._feedback.solver, FeedbackQp)
    [notice] = [r.getMessage() for r in fresh_notices.records]
    assert notice.startswith(f"the RTI feedback calls DAQP from Python: {broken}: ") and "\n" not in notice


@compiled_route
def test_daqps_symbols_stay_inside_the_feedback_library():
    built = []
    with mock.patch.object(rti_compiled, "compiled_library", lambda *args: built.append(compiled_library(*args))
                           or built[-1]):
        rti_nmpc()
    [library] = built
    exported = subprocess.run(["nm", "-D", "--defined-only", str(library)], capture_output=True, text=True,
                              check=True).stdout
    assert "m4_rti_feedback" in exported and "daqp_solve" not in exported and "setup_daqp" not in exported


def test_on_a_casadi_rti_feedback_c_was_not_checked_on_the_python_route_flies_and_says_so(fresh_notices):
    with mock.patch.object(rti_compiled.ca, "__version__", "3.9.0"):
        nmpc = rti_nmpc()
    assert isinstance(nmpc._feedback.solver, FeedbackQp)
    assert [r.getMessage() for r in fresh_notices.records] == [
        ("the RTI feedback calls DAQP from Python: rti_feedback.c was checked on the DAQP of CasADi 3.8.2, "
         "not of CasADi 3.9.0")]


def test_with_codegen_off_the_python_route_flies_and_says_so(fresh_notices):
    assert rti_compiled.feedback_library(None, None, codegen=False) is None
    assert [r.getMessage() for r in fresh_notices.records] == [
        "the RTI feedback calls DAQP from Python: [nmpc] codegen = false"]
