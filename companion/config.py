"""The companion's configuration: ONE TOML file with every tunable, validated at start.

`load_config(path)` reads the file (None: every default, which flies the reference airframe
on the SITL's default link) and returns a frozen CompanionConfig; anything malformed raises
ConfigError naming the table and key. deploy/companion.toml documents every key. The
parameters a ground station sets (companion/params.py) are kept in `params_file` (default:
beside the file, companion.toml's in companion.params.toml) and applied over it at start.

The tables map onto the settings dataclasses of the parts they configure (NmpcConfig,
ReferenceConfig, TouchdownConfig, FaultDetectorConfig, FeedSettings): a key is a field's
name, its default is the field's default, and a field in radians (`*_rad`) is written in
degrees (`*_deg`) in the file. Relative paths are taken from the file's folder. The Zenoh
feed is the [feed] table of m4.feed.settings (absent: no feed); the flight log is [log].

Every number has a range that means something for the robot (`setting_bounds`: the control
rate, the NMPC's stages and span, the detectors' windows, the weights, the timeouts...), some
of it from the airframe; a value outside is refused at start, naming its key.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

from m4.airframe import ROTOR_COUNT, Airframe, load_airframe
from companion.core.disturbance import DisturbanceEstimator
from companion.core.fault_detector import FaultDetectorConfig
from companion.core.nmpc_config import SCHEMES, NmpcConfig, NmpcWeights
from companion.core.reference import ReferenceConfig
from companion.core.touchdown import TouchdownConfig
from companion.core.upset import UpsetConfig
from companion.realtime import PRIORITY_MAX
from m4.feed.settings import FeedSettings, parse_feed_settings
from m4.mission import ON_FAULT_CHOICES, Mission
from m4.scenario import load_mission
from m4.toml_fields import ConfigError, Table, load_toml

RATE_MIN_HZ = 5.0
RATE_MAX_HZ = 100.0
RATE_WHY = ("below 5 Hz a rotor loss drops the robot 0.2 m before the next plan; above 100 Hz a step's p99 "
            "of 7 ms barely fits the period")
# The NMPC's solve time grows with its horizon (N = 20: 8 ms median, 18 ms p99,
# docs/performance.md); beyond this it cannot answer within a control period, and the code it compiles grows
# with it (N = 100000 would compile for hours).
HORIZON_MAX = 40
# 50 Hz: at the paper's 10 Hz every built-in scenario survives too, but a new fault waits up to
# 0.1 s for the next plan, the sag and tilt grow (24 N cap: 0.22 m against 0.13 m) and the
# landing comes down at 0.25 m/s against 0.06 m/s (docs/results.md, "Control rate").
DEFAULT_RATE_HZ = 50.0
# The real-time iteration's slowest rate: it flies every built-in scenario at 25 Hz as at 50 Hz, and at 10 Hz it
# loses 5 of the 12 that the converged SQP flies (one Gauss-Newton step is flown for a whole 0.1 s stage after a
# rotor loss; docs/performance.md). Below it the [nmpc] scheme defaults to "sqp" and "rti" is refused.
RTI_RATE_MIN_HZ = 25.0
# The rate feedback the FC closes around the plan (m4.setpoint, companion.core.rate_feedback):
# its bandwidth. Above ~1/(4 x the FC's 4 ms loop) it would ring on the FC's own loop delay.
DEFAULT_RATE_FEEDBACK_BANDWIDTH_RAD_S = 20.0
RATE_FEEDBACK_BANDWIDTH_MAX_RAD_S = 60.0
# The companion's solves stop iterating at half the control period (the research tools' NMPC,
# NmpcConfig's default, iterates until it converges).
COMPANION_TIME_BUDGET_SHARE = 0.5
DEFAULT_DISTURBANCE_GAIN = inspect.signature(DisturbanceEstimator).parameters["gain"].default
# The plan must reach the next solve (horizon x dt_s >= the control period); beyond 4 s the ROM's
# prediction (no drag, no wind, thrust known to 10 %) says nothing and the terminal weight pulls
# towards a state the robot will never be in.
PLAN_SPAN_MAX_S = 4.0
TELEMETRY_TIMEOUT_PERIODS = 3        # no telemetry for this many control periods is a loss, at the least


class Bounds(NamedTuple):
    """A number's range in the file (in the key's unit): lo..hi, lo itself excluded when
    lo_open; `why` is said with a value outside it."""
    lo: float
    hi: float
    lo_open: bool = False
    why: str = ""


def setting_bounds(af: Airframe) -> dict[type, dict[str, Bounds]]:
    """The range of every number of the tables read into settings dataclasses, by key."""
    share = Bounds(0.0, 1.0, why="a share")
    gain = Bounds(0.0, 1.0, why="a filter's gain")
    rotor_n = Bounds(0.0, af.thrust_max_n, why="one rotor's thrust_max_n")
    decision_s = Bounds(0.0, 1.0, why="a robot falls 2 m in 0.64 s: a detector waiting longer decides on the ground")
    # The QP's Hessian is built from the weights: within 1e-6..1e4 its condition number stays
    # under 1e10, where double precision keeps six digits.
    weight = Bounds(0.0, 1e4, why="the QP's conditioning")
    weight_positive = Bounds(1e-6, 1e4, why="> 0 keeps the QP strictly convex; 1e4: its conditioning")
    return {
        NmpcConfig: {
            "horizon": Bounds(1, HORIZON_MAX, why="the NMPC must solve within a control period"),
            "dt_s": Bounds(0.01, 0.25, why="finer than 2.5 ticks of the FC's 4 ms loop plans what it never flies; "
                                           "past 0.25 s a recovery's 5 rad/s turns the body a radian a step"),
            "rk4_substeps": Bounds(1, 10, why="10 steps of the longest stage are 25 ms, the motors' lag"),
            "roll_pitch_max_deg": Bounds(10.0, 90.0, why="below 10 deg the robot cannot lean against a lost rotor"),
            "fixed_hip_deg": Bounds(math.degrees(af.hip_min_rad), math.degrees(af.hip_max_rad),
                                    why="the airframe's hip range"),
            "max_iterations": Bounds(1, 50, why="about 1 ms each: 50 outlast the slowest control period"),
            "cost_tol_rel": Bounds(0.0, 0.1, why="a step still lowering the cost 10 % has not converged"),
        },
        NmpcWeights: {
            "position": weight, "roll_pitch": weight, "hip": weight, "velocity": weight,
            "roll_pitch_rate": weight, "hip_rate": weight, "thrust": weight_positive,
            "hip_accel": weight_positive,
            "terminal_scale": Bounds(0.0, 100.0, why="more makes the plan a one-point problem"),
            "horizontal_saturated_scale": Bounds(0.0, 1.0, why="a share of the weights"),
        },
        ReferenceConfig: {
            "accel_max_m_s2": Bounds(0.1, 5.0, why="5 m/s^2 leans the robot 27 deg, what three rotors still allow"),
        },
        TouchdownConfig: {
            "height_tolerance_m": Bounds(0.0, 0.3, lo_open=True, why="30 cm up is a hover: a cut there drops it"),
            "vertical_speed_max_m_s": Bounds(0.0, 0.5, lo_open=True, why="faster is a descent, not a rest"),
            "dwell_s": Bounds(0.0, 2.0, lo_open=True, why="a rest is seen within 2 s"),
        },
        UpsetConfig: {
            "tilt_max_deg": Bounds(60.0, 179.0, why="recoveries tilt up to 47 deg: a lower cut stops a robot "
                                                    "that flies"),
            "upside_down_s": Bounds(0.0, 2.0, lo_open=True, why="2 s upside down is long after the crash"),
            "ground_margin_m": Bounds(0.0, 1.0, lo_open=True, why="a metre up is not on the ground"),
            "airborne_margin_m": Bounds(0.0, 5.0, lo_open=True, why="5 m up is airborne"),
            "still_speed_m_s": Bounds(0.0, 5.0, lo_open=True, why="5 m/s is not still"),
            "ground_s": Bounds(0.0, 2.0, lo_open=True, why="2 s on the ground is long after the crash"),
        },
        FaultDetectorConfig: {
            "velocity_noise_m_s": Bounds(0.0, 1.0, lo_open=True, why="noisier is no velocity sensor"),
            "rates_noise_rad_s": Bounds(0.0, 1.0, lo_open=True, why="57 deg/s of noise is no gyro"),
            "force_model_error_n": Bounds(0.0, ROTOR_COUNT * af.thrust_max_n, why="all the rotors give"),
            "torque_model_error_n_m": Bounds(0.0, ROTOR_COUNT * af.thrust_max_n * af.leg_length_m,
                                             why="all the rotors give, at a leg's length"),
            "torque_model_share": share,
            "deficit_min_n": Bounds(0.0, af.thrust_max_n, lo_open=True, why="one rotor's thrust_max_n"),
            "chi2_min": Bounds(1.0, 1000.0, why="1: every noise sample is a fault; 1000: none ever is"),
            "unexplained_max": share,
            "window_s": Bounds(0.0, decision_s.hi, lo_open=True, why=decision_s.why),
            "confirm_s": decision_s, "saturated_confirm_s": decision_s, "direct_confirm_s": decision_s,
            "shortfall_min": share,
            "saturation_margin_n": rotor_n,
            "gross_share": share, "sag_floor_share": share,
            "ceiling_deficit_min_n": rotor_n,
            "estimate_gain": gain,
            "probe_n": Bounds(0.0, af.thrust_max_n, lo_open=True, why="one rotor's thrust_max_n"),
            "rise_gain": gain,
            "recover_s": Bounds(0.0, 10.0, why="a rotor back for 10 s is back"),
            "esc_max_age_s": Bounds(0.0, 1.0, why="ESC frames a second old say nothing about now"),
            "bias_time_constant_s": Bounds(0.0, 60.0, lo_open=True, why="learnt within a minute of flight"),
            "max_gap_s": Bounds(0.0, 2.0, lo_open=True, why="evidence 2 s old says nothing about now"),
        },
    }


SIGNING_STATE_SUFFIX = ".companion-timestamps"     # beside the key unless [link] signing_state_file says where
PARAMS_SUFFIX = ".params.toml"           # companion.toml's parameters: companion.params.toml, unless params_file says


@dataclass(frozen=True)
class LinkConfig:
    fc_url: str = "udpin:127.0.0.1:14550"   # pymavlink form; serial: "/dev/ttyTHS1,921600"
    signing: bool = True                    # MAVLink 2 signing (docs/authority.md); False: unsigned, warned of
    signing_key_path: Path | None = None    # 32-byte key (hex or raw; m4-companion keygen), needed while signing
    signing_state_path: Path | None = None  # signing timestamps kept across restarts; None: beside the key
    telemetry_timeout_s: float = 0.3        # no telemetry for this long: the link is lost
    delay_warning_s: float = 0.1            # setpoints acting this long after their instant: warn
    fc_system_id: int = 1                   # only this flight controller is listened to
    fc_component_id: int = 1

    def signing_files(self) -> tuple[Path, Path] | None:
        """(key file, timestamps file) while signing is on; None when it is explicitly off.
        ConfigError when it is on without a key: the companion does not fly unsigned by omission."""
        if not self.signing:
            return None
        if self.signing_key_path is None:
            raise ConfigError("[link] signing is on (the default) but no signing_key_file is set: make a key with "
                              "`m4-companion keygen FILE` and give it to both ends (docs/authority.md), or set "
                              "signing = false to fly unsigned")
        key = self.signing_key_path
        return key, self.signing_state_path or key.with_name(key.name + SIGNING_STATE_SUFFIX)


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
    cpu: int | None = None                  # the CPU all the companion runs on; None: any (companion/realtime.py)
    rate_feedback_bandwidth_rad_s: float = DEFAULT_RATE_FEEDBACK_BANDWIDTH_RAD_S   # 0: the FC flies thrust_n alone
    shortfall_cover: bool = True            # the FC covers a rotor its ESCs or gyro show falling short (M4_SETPOINT)
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
    mission_path: Path | None = None        # None: the FC's mission if it has one (companion.fc_mission), else hold
    params_path: Path | None = None         # parameters set over MAVLink (companion/params.py); None: for the run
    fc_mission_on_fault: str = "hold"       # the fault policy of a mission from the FC (m4.mission ON_FAULT_CHOICES)
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
    config = parse_config(load_toml(path), path.name, path.parent)
    if config.params_path is None:
        config = dataclasses.replace(config, params_path=path.with_name(path.stem + PARAMS_SUFFIX))
    return config


def parse_config(data: dict, where: str, base_dir: Path | None = None) -> CompanionConfig:
    top = Table(data, where)
    airframe_path = top.path("airframe_file", base_dir, must_exist=True)
    mission_path = top.path("mission_file", base_dir, must_exist=True)
    params_path = top.path("params_file", base_dir)
    fc_mission_on_fault = top.string("fc_mission_on_fault", "hold", choices=ON_FAULT_CHOICES)
    airframe = load_airframe(airframe_path)
    bounds = setting_bounds(airframe)
    control = top.table("control")
    rate_hz = control.number("rate_hz", DEFAULT_RATE_HZ, lo=RATE_MIN_HZ, hi=RATE_MAX_HZ, why=RATE_WHY)
    realtime_priority = control.integer("realtime_priority", 0, lo=0, hi=PRIORITY_MAX)
    cpu = control.integer("cpu", lo=0) if control.has("cpu") else None
    rate_feedback = control.number("rate_feedback_bandwidth_rad_s", DEFAULT_RATE_FEEDBACK_BANDWIDTH_RAD_S, lo=0.0,
                                   hi=RATE_FEEDBACK_BANDWIDTH_MAX_RAD_S)
    shortfall_cover = control.boolean("shortfall_cover", True)
    control.finish()
    nmpc_table = top.table("nmpc")
    disturbance_gain = nmpc_table.number("disturbance_gain", DEFAULT_DISTURBANCE_GAIN, lo=0.0, lo_open=True, hi=1.0)
    nmpc = nmpc_config(nmpc_table, 1.0 / rate_hz, bounds)
    config = CompanionConfig(
        rate_hz=rate_hz,
        realtime_priority=realtime_priority,
        cpu=cpu,
        rate_feedback_bandwidth_rad_s=rate_feedback,
        shortfall_cover=shortfall_cover,
        nmpc=nmpc,
        disturbance_gain=disturbance_gain,
        reference=_settings(top.table("reference"), ReferenceConfig, bounds),
        touchdown=_settings(top.table("touchdown"), TouchdownConfig, bounds),
        fault_detector=_settings(top.table("fault_detector"), FaultDetectorConfig, bounds),
        upset=_settings(top.table("upset"), UpsetConfig, bounds),
        link=_link(top.table("link"), base_dir, rate_hz),
        feed=parse_feed_settings(top.table("feed"), base_dir) if top.has("feed") else FeedSettings(enabled=False),
        log=_log(top.table("log"), base_dir),
        airframe_path=airframe_path,
        mission_path=mission_path,
        params_path=params_path,
        fc_mission_on_fault=fc_mission_on_fault,
        airframe=airframe,
        mission=Mission() if mission_path is None else load_mission(mission_path),
    )
    top.finish()
    return config


def nmpc_config(t: Table, control_period_s: float, bounds: dict[type, dict[str, Bounds]]) -> NmpcConfig:
    """The [nmpc] table (and its [nmpc.weights]) as the NMPC's own settings."""
    weights = _settings(t.table("weights"), NmpcWeights, bounds)
    budget = t.number("time_budget_share", COMPANION_TIME_BUDGET_SHARE, lo=0.0, hi=1.0)
    rti_holds = 1.0 / control_period_s >= RTI_RATE_MIN_HZ - 1e-9
    scheme = t.string("scheme", "rti" if rti_holds else "sqp", choices=SCHEMES)
    if scheme == "rti" and not rti_holds:
        raise ConfigError(f'{t.where} scheme = "rti" needs a control rate of at least {RTI_RATE_MIN_HZ:g} Hz '
                          f"(at 10 Hz it lost 5 of the 12 built-in flights the SQP flies), got "
                          f'{1.0 / control_period_s:g} Hz: use scheme = "sqp", or leave it out')
    config = _settings(t, NmpcConfig, bounds, weights=weights, control_period_s=control_period_s,
                       time_budget_share=budget, scheme=scheme)
    span_s = config.horizon * config.dt_s
    if not control_period_s <= span_s <= PLAN_SPAN_MAX_S:
        raise ConfigError(f"{t.where} horizon x dt_s (the plan's span) must lie within the control period "
                          f"({control_period_s:g} s) and {PLAN_SPAN_MAX_S:g} s (it must reach the next solve; the "
                          f"model predicts nothing useful further), got {config.horizon} x {config.dt_s:g} = "
                          f"{span_s:g} s")
    return config


