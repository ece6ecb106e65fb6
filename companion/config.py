"""The companion's configuration: ONE TOML file with every tunable, validated at start.

`load_config(path)` reads the file (None: every default, which flies the reference airframe
on the SITL's default link) and returns a frozen CompanionConfig; anything malformed raises
ConfigError naming the table and key. deploy/companion.toml documents every key.

The tables map onto the settings dataclasses of the parts they configure (NmpcConfig,
ReferenceConfig, TouchdownConfig, FaultDetectorConfig, FeedSettings): a key is a field's
name, its default is the field's default, and a field in radians (`*_rad`) is written in
degrees (`*_deg`) in the file. Relative paths are taken from the file's folder. The Zenoh
feed is the [feed] table of m4.feed.settings (absent: no feed); the flight log is [log].
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from m4.airframe import Airframe, load_airframe
from companion.core.disturbance import DisturbanceEstimator
from companion.core.fault_detector import FaultDetectorConfig
from companion.core.nmpc_config import NmpcConfig, NmpcWeights
from companion.core.reference import ReferenceConfig
from companion.core.touchdown import TouchdownConfig
from companion.core.upset import UpsetConfig
from companion.realtime import PRIORITY_MAX
from m4.feed.settings import FeedSettings, parse_feed_settings
from m4.mission import Mission, load_mission
from m4.toml_fields import ConfigError, Table, load_toml

RATE_MAX_HZ = 100.0
# The NMPC's solve time grows with its horizon (N = 20: 8 ms median, 18 ms p99,
# docs/performance.md); beyond this it cannot answer within a control period, and the code it compiles grows
# with it (N = 100000 would compile for hours).
HORIZON_MAX = 40
# 50 Hz: at the paper's 10 Hz every built-in scenario survives too, but a new fault waits up to
# 0.1 s for the next plan, the sag and tilt grow (24 N cap: 0.22 m against 0.13 m) and the
# landing comes down at 0.25 m/s against 0.06 m/s (docs/results.md, "Control rate").
DEFAULT_RATE_HZ = 50.0
# The rate feedback the FC closes around the plan (m4.setpoint, companion.core.rate_feedback):
# its bandwidth. Above ~1/(4 x the FC's 4 ms loop) it would ring on the FC's own loop delay.
DEFAULT_RATE_FEEDBACK_BANDWIDTH_RAD_S = 20.0
RATE_FEEDBACK_BANDWIDTH_MAX_RAD_S = 60.0
# The companion's solves stop iterating at half the control period (the research tools' NMPC,
# NmpcConfig's default, iterates until it converges).
COMPANION_TIME_BUDGET_SHARE = 0.5
DEFAULT_DISTURBANCE_GAIN = inspect.signature(DisturbanceEstimator).parameters["gain"].default


@dataclass(frozen=True)
class LinkConfig:
    fc_url: str = "udpin:127.0.0.1:14550"   # pymavlink form; serial: "/dev/ttyTHS1,921600"
    signing_key_path: Path | None = None    # 32-byte key (hex or raw); None: unsigned
    telemetry_timeout_s: float = 0.3        # no telemetry for this long: the link is lost
    delay_warning_s: float = 0.1            # setpoints acting this long after their instant: warn
    fc_system_id: int = 1                   # only this flight controller is listened to
    fc_component_id: int = 1


LOG_DIR_ENVS = ("M4_LOG_DIR", "LOGS_DIRECTORY")       # ours, then systemd's (the unit's LogsDirectory)


def default_log_dir() -> Path:
    """$M4_LOG_DIR, else $LOGS_DIRECTORY (set by systemd), else /var/log/m4."""
    return Path(next((os.environ[e] for e in LOG_DIR_ENVS if os.environ.get(e)), "/var/log/m4"))


@dataclass(frozen=True)
class LogSettings:
    """The flight log (companion/flight_log.py)."""
    enabled: bool = True
    dir: Path = field(default_factory=default_log_dir)
    max_file_mb: float = 256.0              # a longer flight goes on in a new file
    max_total_mb: float = 4096.0            # the oldest logs go beyond this


@dataclass(frozen=True)
class CompanionConfig:
    rate_hz: float = DEFAULT_RATE_HZ
    realtime_priority: int = 0              # SCHED_FIFO priority of the control loop, 1..99; 0: normal (companion/realtime.py)
    rate_feedback_bandwidth_rad_s: float = DEFAULT_RATE_FEEDBACK_BANDWIDTH_RAD_S   # 0: the FC flies thrust_n alone
    shortfall_cover: bool = True            # the FC covers a rotor its ESCs show falling short (M4_SETPOINT)
    nmpc: NmpcConfig = field(default_factory=lambda: NmpcConfig(control_period_s=1.0 / DEFAULT_RATE_HZ,
                                                                time_budget_share=COMPANION_TIME_BUDGET_SHARE))
    disturbance_gain: float = DEFAULT_DISTURBANCE_GAIN
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    touchdown: TouchdownConfig = field(default_factory=TouchdownConfig)
    fault_detector: FaultDetectorConfig = field(default_factory=FaultDetectorConfig)
    upset: UpsetConfig = field(default_factory=UpsetConfig)
    link: LinkConfig = field(default_factory=LinkConfig)
    feed: FeedSettings = field(default_factory=lambda: FeedSettings(enabled=False))   # the Zenoh feed
    log: LogSettings = field(default_factory=LogSettings)
    airframe_path: Path | None = None       # None: the bundled reference airframe
    mission_path: Path | None = None        # None: no mission (hold where the flight starts)
    airframe: Airframe = field(default_factory=load_airframe)
    mission: Mission = field(default_factory=Mission)

    @property
    def control_period_s(self) -> float:
        return 1.0 / self.rate_hz


def load_config(path: str | Path | None = None) -> CompanionConfig:
    """Read and validate the companion's configuration; None gives the defaults."""
    if path is None:
        return parse_config({}, "defaults")
    path = Path(path)
    return parse_config(load_toml(path), path.name, path.parent)


