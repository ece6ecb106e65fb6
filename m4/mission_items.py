"""Mission items of the MAVLink mission protocol, checked and turned into the mission flown.

A ground station plans a mission as MISSION_ITEM_INTs (docs/missions.md); the flight controller
checks each item as it arrives (`check_item`: the MISSION_ACK error that refuses it, with a
line saying why) and keeps them; the companion downloads them and flies them as an
m4.mission.Mission (`to_mission`). One set of rules for both ends:

- item 0 is home (ArduPilot's convention): whatever it holds, the FC's fixed home stands;
- MAV_CMD_NAV_WAYPOINT: fly to x, y, z; param1 the hold there (s);
- MAV_CMD_DO_CHANGE_SPEED: param2 the speed of the legs after it (m/s; -1: no change);
- MAV_CMD_NAV_LAND: land; in a global frame x = y = 0 lands where the robot is, else it flies
  there first at the last waypoint's altitude; in MAV_FRAME_LOCAL_NED always at x, y. Nothing
  may follow it; the landing starts when the last waypoint's hold ends as planned;
- frames: MAV_FRAME_GLOBAL_RELATIVE_ALT(_INT) (x, y: latitude, longitude in degE7, z the
  height above home in m; m4.home places them), MAV_FRAME_LOCAL_NED (x, y: north, east in
  m x 1e4, the protocol's scaling for local frames; z down in m); a DO item's frame is not read;
- anything else is refused: another command MAV_MISSION_UNSUPPORTED, another frame
  MAV_MISSION_UNSUPPORTED_FRAME, a value out of range MAV_MISSION_INVALID_PARAM<n>.
Legs fly at DEFAULT_SPEED_M_S until a DO_CHANGE_SPEED; the descent at
DEFAULT_DESCENT_SPEED_M_S. The fault policy is the companion's (m4.mission ON_FAULT_CHOICES).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from m4.home import Home
from m4.mavlink import mavlink
from m4.mission import (DEFAULT_DESCENT_SPEED_M_S, DEFAULT_SPEED_M_S, MAX_ALTITUDE_M, MAX_DISTANCE_M, MAX_HOLD_S,
                        MAX_SPEED_M_S, Landing, Mission, Waypoint)

m = mavlink
GLOBAL_FRAMES = (m.MAV_FRAME_GLOBAL_RELATIVE_ALT, m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
LOCAL_SCALE = 1e4                 # MISSION_ITEM_INT x, y in a local frame: metres x 1e4
DEGE7 = 1e7
NO_CHANGE = -1.0                  # DO_CHANGE_SPEED param2: keep the speed
_NAV = (m.MAV_CMD_NAV_WAYPOINT, m.MAV_CMD_NAV_LAND)


class MissionItem(NamedTuple):
    """One MISSION_ITEM_INT's content, as kept by the flight controller."""
    seq: int
    frame: int
    command: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    current: int = 0
    autocontinue: int = 1

    @classmethod
    def from_message(cls, msg) -> MissionItem:
        return cls(msg.seq, msg.frame, msg.command, msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y,
                   msg.z, msg.current, msg.autocontinue)

    def message(self, target_system: int, target_component: int) -> m.MAVLink_mission_item_int_message:
        return m.MAVLink_mission_item_int_message(
            target_system, target_component, self.seq, self.frame, self.command, self.current, self.autocontinue,
            self.param1, self.param2, self.param3, self.param4, self.x, self.y, self.z, m.MAV_MISSION_TYPE_MISSION)


class ItemRefused(NamedTuple):
    result: int                   # MAV_MISSION_RESULT for the MISSION_ACK
    text: str                     # why, in one line


def home_item(home: Home) -> MissionItem:
    """Item 0 as the FC reports it: its home, a waypoint in MAV_FRAME_GLOBAL (altitude AMSL)."""
    return MissionItem(0, m.MAV_FRAME_GLOBAL, m.MAV_CMD_NAV_WAYPOINT, 0.0, 0.0, 0.0, 0.0,
                       round(home.lat_deg * DEGE7), round(home.lon_deg * DEGE7), home.alt_amsl_m)


def item_ned_m(item: MissionItem, home: Home) -> tuple[float, float, float]:
    """The local NED position (m) of a navigation item."""
    if item.frame == m.MAV_FRAME_LOCAL_NED:
        return item.x / LOCAL_SCALE, item.y / LOCAL_SCALE, float(item.z)
    north, east = home.north_east_m(item.x / DEGE7, item.y / DEGE7)
    return north, east, -float(item.z)


