"""The flight controller's announcement of an injected fault (STATUSTEXT INFO), made and read
back: the simulated FC says it for every fault it applies (a command's, a scenario's), so a
flight's log, the companion's included, carries each fault's instant, rotor, loss and kind.

    rotor 4 motor stop injected            all rotors loss 50% injected
    rotor 3 propeller loss injected        rotor 2 propeller damage 40% injected
    rotor 4 restored

The loss is said in whole percent (a STATUSTEXT holds 50 characters): read back, it is
within 0.5 % of the one applied.
"""

from __future__ import annotations

import re
from typing import NamedTuple

from m4.fault_kind import FaultKind

_LOSS_TEXT = {
    FaultKind.DEGRADED: lambda loss: f"loss {100.0 * loss:.0f}%",
    FaultKind.MOTOR: lambda loss: "motor stop",
    FaultKind.PROPELLER: lambda loss: "propeller loss",
    FaultKind.DAMAGE: lambda loss: f"propeller damage {100.0 * loss:.0f}%",
}
_PATTERN = re.compile(r"^(?:rotor (?P<rotor>[1-9])|all rotors) (?:(?P<restored>restored)|(?:(?P<motor>motor stop)"
                      r"|(?P<propeller>propeller loss)|propeller damage (?P<damage>\d+)%|loss (?P<degraded>\d+)%)"
                      r" injected)$")


class AnnouncedFault(NamedTuple):
    rotor: int                     # 1..4, 0: all
    loss: float                    # 0: restored
    kind: FaultKind


def fault_text(rotor: int, loss: float, kind: FaultKind) -> str:
    """What the flight controller says when it applies `loss` of `kind` on `rotor` (0: all; loss 0 restores)."""
    which = "all rotors" if rotor == 0 else f"rotor {rotor}"
    return f"{which} restored" if loss == 0.0 else f"{which} {_LOSS_TEXT[kind](loss)} injected"


def read_fault_text(text: str) -> AnnouncedFault | None:
    """The fault a flight controller's announcement states; None for any other text."""
    found = _PATTERN.match(text)
    if found is None:
        return None
    rotor = int(found["rotor"] or 0)
    if found["restored"]:
        return AnnouncedFault(rotor, 0.0, FaultKind.DEGRADED)
    if found["motor"]:
        return AnnouncedFault(rotor, 1.0, FaultKind.MOTOR)
    if found["propeller"]:
        return AnnouncedFault(rotor, 1.0, FaultKind.PROPELLER)
    if found["damage"]:
        return AnnouncedFault(rotor, int(found["damage"]) / 100.0, FaultKind.DAMAGE)
    return AnnouncedFault(rotor, int(found["degraded"]) / 100.0, FaultKind.DEGRADED)