def parse_config(data: dict, where: str, base_dir: Path | None = None) -> CompanionConfig:
    top = Table(data, where)
    airframe_path = top.path("airframe_file", base_dir, must_exist=True)
    mission_path = top.path("mission_file", base_dir, must_exist=True)
    control = top.table("control")
    rate_hz = control.number("rate_hz", DEFAULT_RATE_HZ, lo=0.0, lo_open=True, hi=RATE_MAX_HZ)
    realtime_priority = control.integer("realtime_priority", 0, lo=0, hi=PRIORITY_MAX)
    rate_feedback = control.number("rate_feedback_bandwidth_rad_s", DEFAULT_RATE_FEEDBACK_BANDWIDTH_RAD_S, lo=0.0,
                                   hi=RATE_FEEDBACK_BANDWIDTH_MAX_RAD_S)
    shortfall_cover = control.boolean("shortfall_cover", True)
    control.finish()
    nmpc_table = top.table("nmpc")
    disturbance_gain = nmpc_table.number("disturbance_gain", DEFAULT_DISTURBANCE_GAIN, lo=0.0, lo_open=True, hi=1.0)
    nmpc = nmpc_config(nmpc_table, 1.0 / rate_hz)
    config = CompanionConfig(
        rate_hz=rate_hz,
        realtime_priority=realtime_priority,
        rate_feedback_bandwidth_rad_s=rate_feedback,
        shortfall_cover=shortfall_cover,
        nmpc=nmpc,
        disturbance_gain=disturbance_gain,
        reference=_settings(top.table("reference"), ReferenceConfig),
        touchdown=_settings(top.table("touchdown"), TouchdownConfig),
        fault_detector=_settings(top.table("fault_detector"), FaultDetectorConfig),
        upset=_settings(top.table("upset"), UpsetConfig),
        link=_link(top.table("link"), base_dir),
        feed=parse_feed_settings(top.table("feed"), base_dir) if top.has("feed") else FeedSettings(enabled=False),
        log=_log(top.table("log"), base_dir),
        airframe_path=airframe_path,
        mission_path=mission_path,
        airframe=load_airframe(airframe_path),
        mission=Mission() if mission_path is None else load_mission(mission_path),
    )
    top.finish()
    return config


