"""What fails on a rotor, numbered as the dialect's M4_FAULT_KIND: one vocabulary for what the
companion's detector concludes (M4_FAULT_STATUS.kind), what a scenario file or
MAV_CMD_M4_ROTOR_LOSS makes fail in the simulated plant, and what the logs record.

- UNKNOWN: thrust lost, no evidence of how (the detector without ESC telemetry). Nothing one
  can inject: MAV_CMD_M4_ROTOR_LOSS reads it (0, also an omitted param3) as DEGRADED.
- MOTOR: motor or ESC stopped: rotor speed, thrust and current go to zero.
- PROPELLER: propeller lost: no thrust, the unloaded motor overspeeds on its no-load current.
- DAMAGE: damaged propeller: less thrust at the same speed.
- DEGRADED: the motor cannot reach the speed asked: a lower ceiling.

The values are written here, not read from the generated dialect, so the control core need
not load pymavlink; tests/mavlink/test_dialect.py checks them against it.
"""

from __future__ import annotations

import math
from enum import IntEnum


class FaultKind(IntEnum):
    UNKNOWN = 0
    MOTOR = 1
    PROPELLER = 2
    DAMAGE = 3
    DEGRADED = 4

    @classmethod
    def named(cls, label: str) -> FaultKind:
        """The kind a label names ("motor", as in scenario files)."""
        return cls[label.upper()]

    @property
    def label(self) -> str:
        return self.name.lower()


INJECTABLE = (FaultKind.DEGRADED, FaultKind.MOTOR, FaultKind.PROPELLER, FaultKind.DAMAGE)   # the default first


def rotor_loss_kind(param3: float) -> FaultKind | None:
    """The kind MAV_CMD_M4_ROTOR_LOSS's param3 injects: UNKNOWN (0, the default) is DEGRADED,
    the plain loss of thrust; None: no kind's number."""
    if not math.isfinite(param3) or param3 != int(param3) or int(param3) not in set(FaultKind):
        return None
    kind = FaultKind(int(param3))
    return FaultKind.DEGRADED if kind is FaultKind.UNKNOWN else kind
