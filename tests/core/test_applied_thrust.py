"""What the FC commanded over a period, from its own reports."""

import numpy as np
import pytest

from companion.core.applied_thrust import AppliedThrust

P = 0.02


def reports(*pairs) -> AppliedThrust:
    a = AppliedThrust(P)
    for t, thrust in pairs:
        a.report(t, np.full(4, thrust))
    return a


def test_with_no_lead_the_report_at_the_end_of_the_period_flew_it():
    a = reports((1.00, 10.0), (1.02, 14.0))
    np.testing.assert_allclose(a.over_period(1.02, 0.0), np.full(4, 14.0))


def test_a_lead_off_the_frame_grid_mixes_the_two_reports_by_the_time_each_was_in_force():
    a = reports((1.00, 10.0), (1.02, 14.0))
    np.testing.assert_allclose(a.over_period(1.02, 0.105), np.full(4, 0.25 * 10.0 + 0.75 * 14.0))


def test_only_a_report_of_that_very_instant_counts():
    a = reports((1.00, 10.0), (1.02, 14.0))
    assert a.over_period(1.04, 0.0) is None


def test_after_a_lost_frame_the_newest_report_stands_for_the_period():
    a = reports((1.00, 10.0), (1.04, 14.0))
    np.testing.assert_allclose(a.over_period(1.04, 0.01), np.full(4, 14.0))


@pytest.mark.parametrize("bad", [None, [1.0, np.nan, 1.0, 1.0]])
def test_a_report_that_cannot_tell_forgets_what_was_reported(bad):
    a = reports((1.00, 10.0), (1.02, 14.0))
    a.report(1.04, bad)
    assert a.over_period(1.02, 0.0) is None and a.over_period(1.04, 0.0) is None


def test_a_repeated_frame_does_not_shift_the_previous_report():
    a = reports((1.00, 10.0), (1.02, 14.0), (1.02, 14.0))
    np.testing.assert_allclose(a.over_period(1.02, 0.01), np.full(4, 12.0))


def test_reports_a_jittered_period_apart_mix_as_the_controller_counts_its_steps_consecutive():
    a = reports((1.00, 10.0), (1.027, 14.0))          # 1.35 periods: the next frame, late, not a lost one
    np.testing.assert_allclose(a.over_period(1.027, 0.01), np.full(4, 12.0))
