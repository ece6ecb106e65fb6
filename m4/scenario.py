"""Scenario files (docs/interfaces.md): what is flown, what fails, how the plant differs.

The plant reads `[start]`, `[[fault]]`, `[plant]`, `[wind]` and `[sensors]`; the companion reads `[mission]`
(`m4.mission`, parsed here too so that a scenario is checked whole before it flies). Units
SI, positions local NED (z negative is up), angles in degrees in the file. Unknown keys and
out-of-range values raise ConfigError naming the key.

A mission file (the companion's `--mission`) is a whole scenario, checked whole by the same
rules, or a `[mission]` table alone (`load_mission`): the format lives on the shared floor so
that the companion checks it without the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from m4.airframe import ROTOR_COUNT
from m4.fault_kind import INJECTABLE, FaultKind
from m4.mission import Mission, ned_position, parse_mission
from m4.toml_fields import ConfigError, Table, load_toml


@dataclass(frozen=True)
class Fault:
    at_s: float
    rotor: int                # 1..4
    loss: float               # DEGRADED: max thrust becomes (1 - loss) x hover thrust; see sitl/plant/thrusters.py
    kind: FaultKind = FaultKind.DEGRADED
    until_s: float | None = None       # the fault ends here (None: never)


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
    esc_telemetry: bool = True            # False: the FC has no ESC telemetry and never sends it
    battery: bool = False                 # True: the pack sags over the flight (sitl/plant/battery.py)
    battery_charge: float = 1.0           # state of charge at t = 0 when the pack sags


TURBULENCE_LEVELS = ("none", "light", "moderate", "severe")
WIND_SPEED_MAX_M_S = 30.0          # any wind, mean or gust peak, per axis: beyond it the robot cannot fly


@dataclass(frozen=True)
class Gust:
    """A discrete 1-cosine gust: peak_ned_m_s x (1 - cos(2 pi (t - at_s) / duration_s)) / 2 while
    at_s <= t <= at_s + duration_s (sitl/plant/wind.py)."""
    at_s: float
    peak_ned_m_s: tuple[float, float, float]
    duration_s: float


@dataclass(frozen=True)
class Wind:
    """The air the robot flies in (sitl/plant/wind.py): the air's velocity over the ground."""
    mean_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turbulence: str = "none"              # one of TURBULENCE_LEVELS: Dryden, MIL-HDBK-1797 low altitude
    gusts: tuple[Gust, ...] = ()


SENSOR_PROFILES = ("ideal", "mocap", "gps")


@dataclass(frozen=True)
class Sensors:
    """What the flight controller's reported state is built from (m4/sensor_profiles.py):
    "ideal" is the truth (with [plant] sensor_noise's white noise), "mocap" and "gps" the
    FC's estimator on simulated sensors."""
    profile: str = "ideal"                # one of SENSOR_PROFILES


