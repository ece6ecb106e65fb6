"""The flight controller's modes, numbered as they go on the wire (HEARTBEAT and CURRENT_MODE
custom_mode, CURRENT_MODE intended_custom_mode, MAV_CMD_DO_SET_MODE param2): one vocabulary
for the simulated FC (sitl/fc/modes.py, where each mode's standard number and flags are) and
the companion, which flies what the FC's selected mode asks (docs/flight-controller.md#modes).
The numbers are ArduCopter's modes of the same meaning (GUIDED: a companion flies; LOITER;
LAND), so MAVProxy, Mission Planner and pymavlink name them and MAVProxy's `mode LOITER` sets
one; LANDED has no ArduCopter twin and a number outside its table. A new mode (a mission's:
ArduCopter's AUTO, 3) takes its ArduCopter number.

- COMPANION: the FC flies the companion's setpoints; the companion flies its mission.
- HOLD: position hold where it was selected; the companion flies it (its NMPC: a lost rotor is
  still flown), or the FC's failsafe while setpoints are stale.
- LAND: land where it is; flown as HOLD is.
- LANDED: on the ground, thrust cut, disarmed; nobody selects it.

Written here, not read from the dialect, so the control core need not load pymavlink.
"""

from __future__ import annotations

from enum import IntEnum


class FcMode(IntEnum):
    COMPANION = 4                  # ArduCopter's GUIDED
    HOLD = 5                       # LOITER
    LAND = 9                       # LAND
    LANDED = 100

    @classmethod
    def of(cls, number: int) -> FcMode | None:
        """The mode with this number, or None (another FC's, or a newer one's)."""
        try:
            return cls(number)
        except ValueError:
            return None
