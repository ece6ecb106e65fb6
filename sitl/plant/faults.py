"""A scenario's faults as a schedule on the simulated clock (integer milliseconds since the
scenario's t = 0): what starts and what ends at each instant, for whoever applies them (the
project's flight controller, or the physics behind ArduPilot)."""

from __future__ import annotations

from collections.abc import Iterable

from m4.scenario import Fault


class FaultSchedule:
    def __init__(self, faults: Iterable[Fault]):
        """Every start and every until_s of `faults`; at one instant an end comes before a start,
        so a fault may take over the rotor another one leaves."""
        events = [(round(f.at_s * 1000), f, False) for f in faults]
        events += [(round(f.until_s * 1000), f, True) for f in faults if f.until_s is not None]
        self._events = sorted(events, key=lambda e: (e[0], not e[2]))

    def next_ms(self) -> int | None:
        """When the next event is due (None: none left)."""
        return self._events[0][0] if self._events else None

    def due(self, now_ms: int) -> list[tuple[Fault, bool]]:
        """(fault, whether it ends) of every event due by `now_ms`, in order, taken off the schedule."""
        taken = []
        while self._events and self._events[0][0] <= now_ms:
            _, fault, ends = self._events.pop(0)
            taken.append((fault, ends))
        return taken


def describe(fault: Fault, ends: bool) -> str:
    """One line for the log: what starts or ends."""
    if ends:
        return f"scenario fault over, rotor {fault.rotor} restored"
    return f"scenario fault, rotor {fault.rotor} {fault.kind.label} loss {fault.loss:g}"