def nmpc_config(t: Table, control_period_s: float) -> NmpcConfig:
    """The [nmpc] table (and its [nmpc.weights]) as the NMPC's own settings."""
    weights = _settings(t.table("weights"), NmpcWeights)
    budget = t.number("time_budget_share", COMPANION_TIME_BUDGET_SHARE, lo=0.0, hi=1.0)
    config = _settings(t, NmpcConfig, weights=weights, control_period_s=control_period_s, time_budget_share=budget)
    if config.horizon > HORIZON_MAX:
        raise ConfigError(f"{t.where} horizon must be <= {HORIZON_MAX} (the NMPC must solve within a control "
                          f"period), got {config.horizon}")
    return config


def _settings(t: Table, cls: type, **given: Any):
    """A frozen settings dataclass from a table: one key per field not `given`, defaulting to
    the field's default; numbers >= 0; `*_rad` fields read from `*_deg` keys; fields whose
    default is None are optional numbers. The dataclass's own validate() has the last word."""
    default = cls()
    values = dict(given)
    for f in dataclasses.fields(cls):
        if f.name in given:
            continue
        d = getattr(default, f.name)
        in_degrees = f.name.endswith("_rad")
        key = f.name[:-4] + "_deg" if in_degrees else f.name
        if isinstance(d, bool):
            value = t.boolean(key, d)
        elif isinstance(d, int):
            value = t.integer(key, d, lo=0)
        elif isinstance(d, str):
            value = t.string(key, d)
        elif isinstance(d, tuple):
            value = t.vector(key, len(d), list(d), lo=0.0)
        elif isinstance(d, float) or d is None:
            if d is None and not t.has(key):
                continue
            value = t.number(key, math.degrees(d) if in_degrees and d is not None else d, lo=0.0)
            value = math.radians(value) if in_degrees else value
        else:
            raise TypeError(f"{cls.__name__}.{f.name}: no TOML form for {type(d).__name__}")
        values[f.name] = value
    t.finish()
    settings = dataclasses.replace(default, **values)
    try:
        settings.validate()
    except ValueError as e:
        raise ConfigError(f"{t.where}: {e}") from None
    return settings


def _log(t: Table, base_dir: Path | None) -> LogSettings:
    d = LogSettings()
    settings = LogSettings(enabled=t.boolean("enabled", d.enabled), dir=t.path("dir", base_dir) or d.dir,
                           max_file_mb=t.number("max_file_mb", d.max_file_mb, lo=0.0, lo_open=True),
                           max_total_mb=t.number("max_total_mb", d.max_total_mb, lo=0.0, lo_open=True))
    t.finish()
    return settings


def _link(t: Table, base_dir: Path | None) -> LinkConfig:
    d = LinkConfig()
    link = LinkConfig(
        fc_url=t.string("fc_url", d.fc_url),
        signing_key_path=t.path("signing_key_file", base_dir),
        telemetry_timeout_s=t.number("telemetry_timeout_s", d.telemetry_timeout_s, lo=0.0, lo_open=True, hi=10.0),
        delay_warning_s=t.number("delay_warning_s", d.delay_warning_s, lo=0.0, lo_open=True, hi=10.0),
        fc_system_id=t.integer("fc_system_id", d.fc_system_id, lo=1, hi=255),
        fc_component_id=t.integer("fc_component_id", d.fc_component_id, lo=1, hi=255),
    )
    t.finish()
    # Imported here, not at the top: the pure-logic controller imports this module, and
    # pymavlink should load only where a link is read or opened.
    from m4.mavlink.connect import LinkError, check_url

    try:
        check_url(link.fc_url)
    except LinkError as e:
        raise ConfigError(f"{t.where} fc_url: {e}") from None
    return link