def _settings(t: Table, cls: type, bounds: dict[type, dict[str, Bounds]], **given: Any):
    """A frozen settings dataclass from a table: one key per field not `given`, defaulting to
    the field's default; numbers within their `bounds[cls][key]`; `*_rad` fields read from
    `*_deg` keys; fields whose default is None are optional numbers. The dataclass's own
    validate() has the last word."""
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
        elif isinstance(d, str):
            value = t.string(key, d)
        elif (b := bounds[cls].get(key)) is None:
            raise TypeError(f"{cls.__name__}.{f.name}: no range in setting_bounds")
        elif isinstance(d, int):
            value = t.integer(key, d, lo=int(b.lo), hi=int(b.hi), why=b.why)
        elif isinstance(d, tuple):
            value = t.vector(key, len(d), list(d), lo=b.lo, hi=b.hi, why=b.why)
        elif isinstance(d, float) or d is None:
            if d is None and not t.has(key):
                continue
            value = t.number(key, math.degrees(d) if in_degrees and d is not None else d, lo=b.lo, hi=b.hi,
                             lo_open=b.lo_open, why=b.why)
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
    max_file_mb = t.number("max_file_mb", d.max_file_mb, lo=1.0, hi=1e6,
                           why="a flight logs about 50 kB/s: under 1 MB is a new file every 20 s")
    settings = LogSettings(enabled=t.boolean("enabled", d.enabled), dir=t.path("dir", base_dir) or d.dir,
                           max_file_mb=max_file_mb,
                           max_total_mb=t.number("max_total_mb", d.max_total_mb, lo=max_file_mb, hi=1e6,
                                                 why="the cap holds at least the file being written"))
    t.finish()
    return settings


