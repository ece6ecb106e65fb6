"""The one rule for "the fault was detected" (analysis.detection), on plain arrays of statuses."""

import numpy as np
import pytest

from analysis.detection import CONFIRMED, DETECTION_MARGIN, Fault, detections, first_confirmation_s, stated_ceiling_n

HOVER_N = 14.7
MAX_N = 30.0
SUSPECT = 1
KEYS = {"at_s", "rotor", "loss", "kind", "until_s", "detected_at_s", "detected_rotor", "latency_s"}


def _statuses(rows):
    """rows: (t_s, state, rotor, estimate for that rotor); the other rotors at MAX_N."""
    est = np.full((len(rows), 4), MAX_N)
    for k, (_, _, rotor, e) in enumerate(rows):
        if rotor:
            est[k, rotor - 1] = e
    return (np.array([r[0] for r in rows], float), np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
            est)


def _found(faults, ceilings_n, rows):
    return [(f["detected_at_s"], f["detected_rotor"]) for f in detections(faults, ceilings_n, HOVER_N,
                                                                          *_statuses(rows))]


def test_a_confirmation_still_sizing_the_previous_fault_does_not_detect_the_next():
    faults = [Fault(7.0, 4, 0.33), Fault(14.0, 4, 0.66)]
    ceilings_n = [stated_ceiling_n(f, HOVER_N) for f in faults]
    rows = [(7.1, SUSPECT, 4, MAX_N), (7.3, CONFIRMED, 4, 0.67 * HOVER_N), (14.0, CONFIRMED, 4, 0.67 * HOVER_N),
            (14.6, CONFIRMED, 4, 0.34 * HOVER_N)]
    assert _found(faults, ceilings_n, rows) == [(7.3, 4), (14.6, 4)]


def test_the_bound_is_the_ceiling_plus_the_margin_and_a_detection_may_name_another_rotor():
    bound_n = 5.0 + DETECTION_MARGIN * HOVER_N
    rows = [(1.0, CONFIRMED, 2, bound_n + 0.01), (1.1, CONFIRMED, 3, bound_n)]
    assert _found([Fault(0.5, 4, 0.5)], [5.0], rows) == [(1.1, 3)]


def test_each_fault_is_looked_for_only_until_the_next_one():
    faults = [Fault(1.0, 4, 1.0), Fault(2.0, 1, 1.0)]
    rows = [(0.9, CONFIRMED, 4, 0.0), (2.0, CONFIRMED, 4, 0.0)]
    assert _found(faults, [0.0, 0.0], rows) == [(None, None), (2.0, 4)]


def test_faults_starting_at_one_instant_share_their_window():
    faults = [Fault(1.0, 2, 1.0), Fault(1.0, 4, 1.0), Fault(3.0, 1, 1.0)]
    rows = [(1.1, CONFIRMED, 4, 0.0), (3.1, CONFIRMED, 1, 0.0)]
    assert _found(faults, [0.0, 0.0, 0.0], rows) == [(1.1, 4), (1.1, 4), (3.1, 1)]


@pytest.mark.parametrize("estimate_n", [MAX_N, np.nan])
def test_an_unknown_ceiling_takes_the_first_confirmation_naming_a_rotor(estimate_n):
    rows = [(1.1, CONFIRMED, 0, 0.0), (1.2, CONFIRMED, 2, estimate_n)]
    assert _found([Fault(1.0, 2, 0.5, "damage")], [None], rows) == [(1.2, 2)]


def test_a_detection_has_every_key_of_the_fault_and_its_latency():
    fault = Fault(1.0, 4, 1.0, "propeller", until_s=3.0)
    [found] = detections([fault], [0.0], HOVER_N, *_statuses([(1.04, CONFIRMED, 4, 0.0)]))
    assert set(found) == KEYS
    assert (found["kind"], found["until_s"], found["latency_s"]) == ("propeller", 3.0, pytest.approx(0.04))
    [missed] = detections([fault], [0.0], HOVER_N, *_statuses([]))
    assert set(missed) == KEYS and missed["detected_at_s"] is missed["latency_s"] is None


@pytest.mark.parametrize("fault, ceiling_n", [
    (Fault(1.0, 4, 1.0, "motor"), 0.0), (Fault(1.0, 4, 1.0, "propeller"), 0.0),
    (Fault(1.0, 4, 0.5), 0.5 * HOVER_N), (Fault(1.0, 4, 1.0), 0.0),
    (Fault(1.0, 4, 0.5, "damage"), None), (Fault(1.0, 4, 0.0, "motor"), None), (Fault(1.0, 4, 0.5, "unknown"), None)])
def test_a_faults_kind_and_loss_state_its_ceiling_except_a_damaged_propellers_and_a_restore(fault, ceiling_n):
    assert stated_ceiling_n(fault, HOVER_N) == ceiling_n


def test_the_first_confirmation_is_whatever_it_names():
    time_s, state, _, _ = _statuses([(0.5, SUSPECT, 4, MAX_N), (0.7, CONFIRMED, 0, MAX_N), (0.9, CONFIRMED, 4, 0.0)])
    assert first_confirmation_s(time_s, state) == 0.7
    assert first_confirmation_s(time_s[:1], state[:1]) is None
