"""The real-time iteration's kept DAQP workspace solves as daqp.solve does on the same QP."""

import daqp
import numpy as np
import pytest

from companion.core.feedback_qp import FeedbackQp

N_VAR, N_ROWS = 12, 6
SENSE = np.r_[np.zeros(N_VAR, np.int32), np.full(N_ROWS, 8, np.int32)]


def qp(seed):
    """A strictly convex QP whose unconstrained optimum leaves some bounds: (H, A, f, upper, lower)."""
    rng = np.random.default_rng(seed)
    h = rng.normal(size=(N_VAR, N_VAR))
    upper = np.r_[np.full(N_VAR, 0.3), np.full(N_ROWS, 1.0)]
    return h @ h.T + N_VAR * np.eye(N_VAR), rng.normal(size=(N_ROWS, N_VAR)), 20 * rng.normal(size=N_VAR), upper, -upper


def reference(h, a, f, upper, lower, dual_start=None):
    x, _, flag, info = daqp.solve(h, f, a, upper, lower, SENSE, dual_start=dual_start)
    return np.asarray(x), flag, np.asarray(info["lam"])


def test_each_loaded_qp_is_solved_as_daqp_solves_it_warm_from_the_last_active_set():
    fb = FeedbackQp(N_VAR, SENSE, iter_limit=1000)
    duals = None
    for seed in range(4):
        h, a, f, upper, lower = qp(seed)
        fb.load(h.copy(), a.copy(), warm=duals is not None)
        x, flag, lam = fb.solve(f, upper, lower)
        x_ref, flag_ref, duals = reference(h, a, f, upper, lower, duals)
        assert flag == flag_ref and flag in (1, 2)
        assert np.count_nonzero(duals) > 0                       # bounds are active: the active set matters
        np.testing.assert_allclose(x, x_ref, atol=1e-12)
        np.testing.assert_allclose(lam, duals, atol=1e-9)


def test_a_warm_load_starts_from_the_last_active_set_and_a_cold_one_from_none():
    h, a, f, upper, lower = qp(0)
    fb = FeedbackQp(N_VAR, SENSE, iter_limit=1000)
    fb.load(h, a, warm=False)
    fb.solve(f, upper, lower)
    cold = fb.iterations
    assert cold > 2                                              # several constraints to find active
    fb.load(h, a, warm=True)
    fb.solve(f, upper, lower)
    assert fb.iterations <= 1                                    # the same QP: its active set is the answer
    fb.load(h, a, warm=False)
    fb.solve(f, upper, lower)
    assert fb.iterations == cold


def test_the_gradient_and_bounds_of_a_loaded_qp_change_without_loading_it_again():
    h, a, f, upper, lower = qp(7)
    fb = FeedbackQp(N_VAR, SENSE, iter_limit=1000)
    fb.load(h, a, warm=False)
    fb.solve(f, upper, lower)
    x, _, _ = fb.solve(-f, 2 * upper, 2 * lower)
    np.testing.assert_allclose(x, reference(h, a, -f, 2 * upper, 2 * lower)[0], atol=1e-12)


def test_a_hessian_daqp_cannot_factorise_fails_the_solve_and_the_next_load_recovers():
    h, a, f, upper, lower = qp(3)
    fb = FeedbackQp(N_VAR, SENSE, iter_limit=1000)
    fb.load(h, a, warm=False)
    fb.load(-np.eye(N_VAR), a, warm=True)
    x, flag, _ = fb.solve(f, upper, lower)
    assert flag < 0 and np.isnan(x).all()
    fb.load(h, a, warm=False)
    x, flag, _ = fb.solve(f, upper, lower)
    np.testing.assert_allclose(x, reference(h, a, f, upper, lower)[0], atol=1e-12)


def test_an_array_of_the_wrong_shape_is_refused_by_name_where_daqp_would_take_it_silently():
    h, a, f, upper, lower = qp(0)
    fb = FeedbackQp(N_VAR, SENSE, iter_limit=1000)
    fb.load(h, a, warm=False)
    wrong_loads = {"hess": (h[:6, :6].copy(), a), "rows": (h, a[:3].copy())}
    for name, (hess, rows) in wrong_loads.items():
        with pytest.raises(ValueError, match=rf"^FeedbackQp: {name} must have shape \(\d+, 12\), got \(\d+, \d+\)$"):
            fb.load(hess, rows, warm=True)
    wrong_solves = {"grad": (f[:5].copy(), upper, lower), "upper": (f, upper[:10].copy(), lower),
                    "lower": (f, upper, lower[:10].copy())}
    for name, args in wrong_solves.items():
        with pytest.raises(ValueError, match=rf"^FeedbackQp: {name} must have shape \(\d+,\), got \(\d+,\)$"):
            fb.solve(*args)
    x, _, _ = fb.solve(f, upper, lower)                          # the workspace still holds the right QP
    np.testing.assert_allclose(x, reference(h, a, f, upper, lower)[0], atol=1e-12)
