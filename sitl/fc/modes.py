"""The simulated flight controller's modes and how they look on the wire, so that any ground
station shows them for what they are.

- HEARTBEAT: autopilot MAV_AUTOPILOT_GENERIC, base_mode MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and
  MAVLink's standard flags (SAFETY_ARMED; GUIDED while the companion's setpoints fly, AUTO
  while the FC's own failsafe does; STABILIZE whenever a controller holds the attitude),
  custom_mode our mode number (m4.fc_mode: ArduCopter's number of the same mode, so
  pymavlink and MAVProxy, which read custom_mode through ArduCopter's table for a quadrotor,
  show GUIDED, LOITER and LAND; LANDED shows as Mode(100)).
- The standard modes protocol (MAVLink's development.xml, which the dialect includes):
  CURRENT_MODE on every mode change and every CURRENT_MODE_INTERVAL_MS; AVAILABLE_MODES on
  MAV_CMD_REQUEST_MESSAGE (param2: 0 for every mode, else the mode's index from 1). HOLD and
  LAND are the standard POSITION_HOLD and LAND (no name, as the protocol asks); COMPANION and
  LANDED are custom modes with their names. COMPANION, HOLD and LAND are user selectable
  (sitl/fc/commands.py: MAV_CMD_DO_SET_MODE with our numbers, or PX4's main and sub mode as
  MAVSDK sends them, MAV_CMD_DO_SET_STANDARD_MODE, MAV_CMD_NAV_LAND);
  CURRENT_MODE's intended_custom_mode is the one selected, custom_mode the one in force (the
  failsafe's, while setpoints are stale). A new mode is one more row of `MODES`.
"""

from __future__ import annotations

from dataclasses import dataclass

from m4.fc_mode import FcMode
from m4.mavlink import mavlink

m = mavlink
CURRENT_MODE_INTERVAL_MS = 2000           # 0.5 Hz, the protocol's nominal rate


@dataclass(frozen=True)
class ModeInfo:
    mode: FcMode
    standard_mode: int             # MAV_STANDARD_MODE
    name: str                      # sent for the custom (non-standard) modes only
    base_flags: int                # MAV_MODE_FLAG bits besides SAFETY_ARMED
    selectable: bool = True        # a ground station or the companion may select it


_STAB = m.MAV_MODE_FLAG_STABILIZE_ENABLED
MODES = (
    ModeInfo(FcMode.COMPANION, m.MAV_STANDARD_MODE_NON_STANDARD, "COMPANION", _STAB | m.MAV_MODE_FLAG_GUIDED_ENABLED),
    ModeInfo(FcMode.HOLD, m.MAV_STANDARD_MODE_POSITION_HOLD, "HOLD", _STAB | m.MAV_MODE_FLAG_AUTO_ENABLED),
    ModeInfo(FcMode.LAND, m.MAV_STANDARD_MODE_LAND, "LAND", _STAB | m.MAV_MODE_FLAG_AUTO_ENABLED),
    ModeInfo(FcMode.LANDED, m.MAV_STANDARD_MODE_NON_STANDARD, "LANDED", 0, selectable=False),
)
_BY_MODE = {info.mode: info for info in MODES}


def base_mode(custom_mode: int, armed: bool) -> int:
    """HEARTBEAT.base_mode for a mode: custom_mode holds it, the standard flags say who flies."""
    flags = _BY_MODE[FcMode(custom_mode)].base_flags | m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    return flags | (m.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)


def current_mode(custom_mode: int, intended: int) -> mavlink.MAVLink_current_mode_message:
    """CURRENT_MODE: the mode in force (`custom_mode`) and the one selected (`intended`)."""
    info = _BY_MODE[FcMode(custom_mode)]
    return m.MAVLink_current_mode_message(info.standard_mode, int(info.mode), int(intended))


def mode_info(mode: FcMode) -> ModeInfo:
    return _BY_MODE[mode]


# MAV_CMD_DO_SET_MODE as MAVSDK sends it to any autopilot but ArduPilot: PX4's (main mode,
# sub mode) in param2 and param3 (PX4's px4_custom_mode.h: AUTO 4; LOITER 3, LAND 6).
PX4_MODES = {(4, 3): FcMode.HOLD, (4, 6): FcMode.LAND}


def by_standard_mode(standard_mode: int) -> FcMode | None:
    """The selectable mode a MAV_STANDARD_MODE names (None: none of ours, or NON_STANDARD)."""
    for info in MODES:
        if info.selectable and info.standard_mode == standard_mode != m.MAV_STANDARD_MODE_NON_STANDARD:
            return info.mode
    return None


def available_modes(index: int) -> list[mavlink.MAVLink_available_modes_message] | None:
    """AVAILABLE_MODES for mode `index` (1..n), or for every mode (0); None: no such index."""
    if not 0 <= index <= len(MODES):
        return None
    picked = range(1, len(MODES) + 1) if index == 0 else (index,)
    return [_available(i) for i in picked]


def _available(index: int) -> mavlink.MAVLink_available_modes_message:
    info = MODES[index - 1]
    name = b"" if info.standard_mode != m.MAV_STANDARD_MODE_NON_STANDARD else info.name.encode()
    properties = 0 if info.selectable else m.MAV_MODE_PROPERTY_NOT_USER_SELECTABLE
    return m.MAVLink_available_modes_message(len(MODES), index, info.standard_mode, int(info.mode), properties, name)
