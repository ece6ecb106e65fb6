"""The companion's parameters (component 191), as a ground station sees them.

Each is a key of the configuration (companion/config.py), with the range the configuration
gives it (`setting_bounds`). Settable: what is read afresh at every control step and safe to
change in flight: the fault detector's thresholds (DET_) and when a slow link is reported
(LINK_DELAY_WARN). Read-only, with the reason: what the companion builds once at start (the
NMPC's horizon, step, weights and iterations, compiled; the control rate; the detector's noise
model; the upset check, the landing reference, the link's timeout). Angles are in degrees, as
in the file. `CompanionParams.config` is the configuration with the values set; a change is
handed to `on_change` (the app retunes its detector). The table: docs/parameters.md.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

from companion.config import (RATE_FEEDBACK_BANDWIDTH_MAX_RAD_S, RATE_MAX_HZ, RATE_MIN_HZ, CompanionConfig,
                              setting_bounds)
from companion.core.fault_detector import FaultDetectorConfig
from companion.core.nmpc_config import NmpcConfig, NmpcWeights
from companion.core.upset import UpsetConfig
from m4.params_file import ParamFile
from m4.params import Param, ParamTable
from m4.params import ParamType as T

BUILT = "built at start: change it in the configuration and restart"
COMPILED = "the NMPC is compiled for it at start: change it in the configuration and restart"


class _Spec(NamedTuple):
    name: str
    path: tuple                   # attribute names (and a tuple's index) from CompanionConfig
    type: T
    lo: float
    hi: float
    unit: str
    text: str
    read_only_why: str = ""       # "": settable in flight
    lo_open: bool = False
    degrees: bool = False         # a *_rad field, shown in degrees


def _get(obj: Any, path: tuple) -> Any:
    for step in path:
        obj = obj[step] if isinstance(step, int) else getattr(obj, step)
    return obj


def _replace(obj: Any, path: tuple, value: Any) -> Any:
    """`obj` (frozen dataclasses and tuples) with the item at `path` replaced by `value`."""
    step, rest = path[0], path[1:]
    new = value if not rest else _replace(_get(obj, (step,)), rest, value)
    if isinstance(step, int):
        return obj[:step] + (new,) + obj[step + 1:]
    return dataclasses.replace(obj, **{step: new})


def _specs(config: CompanionConfig) -> list[_Spec]:
    bounds = setting_bounds(config.airframe)
    det, nmpc, w = bounds[FaultDetectorConfig], bounds[NmpcConfig], bounds[NmpcWeights]

    def detector(name, key, unit, text, settable=True):
        b = det[key]
        return _Spec(name, ("fault_detector", key), T.REAL32, b.lo, b.hi, unit, text,
                     "" if settable else "the detector's noise model is " + BUILT, b.lo_open)

    def weight(name, path, text):
        b = w[path[0]]
        return _Spec(name, ("nmpc", "weights", *path), T.REAL32, b.lo, b.hi, "", text, COMPILED)

    return [
        _Spec("CTRL_RATE_HZ", ("rate_hz",), T.REAL32, RATE_MIN_HZ, RATE_MAX_HZ, "Hz", "control rate", COMPILED),
        _Spec("CTRL_RATE_FB_BW", ("rate_feedback_bandwidth_rad_s",), T.REAL32, 0.0, RATE_FEEDBACK_BANDWIDTH_MAX_RAD_S,
              "rad/s", "the FC's rate feedback bandwidth (0: none)", BUILT),
        _Spec("CTRL_SF_COVER", ("shortfall_cover",), T.INT8, 0, 1, "", "ask the FC to cover a rotor falling short",
              BUILT),
        _Spec("NMPC_HORIZON", ("nmpc", "horizon"), T.INT32, nmpc["horizon"].lo, nmpc["horizon"].hi, "",
              "stages", COMPILED),
        _Spec("NMPC_DT", ("nmpc", "dt_s"), T.REAL32, nmpc["dt_s"].lo, nmpc["dt_s"].hi, "s", "stage length",
              COMPILED),
        _Spec("NMPC_MAX_ITER", ("nmpc", "max_iterations"), T.INT32, nmpc["max_iterations"].lo,
              nmpc["max_iterations"].hi, "", "SQP iterations per solve, at most", COMPILED),
        _Spec("NMPC_ATT_MAX", ("nmpc", "roll_pitch_max_rad"), T.REAL32, nmpc["roll_pitch_max_deg"].lo,
              nmpc["roll_pitch_max_deg"].hi, "deg", "roll and pitch bound", COMPILED, degrees=True),
        weight("NMPC_W_POS_N", ("position", 0), "position weight, north"),
        weight("NMPC_W_POS_E", ("position", 1), "position weight, east"),
        weight("NMPC_W_POS_D", ("position", 2), "position weight, down"),
        weight("NMPC_W_VEL_N", ("velocity", 0), "velocity weight, north"),
        weight("NMPC_W_VEL_E", ("velocity", 1), "velocity weight, east"),
        weight("NMPC_W_VEL_D", ("velocity", 2), "velocity weight, down"),
        weight("NMPC_W_ATT", ("roll_pitch",), "roll and pitch weight"),
        weight("NMPC_W_RATE", ("roll_pitch_rate",), "roll and pitch rate weight"),
        weight("NMPC_W_HIP", ("hip",), "hip angle weight"),
        weight("NMPC_W_HIP_RATE", ("hip_rate",), "hip rate weight"),
        weight("NMPC_W_THRUST", ("thrust",), "thrust weight"),
        weight("NMPC_W_HIP_ACC", ("hip_accel",), "hip acceleration weight"),
        weight("NMPC_W_TERMINAL", ("terminal_scale",), "terminal weight, times the stage's"),
        weight("NMPC_W_SAT_HORIZ", ("horizontal_saturated_scale",),
               "north and east weights, times this while the rotors saturate"),
        detector("DET_CHI2_MIN", "chi2_min", "", "smallest residual chi2 a rotor must explain"),
        detector("DET_DEFICIT_MIN", "deficit_min_n", "N", "smallest thrust deficit that votes"),
        detector("DET_UNEXPLAINED", "unexplained_max", "", "chi2 the best rotor may leave, as a share"),
        detector("DET_CONFIRM", "confirm_s", "s", "residual votes for one rotor this long confirm it"),
        detector("DET_SAT_CONFIRM", "saturated_confirm_s", "s", "votes of a rotor at its bound this long confirm"),
        detector("DET_ESC_CONFIRM", "direct_confirm_s", "s", "ESC votes this long confirm"),
        detector("DET_ESC_SHORT", "shortfall_min", "", "share of its command a rotor may fall short by (ESC)"),
        detector("DET_SAT_MARGIN", "saturation_margin_n", "N", "within this of its bound a rotor is at it"),
        detector("DET_ESC_MAX_AGE", "esc_max_age_s", "s", "older ESC frames are no evidence"),
        detector("DET_RECOVER", "recover_s", "s", "a confirmed rotor giving all it is asked this long is healthy"),
        detector("DET_VEL_NOISE", "velocity_noise_m_s", "m/s", "velocity noise", settable=False),
        detector("DET_RATE_NOISE", "rates_noise_rad_s", "rad/s", "body rate noise", settable=False),
        detector("DET_FORCE_ERR", "force_model_error_n", "N", "force the model gets wrong", settable=False),
        _Spec("LINK_DELAY_WARN", ("link", "delay_warning_s"), T.REAL32, 0.004, 1.0, "s",
              "report setpoints acting later than this"),
        _Spec("LINK_TELEM_TMO", ("link", "telemetry_timeout_s"), T.REAL32, 0.0, 10.0, "s",
              "telemetry silent this long is a lost link", BUILT, lo_open=True),
        _Spec("UPSET_TILT_MAX", ("upset", "tilt_max_rad"), T.REAL32, bounds[UpsetConfig]["tilt_max_deg"].lo,
              bounds[UpsetConfig]["tilt_max_deg"].hi, "deg", "a tilt beyond this is upside down", BUILT, degrees=True),
    ]


class CompanionParams:
    def __init__(self, config: CompanionConfig, on_change: Callable[[CompanionConfig], None] = lambda config: None):
        """on_change: told the new configuration after each set."""
        self.config = config
        self._on_change = on_change
        self.table = ParamTable(self._param(s) for s in _specs(config))

    def _param(self, s: _Spec) -> Param:
        def get() -> float:
            value = _get(self.config, s.path)
            return math.degrees(value) if s.degrees else float(value)

        def set_(value: float) -> None:
            self.config = _replace(self.config, s.path, math.radians(value) if s.degrees else value)
            self._on_change(self.config)
        return Param(s.name, s.type, s.lo, s.hi, s.unit, s.text, get, None if s.read_only_why else set_,
                     s.read_only_why, s.lo_open)


def with_params_file(config: CompanionConfig) -> CompanionConfig:
    """The configuration with its parameter file's values (config.params_path; none: as it is);
    ConfigError naming the file and the entry when one is bad."""
    if config.params_path is None:
        return config
    params = CompanionParams(config)
    ParamFile(config.params_path).load(params.table)
    return params.config
