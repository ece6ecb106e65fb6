"""Why posture matters: the figures of docs/airframe.md from a static balance."""

import numpy as np
import pytest

from m4.airframe import load_airframe
from research.allocation import admissible, allocate, best_posture

AF = load_airframe()


def test_rotor_4_off_at_the_nominal_posture_loads_rotors_1_and_2_with_the_whole_weight():
    a = allocate(AF, np.radians([45, 45, 45, 45]), failed_index=3)
    assert a.thrust_n == pytest.approx([29.43, 29.43, 0.0, 0.0], abs=0.01)
    assert a.yaw_moment_n_m == pytest.approx(1.18, abs=0.005)


@pytest.mark.parametrize("failed", [0, 1, 2, 3])
def test_best_posture_shares_the_load_over_three_rotors_and_halves_the_yaw_moment(failed):
    a = best_posture(AF, failed)
    live = [i for i in range(4) if i != failed]
    assert a.max_thrust_n == pytest.approx(21.76, abs=0.05)
    assert sorted(a.thrust_n[live]) == pytest.approx([15.3, 21.76, 21.76], abs=0.1)
    assert abs(a.yaw_moment_n_m) == pytest.approx(0.56, abs=0.01)
    assert admissible(AF, a.hip_rad)[0]
    assert a.max_thrust_n < AF.thrust_max_tight_n < 29.4    # the tight cap: only posture can hover


def test_the_best_posture_for_rotor_4_is_the_published_one():
    a = best_posture(AF, 3)
    assert np.degrees(a.hip_rad) == pytest.approx([90, 0, 72, 0], abs=1.0)


def test_best_postures_of_opposite_rotors_mirror_each_other():
    q4, q1 = np.degrees(best_posture(AF, 3).hip_rad), np.degrees(best_posture(AF, 0).hip_rad)
    assert q1 == pytest.approx(q4[[3, 2, 1, 0]], abs=0.5)