@dataclass(frozen=True)
class Scenario:
    name: str
    duration_s: float
    start: Start = field(default_factory=Start)
    mission: Mission = field(default_factory=Mission)
    faults: tuple[Fault, ...] = ()
    plant: PlantOptions = field(default_factory=PlantOptions)
    wind: Wind | None = None              # None: no [wind] table, still air (the plant as calibrated)
    sensors: Sensors = field(default_factory=Sensors)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file."""
    path = Path(path)
    return parse_scenario(load_toml(path), path.name)


def parse_scenario(data: dict, where: str) -> Scenario:
    top = Table(data, where)
    name = top.string("name")
    duration_s = top.number("duration_s", lo=0.0, lo_open=True, hi=3600.0)
    start = _parse_start(top.table("start"))
    mission = parse_mission(top.table("mission"))
    faults = tuple(sorted((_parse_fault(t, duration_s) for t in top.tables("fault")), key=lambda f: f.at_s))
    plant = _parse_plant(top.table("plant"))
    wind = _parse_wind(top.table("wind"), duration_s) if top.has("wind") else None
    sensors = _parse_sensors(top.table("sensors"))
    top.finish()
    if mission.land is not None and mission.land.at_s > duration_s:
        raise ConfigError(f"{where} [mission.land] at_s ({mission.land.at_s:g}) is after duration_s ({duration_s:g})")
    return Scenario(name=name, duration_s=duration_s, start=start, mission=mission, faults=faults, plant=plant,
                    wind=wind, sensors=sensors)


def _parse_start(t: Table) -> Start:
    s = Start(ned_m=ned_position(t, "ned_m", list(Start.ned_m)),
              yaw_deg=t.number("yaw_deg", 0.0, lo=-360.0, hi=360.0))
    t.finish()
    return s


_KINDS = tuple(k.label for k in INJECTABLE)


def _parse_fault(t: Table, duration_s: float) -> Fault:
    at_s = t.number("at_s", lo=0.0, hi=duration_s)
    f = Fault(at_s=at_s,
              rotor=t.integer("rotor", lo=1, hi=ROTOR_COUNT),
              loss=t.number("loss", 1.0, lo=0.0, hi=1.0),
              kind=FaultKind.named(t.string("kind", FaultKind.DEGRADED.label, choices=_KINDS)),
              until_s=t.number("until_s", lo=at_s, lo_open=True, hi=duration_s) if t.has("until_s") else None)
    t.finish()
    return f


def _parse_plant(t: Table) -> PlantOptions:
    thrust_max_n = t.number("thrust_max_n", lo=1.0, hi=200.0) if t.has("thrust_max_n") else None
    p = PlantOptions(mass_scale=t.number("mass_scale", 1.0, lo=0.5, hi=2.0),
                     inertia_scale=t.number("inertia_scale", 1.0, lo=0.5, hi=2.0),
                     thrust_max_n=thrust_max_n,
                     sensor_noise=t.boolean("sensor_noise", False),
                     esc_telemetry=t.boolean("esc_telemetry", True),
                     battery=t.boolean("battery", False),
                     battery_charge=t.number("battery_charge", 1.0, lo=0.0, hi=1.0))
    t.finish()
    return p


def _parse_wind(t: Table, duration_s: float) -> Wind:
    lim = WIND_SPEED_MAX_M_S
    w = Wind(mean_ned_m_s=t.vector("mean_ned_m_s", 3, [0.0, 0.0, 0.0], lo=-lim, hi=lim),
             turbulence=t.string("turbulence", "none", choices=TURBULENCE_LEVELS),
             gusts=tuple(sorted((_parse_gust(g, duration_s) for g in t.tables("gust")), key=lambda g: g.at_s)))
    t.finish()
    return w


def _parse_gust(t: Table, duration_s: float) -> Gust:
    lim = WIND_SPEED_MAX_M_S
    g = Gust(at_s=t.number("at_s", lo=0.0, hi=duration_s),
             peak_ned_m_s=t.vector("peak_ned_m_s", 3, lo=-lim, hi=lim),
             duration_s=t.number("duration_s", lo=0.0, lo_open=True, hi=60.0))
    t.finish()
    return g


def _parse_sensors(t: Table) -> Sensors:
    s = Sensors(profile=t.string("profile", "ideal", choices=SENSOR_PROFILES))
    t.finish()
    return s


def load_mission(path: str | Path) -> Mission:
    """The `[mission]` of a mission file: a whole scenario (one with a name or a duration),
    checked whole, or a file holding `[mission]` alone; anything else in it is an error naming it."""
    path = Path(path)
    data = load_toml(path)
    if "mission" not in data:
        raise ConfigError(f"{path.name}: no [mission] table")
    if "name" in data or "duration_s" in data:
        return parse_scenario(data, path.name).mission
    if extra := sorted(data.keys() - {"mission"}):
        raise ConfigError(f"{path.name}: unknown key(s) {', '.join(extra)} (a mission file holds [mission] alone, "
                          f"or is a whole scenario with name and duration_s)")
    return parse_mission(Table(data["mission"], f"{path.name} [mission]"))
