"""The setpoint's checks on Python floats give what numpy's calls on arrays gave: the bounds'
clamps (signed zeros included) and the float32 step past a bound."""

from __future__ import annotations

import numpy as np
import pytest

from companion.core.control_types import _float32_next, _plausible_range, thrust_bound_list
from m4.airframe import load_airframe

AF = load_airframe()
FLOAT32_LEAST = np.float32(1e-45)          # the least positive subnormal


def test_thrust_bound_list_clamps_as_numpy_did_signed_zeros_and_non_finite_included():
    values = [np.nan, np.inf, -np.inf, -1.0, -0.0, 0.0, AF.thrust_min_n, AF.thrust_max_n, 0.5 * AF.thrust_max_n,
              np.nextafter(AF.thrust_max_n, np.inf), 1e300, -1e-300]
    for v in values:
        bound = np.full(4, v)
        numpy_s = np.minimum(np.maximum(np.where(np.isfinite(bound), bound, AF.thrust_max_n), AF.thrust_min_n),
                             AF.thrust_max_n)
        assert np.array(thrust_bound_list(AF, bound)).tobytes() == numpy_s.tobytes(), v


def test_thrust_bound_list_says_what_is_wrong_with_a_bound_of_the_wrong_size():
    with pytest.raises(ValueError, match="thrust_bound_n must have 4 entries, got 3"):
        thrust_bound_list(AF, [1.0, 2.0, 3.0])


@pytest.mark.parametrize("down", [True, False])
def test_the_float32_step_is_numpys_nextafter_on_float32(down):
    rng = np.random.default_rng(21)
    values = np.concatenate([rng.normal(size=4000) * 10.0 ** rng.integers(-44, 38, 4000),
                             [0.0, -0.0, FLOAT32_LEAST, -FLOAT32_LEAST, 1.0, -1.0, np.pi / 2, -np.pi / 2,
                              3e38, -3e38]]).astype(np.float32)
    toward = np.float32(-np.inf if down else np.inf)
    for v in values:
        assert np.float32(_float32_next(float(v), down)).tobytes() == np.nextafter(v, toward).tobytes(), v


def test_the_cached_plausible_range_cannot_be_changed_by_a_caller():
    least, most = _plausible_range(AF.hip_min_rad, AF.hip_max_rad)
    with pytest.raises(ValueError, match="read-only"):
        least[0] = 0.0
    with pytest.raises(ValueError, match="read-only"):
        most[0] = 0.0
