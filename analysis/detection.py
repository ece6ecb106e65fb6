"""When a fault counts as detected: one rule for the simulator's truth (sitl.flights.metrics) and for a
tlog alone (analysis.flight_metrics), on plain arrays of the companion's M4_FAULT_STATUS.

A fault is detected at the first status in [its at_s, the next later fault's at_s) that is
CONFIRMED and names a rotor whose thrust ceiling estimate reflects this fault: at most the
ceiling the fault leaves its rotor + DETECTION_MARGIN x hover thrust per rotor. The rotor named
need not be the fault's (detected_rotor says which). Faults that start at one instant share
their window. A fault whose ceiling is unknown (None) is detected at the first confirmation
naming a rotor, whatever its estimate.

The ceiling comes from whoever knows it: the simulator from its motor model
(sitl.plant.thrusters.fault_ceiling_n), a tlog from the fault's kind and loss (stated_ceiling_n).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from m4.mavlink import mavlink

CONFIRMED = mavlink.M4_FAULT_STATE_CONFIRMED
DETECTION_MARGIN = 0.25
_TOTAL_KINDS = ("motor", "propeller")


@dataclass(frozen=True)
class Fault:
    at_s: float
    rotor: int                     # 1..4, 0: all
    loss: float                    # 0 restores
    kind: str = "degraded"         # an injectable FaultKind's label (m4.fault_kind): degraded, motor, propeller, damage
    until_s: float | None = None   # the fault ends here (None: never, or a later restore says so)


def stated_ceiling_n(fault: Fault, hover_thrust_per_rotor_n: float) -> float | None:
    """The ceiling the fault leaves its rotor as far as its kind and loss say: 0 for a stopped
    motor or a lost propeller, (1 - loss) x hover thrust for a degraded motor; None for a
    restore and for a damaged propeller (its ceiling depends on the motor: sitl.plant.thrusters)."""
    if fault.loss == 0.0:
        return None
    if fault.kind in _TOTAL_KINDS:
        return 0.0
    return (1.0 - fault.loss) * hover_thrust_per_rotor_n if fault.kind == "degraded" else None


def first_confirmation_s(time_s: np.ndarray, state: np.ndarray) -> float | None:
    """The first confirmed status, whatever it names (where the companion holds on a fault)."""
    hits = np.flatnonzero(state == CONFIRMED)
    return float(time_s[hits[0]]) if hits.size else None


def _first_detection(time_s: np.ndarray, state: np.ndarray, rotor: np.ndarray, thrust_max_estimate_n: np.ndarray,
                     from_s: float, until_s: float, bound_n: float | None) -> tuple[float, int] | None:
    """(instant, rotor) of the first confirmation in [from_s, until_s) sizing its rotor at most
    bound_n (None: naming a rotor is enough)."""
    for k in np.flatnonzero((state == CONFIRMED) & (time_s >= from_s) & (time_s < until_s)):
        named = int(rotor[k])
        if 1 <= named <= thrust_max_estimate_n.shape[1] and (bound_n is None
                                                              or thrust_max_estimate_n[k, named - 1] <= bound_n):
            return float(time_s[k]), named
    return None


def detections(faults: Sequence[Fault], ceilings_n: Sequence[float | None], hover_thrust_per_rotor_n: float,
               time_s: np.ndarray, state: np.ndarray, rotor: np.ndarray,
               thrust_max_estimate_n: np.ndarray) -> list[dict]:
    """Each fault (in time order, with the ceiling it leaves its rotor) and its detection, from the
    companion's statuses: time_s, state, rotor (n,) and thrust_max_estimate_n (n, 4)."""
    margin_n = DETECTION_MARGIN * hover_thrust_per_rotor_n
    ends_s = [min((later.at_s for later in faults[i + 1:] if later.at_s > fault.at_s), default=math.inf)
              for i, fault in enumerate(faults)]
    out = []
    for fault, ceiling_n, end_s in zip(faults, ceilings_n, ends_s):
        bound_n = None if ceiling_n is None else ceiling_n + margin_n
        hit = _first_detection(time_s, state, rotor, thrust_max_estimate_n, fault.at_s, end_s, bound_n)
        out.append({"at_s": fault.at_s, "rotor": fault.rotor, "loss": fault.loss, "kind": fault.kind,
                    "until_s": fault.until_s, "detected_at_s": None if hit is None else hit[0],
                    "detected_rotor": None if hit is None else hit[1],
                    "latency_s": None if hit is None else hit[0] - fault.at_s})
    return out
