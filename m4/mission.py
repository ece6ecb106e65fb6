"""The scenario file's `[mission]` (docs/interfaces.md): what the companion flies.

The table as the companion and the simulator read it; a mission file (`--mission FILE`),
which is a whole scenario or a `[mission]` table alone, is read by `m4.scenario.load_mission`.
Units SI, positions local NED (z negative is up). Unknown keys and out-of-range values raise
ConfigError naming the key.
"""

from __future__ import annotations

from dataclasses import dataclass

from m4.toml_fields import ConfigError, Table

ON_FAULT_CHOICES = ("hold", "continue")
MAX_SPEED_M_S = 15.0
MAX_ALTITUDE_M = 500.0
MAX_HOLD_S = 3600.0
MAX_DISTANCE_M = 1e5          # north or east of the origin


@dataclass(frozen=True)
class Waypoint:
    ned_m: tuple[float, float, float]
    speed_m_s: float          # speed of the reference along the leg to this waypoint
    hold_s: float             # time to stay at it before the next one


DEFAULT_SPEED_M_S = 1.0
DEFAULT_DESCENT_SPEED_M_S = 0.5


@dataclass(frozen=True)
class Landing:
    at_s: float | None        # from here the reference descends to the ground (None: once the last
    descent_speed_m_s: float  # waypoint's hold ends, as planned: a mission from a ground station)


@dataclass(frozen=True)
class Mission:
    on_fault: str = "hold"    # "hold": hold where the fault was detected; "continue": keep tracking
    waypoints: tuple[Waypoint, ...] = ()
    land: Landing | None = None


def parse_mission(t: Table) -> Mission:
    on_fault = t.string("on_fault", "hold", choices=ON_FAULT_CHOICES)
    waypoints = tuple(_parse_waypoint(w) for w in t.tables("waypoint"))
    land = None
    if t.has("land"):
        lt = t.table("land")
        land = Landing(at_s=lt.number("at_s", lo=0.0),
                       descent_speed_m_s=lt.number("descent_speed_m_s", DEFAULT_DESCENT_SPEED_M_S, lo=0.05,
                                                   lo_open=False, hi=3.0))
        lt.finish()
    t.finish()
    return Mission(on_fault=on_fault, waypoints=waypoints, land=land)


def ned_position(t: Table, key: str, default=None) -> tuple[float, float, float]:
    """A local NED position (m) at or above the ground and below MAX_ALTITUDE_M."""
    ned = t.vector(key, 3, default, lo=-MAX_DISTANCE_M, hi=MAX_DISTANCE_M)
    if ned[2] > 0.0:
        raise ConfigError(f"{t.where} {key}: z must be <= 0 (NED, up is negative), got {ned[2]:g}")
    if -ned[2] > MAX_ALTITUDE_M:
        raise ConfigError(f"{t.where} {key}: altitude {-ned[2]:g} m is above {MAX_ALTITUDE_M:g} m")
    return ned  # type: ignore[return-value]


def _parse_waypoint(t: Table) -> Waypoint:
    w = Waypoint(ned_m=ned_position(t, "ned_m"),
                 speed_m_s=t.number("speed_m_s", DEFAULT_SPEED_M_S, lo=0.0, lo_open=True, hi=MAX_SPEED_M_S),
                 hold_s=t.number("hold_s", 0.0, lo=0.0, hi=MAX_HOLD_S))
    t.finish()
    return w