def _lands_here(item: MissionItem) -> bool:
    return item.command == m.MAV_CMD_NAV_LAND and item.frame in GLOBAL_FRAMES and item.x == 0 and item.y == 0


def check_item(item: MissionItem, before: Sequence[MissionItem], home: Home) -> ItemRefused | None:
    """Why `item` cannot follow the items `before` it (from seq 0), or None: it can."""
    if item.seq == 0:
        return None
    name = f"item {item.seq}"
    if any(b.command == m.MAV_CMD_NAV_LAND for b in before):
        return ItemRefused(m.MAV_MISSION_INVALID_SEQUENCE, f"{name}: nothing may follow NAV_LAND")
    if item.command == m.MAV_CMD_DO_CHANGE_SPEED:
        if item.param2 != NO_CHANGE and not (math.isfinite(item.param2) and 0.0 < item.param2 <= MAX_SPEED_M_S):
            return ItemRefused(m.MAV_MISSION_INVALID_PARAM2,
                               f"{name}: speed {item.param2:g} m/s outside (0, {MAX_SPEED_M_S:g}]")
        return None
    if item.command not in _NAV:
        return ItemRefused(m.MAV_MISSION_UNSUPPORTED, f"{name}: command {item.command} not supported")
    if item.frame not in (*GLOBAL_FRAMES, m.MAV_FRAME_LOCAL_NED):
        return ItemRefused(m.MAV_MISSION_UNSUPPORTED_FRAME, f"{name}: frame {item.frame} not supported")
    if item.command == m.MAV_CMD_NAV_WAYPOINT and not (math.isfinite(item.param1) and 0 <= item.param1 <= MAX_HOLD_S):
        return ItemRefused(m.MAV_MISSION_INVALID_PARAM1, f"{name}: hold {item.param1:g} s outside [0, {MAX_HOLD_S:g}]")
    if _lands_here(item):
        return None
    if item.command == m.MAV_CMD_NAV_LAND and not any(b.command == m.MAV_CMD_NAV_WAYPOINT for b in before[1:]):
        return ItemRefused(m.MAV_MISSION_INVALID_SEQUENCE, f"{name}: a located NAV_LAND needs a waypoint before it")
    north, east, down = item_ned_m(item, home)
    for value, result, axis in ((north, m.MAV_MISSION_INVALID_PARAM5_X, "north"),
                                (east, m.MAV_MISSION_INVALID_PARAM6_Y, "east")):
        if not abs(value) <= MAX_DISTANCE_M:
            return ItemRefused(result, f"{name}: {value:g} m {axis} of home, beyond {MAX_DISTANCE_M:g} m")
    if item.command == m.MAV_CMD_NAV_WAYPOINT and not (math.isfinite(down) and 0.0 <= -down <= MAX_ALTITUDE_M):
        return ItemRefused(m.MAV_MISSION_INVALID_PARAM7,
                           f"{name}: height {-down:g} m above home outside [0, {MAX_ALTITUDE_M:g}]")
    return None


@dataclass(frozen=True)
class FlownMission:
    """A mission from the FC's items: what the companion flies, and for each of its waypoints
    (then its landing) the item's seq, for the progress the companion reports."""
    mission: Mission
    seqs: tuple[int, ...]


def to_mission(items: Sequence[MissionItem], home: Home, on_fault: str) -> FlownMission:
    """The mission the items (item 0 home) describe; ValueError naming the first item
    check_item refuses."""
    waypoints: list[Waypoint] = []
    seqs: list[int] = []
    land = None
    speed_m_s = DEFAULT_SPEED_M_S
    for i, item in enumerate(items):
        if (refused := check_item(item, items[:i], home)) is not None:
            raise ValueError(refused.text)
        if i == 0:
            continue
        if item.command == m.MAV_CMD_DO_CHANGE_SPEED:
            speed_m_s = speed_m_s if item.param2 == NO_CHANGE else float(item.param2)
            continue
        if item.command == m.MAV_CMD_NAV_LAND:
            if not _lands_here(item):
                north, east, _ = item_ned_m(item, home)
                waypoints.append(Waypoint((north, east, waypoints[-1].ned_m[2]), speed_m_s, 0.0))
                seqs.append(item.seq)
            land = Landing(at_s=None, descent_speed_m_s=DEFAULT_DESCENT_SPEED_M_S)
        else:
            waypoints.append(Waypoint(item_ned_m(item, home), speed_m_s, float(item.param1)))
        seqs.append(item.seq)
    return FlownMission(Mission(on_fault=on_fault, waypoints=tuple(waypoints), land=land), tuple(seqs))