def _link(t: Table, base_dir: Path | None, rate_hz: float) -> LinkConfig:
    d = LinkConfig()
    link = LinkConfig(
        fc_url=t.string("fc_url", d.fc_url),
        signing=t.boolean("signing", d.signing),
        signing_key_path=t.path("signing_key_file", base_dir),
        signing_state_path=t.path("signing_state_file", base_dir),
        telemetry_timeout_s=t.number("telemetry_timeout_s", d.telemetry_timeout_s, lo=0.0, lo_open=True, hi=10.0,
                                     why="the FC's own failsafe lands 2 s after the setpoints stop"),
        delay_warning_s=t.number("delay_warning_s", d.delay_warning_s, lo=0.004, hi=1.0,
                                 why="from a tick of the FC's 4 ms loop to a second, when its failsafe has long "
                                     "flown instead"),
        fc_system_id=t.integer("fc_system_id", d.fc_system_id, lo=1, hi=255),
        fc_component_id=t.integer("fc_component_id", d.fc_component_id, lo=1, hi=255),
    )
    t.finish()
    periods_s = TELEMETRY_TIMEOUT_PERIODS / rate_hz
    if link.telemetry_timeout_s < periods_s:
        raise ConfigError(f"{t.where} telemetry_timeout_s must be at least {TELEMETRY_TIMEOUT_PERIODS} control "
                          f"periods ({periods_s:g} s at {rate_hz:g} Hz; fewer would call one late frame a loss), "
                          f"got {link.telemetry_timeout_s:g}")
    if not link.signing and (link.signing_key_path or link.signing_state_path):
        raise ConfigError(f"{t.where}: signing = false but a signing key or state file is set: remove one or the "
                          "other")
    # Imported here, not at the top: the pure-logic controller imports this module, and
    # pymavlink should load only where a link is read or opened.
    from m4.mavlink.connect import LinkError, check_url

    try:
        check_url(link.fc_url)
    except LinkError as e:
        raise ConfigError(f"{t.where} fc_url: {e}") from None
    return link
