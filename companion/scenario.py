"""Scenario files (interfaces.md): what is flown, what fails, how the plant differs.

The plant reads `[start]`, `[[fault]]` and `[plant]`; the companion reads `[mission]` (its
`--mission FILE` may be a whole scenario or a file with only a `[mission]` table). Units SI,
positions local NED (z negative is up), angles in degrees in the file. Unknown keys and
out-of-range values raise ConfigError naming the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from companion.airframe import ROTOR_COUNT
from companion.toml_fields import ConfigError, Table, load_toml

ON_FAULT_CHOICES = ("hold", "continue")
MAX_SPEED_M_S = 15.0
MAX_ALTITUDE_M = 500.0


@dataclass(frozen=True)
class Waypoint:
    ned_m: tuple[float, float, float]
    speed_m_s: float          # speed of the reference along the leg to this waypoint
    hold_s: float             # time to stay at it before the next one


@dataclass(frozen=True)
class Landing:
    at_s: float               # from here the reference descends to the ground
    descent_speed_m_s: float


@dataclass(frozen=True)
class Mission:
    on_fault: str = "hold"    # "hold": hold where the fault was detected; "continue": keep tracking
    waypoints: tuple[Waypoint, ...] = ()
    land: Landing | None = None


@dataclass(frozen=True)
class Fault:
    at_s: float
    rotor: int                # 1..4
    loss: float               # loss of effectiveness: max thrust becomes (1 - loss) x hover thrust


@dataclass(frozen=True)
class Start:
    ned_m: tuple[float, float, float] = (0.0, 0.0, -2.0)
    yaw_deg: float = 0.0

    @property
    def yaw_rad(self) -> float:
        return math.radians(self.yaw_deg)


@dataclass(frozen=True)
class PlantOptions:
    """How the simulated robot differs from the controller's model."""

    mass_scale: float = 1.0
    inertia_scale: float = 1.0
    thrust_max_n: float | None = None     # None: the airframe's thrust_max_n
    sensor_noise: bool = False


@dataclass(frozen=True)
class Scenario:
    name: str
    duration_s: float
    start: Start = field(default_factory=Start)
    mission: Mission = field(default_factory=Mission)
    faults: tuple[Fault, ...] = ()
    plant: PlantOptions = field(default_factory=PlantOptions)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file."""
    path = Path(path)
    return parse_scenario(load_toml(path), path.name)


def load_mission(path: str | Path) -> Mission:
    """The `[mission]` of a file: a whole scenario or a file holding only `[mission]`."""
    path = Path(path)
    data = load_toml(path)
    if "mission" not in data:
        raise ConfigError(f"{path.name}: no [mission] table")
    if set(data) - {"mission"}:
        return parse_scenario(data, path.name).mission
    top = Table(data, path.name)
    mission = parse_mission(top.table("mission"))
    top.finish()
    return mission


def parse_scenario(data: dict, where: str) -> Scenario:
    top = Table(data, where)
    name = top.string("name")
    duration_s = top.number("duration_s", lo=0.0, lo_open=True, hi=3600.0)
    start = _parse_start(top.table("start"))
    mission = parse_mission(top.table("mission"))
    faults = tuple(sorted((_parse_fault(t, duration_s) for t in top.tables("fault")), key=lambda f: f.at_s))
    plant = _parse_plant(top.table("plant"))
    top.finish()
    if mission.land is not None and mission.land.at_s > duration_s:
        raise ConfigError(f"{where} [mission.land] at_s ({mission.land.at_s:g}) is after duration_s ({duration_s:g})")
    return Scenario(name=name, duration_s=duration_s, start=start, mission=mission, faults=faults, plant=plant)


def parse_mission(t: Table) -> Mission:
    on_fault = t.string("on_fault", "hold", choices=ON_FAULT_CHOICES)
    waypoints = tuple(_parse_waypoint(w) for w in t.tables("waypoint"))
    land = None
    if t.has("land"):
        lt = t.table("land")
        land = Landing(at_s=lt.number("at_s", lo=0.0),
                       descent_speed_m_s=lt.number("descent_speed_m_s", 0.5, lo=0.05, lo_open=False, hi=3.0))
        lt.finish()
    t.finish()
    return Mission(on_fault=on_fault, waypoints=waypoints, land=land)


def _ned_position(t: Table, key: str, default=None) -> tuple[float, float, float]:
    ned = t.vector(key, 3, default, lo=-1e5, hi=1e5)
    if ned[2] > 0.0:
        raise ConfigError(f"{t.where} {key}: z must be <= 0 (NED, up is negative), got {ned[2]:g}")
    if -ned[2] > MAX_ALTITUDE_M:
        raise ConfigError(f"{t.where} {key}: altitude {-ned[2]:g} m is above {MAX_ALTITUDE_M:g} m")
    return ned  # type: ignore[return-value]


def _parse_waypoint(t: Table) -> Waypoint:
    w = Waypoint(ned_m=_ned_position(t, "ned_m"),
                 speed_m_s=t.number("speed_m_s", 1.0, lo=0.0, lo_open=True, hi=MAX_SPEED_M_S),
                 hold_s=t.number("hold_s", 0.0, lo=0.0, hi=3600.0))
    t.finish()
    return w


def _parse_start(t: Table) -> Start:
    s = Start(ned_m=_ned_position(t, "ned_m", list(Start.ned_m)),
              yaw_deg=t.number("yaw_deg", 0.0, lo=-360.0, hi=360.0))
    t.finish()
    return s


def _parse_fault(t: Table, duration_s: float) -> Fault:
    f = Fault(at_s=t.number("at_s", lo=0.0, hi=duration_s),
              rotor=t.integer("rotor", lo=1, hi=ROTOR_COUNT),
              loss=t.number("loss", 1.0, lo=0.0, hi=1.0))
    t.finish()
    return f


def _parse_plant(t: Table) -> PlantOptions:
    thrust_max_n = t.number("thrust_max_n", lo=1.0, hi=200.0) if t.has("thrust_max_n") else None
    p = PlantOptions(mass_scale=t.number("mass_scale", 1.0, lo=0.5, hi=2.0),
                     inertia_scale=t.number("inertia_scale", 1.0, lo=0.5, hi=2.0),
                     thrust_max_n=thrust_max_n,
                     sensor_noise=t.boolean("sensor_noise", False))
    t.finish()
    return p
