"""Rotor fault detection, isolation, kind and sizing, handed to the NMPC as a thrust bound.

It reads only what a flight controller reports: the measured state, the command we sent, the
FC's configured thrust limits and, where the FC has them, its ESCs' RPM, current and voltage
(companion.core.esc_evidence). Three kinds of evidence, fused each telemetry frame:

- ESC evidence: a rotor whose speed-implied thrust (0 when it turns unloaded) falls short of
  its command passed through the motor lag, while every other rotor gives what it is asked
  (a rotor held at the battery's common ceiling is not short). Votes in a row covering
  direct_confirm_s confirm. It tells the kind: speed collapsed = motor, overspeed without
  load = propeller, slow but loaded = degraded.
- Thrust saturation (the paper's criterion): a rotor commanded at its bound while the
  vehicle departs from the plan, i.e. the reduced-order model's one-step prediction
  (companion.core.fault_residual) misses by what that rotor's deficit alone explains.
  Votes in a row covering saturated_confirm_s confirm; so do votes for a rotor that gives
  less than gross_share of what it is asked (a rotor lost outright, before it saturates).
- The model residual alone (a deficit one rotor explains, significant, large): votes for
  rotor i during confirm_s confirm. With the ESCs reporting that rotor turning normally,
  the kind is a damaged propeller (less thrust at the same speed).

A deficit counts only below the common ceiling (the battery's, from the ESC voltage, else
sag_floor_share of the limit): a sagging battery lowers every rotor's ceiling together and
is no rotor's fault.

    healthy --vote i--> suspect(i) --confirm rule--> confirmed(i, kind)
    suspect(i) --no vote--> healthy;  suspect(i) --vote j--> suspect(j)
    confirmed(i) --estimate back within probe_n of the limit--> healthy (a new fault can follow)
    confirmed(i) --estimate near a hover share, delivers all it is asked for recover_s--> healthy

Confirmed: the rotor is modelled as min(effectiveness x command, ceiling estimate). At
confirmation the ceiling is what the rotor delivers (from the ESC: the level its lag heads
to; from the residual: the interval average), 0 for a lost motor or propeller; a damaged
propeller keeps its full range at a lower effectiveness, its ceiling its thrust coefficient's
share at the speed a full command reaches on its lighter load (companion.core.damaged_rotor;
without ESC speeds, effectiveness x limit), refined either way as it flies (_refine_damage).
Afterwards the NMPC's bound on that rotor is the estimate plus probe_n: a rotor commanded
there that delivers less lowers the estimate, one that delivers more raises it (it came
back, an intermittent fault), so the bound climbs back to the limit and the state returns
to healthy, ready for the next fault. One rotor at a time: while one is confirmed, evidence
about the others is not weighed.

Time and frames: time_s is the telemetry time; the state is the ROM state of the measured
robot (centre of mass, see companion.core.rom); thrust_cmd_n is the command in force during
the interval that ends at time_s (the last setpoint sent before this frame).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.fault_kind import FaultKind
from companion.core import rom
from companion.core.control_types import FaultState, FaultStatus
from companion.core.damaged_rotor import damaged_ceiling_n
from companion.core.esc_evidence import (EscReading, EscSample, PropellerModel, RotorCondition, current_speed_rpm,
                                         read_escs)
from companion.core.fault_residual import (
    CHANNELS,
    IntervalFit,
    ResidualNoise,
    ThrustResidualModel,
    best_hypothesis,
    combine,
)

# A residual of pure noise has a chi2 of about one per channel and interval; the best rotor may
# leave this many times that unexplained on top of its share.
_NOISE_CHI2_MARGIN = 3.0
_STOPPED_SHARE = 0.1      # an ESC whose speed heads for less than this share of the asked thrust: a stopped motor
_LOST_SHARE = 0.25        # a damaged propeller sized below this share of its command may be a lost one
_LAG_SPANS = 3.0          # the lag is undone in the sizing over spans up to this many motor time constants
_DAMAGE_AVERAGE_S = 0.3   # a damaged propeller's sizing after confirmation averages its evidence over this long
_EVERY_ROTOR = (True,) * ROTOR_COUNT    # an ESC measures what every rotor delivers
_KIND_OF_CONDITION = {RotorCondition.STOPPED: FaultKind.MOTOR, RotorCondition.UNLOADED: FaultKind.PROPELLER,
                      RotorCondition.SLOW: FaultKind.DEGRADED, RotorCondition.NORMAL: FaultKind.DEGRADED}


@dataclass(frozen=True)
class FaultDetectorConfig:
    velocity_noise_m_s: float = 0.05      # sensor noise of the measured velocity (per component)
    rates_noise_rad_s: float = 0.02       # sensor noise of the measured body rates
    force_model_error_n: float = 1.0      # force the ROM gets wrong, per axis
    torque_model_error_n_m: float = 0.05  # torque the ROM gets wrong, per axis
    torque_model_share: float = 0.1       # share of the commanded thrust torque the ROM gets wrong
    deficit_min_n: float = 2.0            # smallest deficit that votes (14 % of hover thrust)
    chi2_min: float = 25.0                # smallest residual chi2 explained (about 5 sigma)
    unexplained_max: float = 0.3          # chi2 the best rotor may leave, as a share of what it explains
    window_s: float = 0.1                 # evidence pooled over this much time before voting
    confirm_s: float = 0.1                # residual votes for one rotor during this long confirm it
    saturated_confirm_s: float = 0.04     # residual votes of a rotor at its bound, in a row, covering this confirm
    direct_confirm_s: float = 0.03        # ESC votes in a row covering this long confirm (~ motor lag)
    shortfall_min: float = 0.3            # share of its lagged command a rotor may fall short by (ESC path)
    saturation_margin_n: float = 0.5      # a rotor commanded within this of its bound is at its bound
    gross_share: float = 0.5              # a residual vote for a rotor short of this share of its command is fast too
    sag_floor_share: float = 0.6          # no ESC voltage: a battery may lower every ceiling to this share of the limit
    ceiling_deficit_min_n: float = 0.5    # a deficit this large of the faulty rotor lowers its estimate
    estimate_gain: float = 0.3            # weight of each such observation after confirmation
    probe_n: float = 2.0                  # the NMPC may ask the faulty rotor this much above its estimate
    rise_gain: float = 0.8                # weight of an observation above the estimate (the rotor came back)
    recover_s: float = 0.3                # a rotor near a hover share delivering all it is asked this long: healthy
    esc_max_age_s: float = 0.1            # ESC frames older than this (FC clock) are not evidence
    bias_time_constant_s: float = 2.0     # learning time of the residual the model always shows
    max_gap_s: float = 0.5                # frames further apart restart the evidence

    def validate(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"FaultDetectorConfig.{f.name} must be finite and >= 0, got {value}")
        for name in ("velocity_noise_m_s", "rates_noise_rad_s", "deficit_min_n", "window_s",
                     "bias_time_constant_s", "max_gap_s", "probe_n"):
            if getattr(self, name) <= 0:
                raise ValueError(f"FaultDetectorConfig.{name} must be > 0")
        for name in ("estimate_gain", "rise_gain", "sag_floor_share", "gross_share"):
            if getattr(self, name) > 1:
                raise ValueError(f"FaultDetectorConfig.{name} must be <= 1, got {getattr(self, name)}")


class _Path(IntEnum):
    ESC = 0
    SATURATED = 1
    RESIDUAL = 2


class _Frame(NamedTuple):
    time_s: float
    state: np.ndarray                  # (20,) the ROM state measured


class _Run(NamedTuple):
    """Votes in a row for one rotor on one path."""
    path: _Path
    index: int                         # the rotor's, 0..3
    covered_s: float                   # the time they cover


@dataclass(frozen=True)
class _Evidence:
    index: int | None                  # the rotor voted for, 0..3 (rotor - 1); None: no vote
    path: _Path
    kind: FaultKind
    # (4,) each: numpy arrays from the residual, Python lists from an ESC frame
    delivered_n: Sequence[float]       # what each rotor delivered (ESC: the level its lag heads to)
    expected_n: Sequence[float]        # what the model expected of each rotor over the interval
    short: Sequence[bool]              # clearly delivered less than expected (this rotor alone)
    significant: Sequence[bool]        # what it delivered is measured, not noise


class FaultDetector:
    def __init__(self, af: Airframe, config: FaultDetectorConfig = FaultDetectorConfig(),
                 propeller: PropellerModel | None = None, codegen: bool = False):
        """propeller: the ESC model (None: ESC frames are not read); codegen: the residual's
        model step compiled to C (cached), else CasADi's VM."""
        config.validate()
        self._af, self._c = af, config
        self._propeller = propeller                # None: no ESC model, ESC frames are not read
        self._model = ThrustResidualModel(af, ResidualNoise(
            velocity_m_s=config.velocity_noise_m_s, rates_rad_s=config.rates_noise_rad_s,
            force_n=config.force_model_error_n, torque_n_m=config.torque_model_error_n_m,
            torque_share=config.torque_model_share), codegen)
        self._limit_n = np.full(ROTOR_COUNT, af.thrust_max_n)
        self._prev: _Frame | None = None
        # The lags, rotor by rotor as Python floats (four rotors: no numpy call each).
        self._lag_n = [0.0] * ROTOR_COUNT          # thrust the model says the motors deliver
        self._cmd_lag_n = [0.0] * ROTOR_COUNT      # the command through the motor lag: what the ESCs are asked for
        self._asked_n = [0.0] * ROTOR_COUNT        # the command in force (clipped to the limits)
        # The FC may change a command anywhere between our frames (its rate feedback, its cover
        # of a failing rotor): the lagged command lies between these two, each frame's change
        # taken at its start or at its end; the low one through the lag of the rotor's speed,
        # the fastest a healthy rotor can give up its thrust (the cover drops a lost rotor's
        # diagonal partner to nothing within milliseconds).
        self._cmd_lag_low_n = [0.0] * ROTOR_COUNT
        self._cmd_lag_high_n = [0.0] * ROTOR_COUNT
        self._esc_time_s = -math.inf               # newest ESC frame used
        # The ESC frames' per-rotor figures as Python floats (four rotors: no numpy call each).
        self._esc_thrust_n = [0.0] * ROTOR_COUNT       # its speed-implied thrusts
        self._esc_rpm: list[float] | None = None
        self._esc_sample: EscSample | None = None      # the last frame read
        self._current_rpm: list[float] | None = None   # each rotor's speed when its current was measured
        self._esc_heading_n = [0.0] * ROTOR_COUNT      # the level those thrusts head to through the lag
        self._esc_voltage_v = math.nan                 # its voltage
        self._run: _Run | None = None
        self._window: deque[tuple[float, IntervalFit]] = deque()
        self._bias_per_s = np.zeros(len(CHANNELS))
        self._deficit_n = np.zeros(ROTOR_COUNT)
        self._status: FaultStatus | None = None        # built when asked for, until the next change
        self._clear()
        self._detected_at_s: float | None = None

    def _clear(self) -> None:
        self._state, self._index, self._kind = FaultState.HEALTHY, None, FaultKind.UNKNOWN
        self._healthy_s = 0.0                      # confirmed rotor delivering all it is asked for this long
        self._window.clear()
        self._suspect_since_s = 0.0
        self._estimate_n = math.inf                # ceiling of the confirmed rotor
        self._effectiveness = 1.0                  # thrust per command of the confirmed rotor
        self._overspeed: float | None = None       # a damaged propeller's ESC thrust k_t w^2 over its command

    def retune(self, config: FaultDetectorConfig) -> None:
        """Decide by `config`'s thresholds from the next frame on (a parameter set in flight); the
        residual's noise model stays the one built (its fields are read-only parameters)."""
        config.validate()
        self._c, self._status = config, None

    def hold(self) -> None:
        """The robot touches the ground: forces the model does not have (the ground's support,
        its friction against the air's push) move it, so this frame is no evidence. A suspicion
        is dropped and the evidence restarts at the next frame in free flight; a confirmed fault
        stays as it is."""
        self._prev, self._run, self._status = None, None, None
        if self._state is FaultState.SUSPECT:
            self._clear()
        self._window.clear()

    def restore(self, rotor: int, thrust_max_estimate_n: float, detected_at_s: float) -> None:
        """Start from a fault confirmed before this detector existed (a restarted companion:
        the FC kept its M4_FAULT_STATUS): rotor 1..4, its ceiling, when it was confirmed."""
        self._clear()
        self._status = None
        self._state, self._index, self._detected_at_s = FaultState.CONFIRMED, rotor - 1, detected_at_s
        self._estimate_n = float(thrust_max_estimate_n)

    def _thrust_bound_n(self) -> np.ndarray:
        """The NMPC's bounds: the limits, the estimate plus the probe on a confirmed rotor."""
        bound = self._limit_n.copy()
        if self._state is FaultState.CONFIRMED:
            bound[self._index] = min(self._estimate_n + self._c.probe_n, self._limit_n[self._index])
        return bound

    @property
    def status(self) -> FaultStatus:
        """The detector's status, built once after each change (update, hold, restore, retune):
        asked again, the same object, its arrays read-only."""
        if self._status is None:
            self._status = self._build_status()
        return self._status

    def _build_status(self) -> FaultStatus:
        estimate, bound = self._limit_n.copy(), self._thrust_bound_n()
        confirmed = self._state is FaultState.CONFIRMED
        if confirmed:
            estimate[self._index] = self._estimate_n
        rotor = None if self._index is None else self._index + 1
        message = ""
        if confirmed:
            known = "" if self._kind is FaultKind.UNKNOWN else f" ({self._kind.name.lower()})"
            message = f"thrust loss rotor {rotor}{known}"
        deficit = self._deficit_n                  # replaced at each frame, never written into
        for array in (estimate, bound, deficit):
            array.flags.writeable = False
        return FaultStatus(state=self._state, rotor=rotor, kind=self._kind, thrust_max_estimate_n=estimate,
                           thrust_bound_n=bound, detected_at_s=self._detected_at_s if confirmed else None,
                           message=message, deficit_n=deficit)

    def cannot_confirm(self, time_s: float, thrust_limit_n) -> bool:
        """True when update() at time_s with these limits (4,) can neither confirm a fault nor
        take new limits: the limits the ones in force, and either a rotor confirmed lost already
        (motor or propeller: its ceiling at the least a rotor gives or on its way back up; one
        rotor at a time: a frame refines that ceiling or clears the fault, never confirms another)
        or healthy, no votes in a row carried over, and the frame too soon after the last for a
        single vote to confirm. Such a frame may be read after the setpoint that answers it has
        left (a refinement then bounds the next setpoint). With ESC telemetry a damaged or weak
        rotor's frame may find it lost after all, and a damaged propeller's ceiling falls at once
        on a clear deficit: such a frame is read before the solve (without ESCs a weak rotor's
        ceiling only moves by estimate_gain a frame)."""
        most_n = self._af.thrust_max_n
        limit = np.asarray(thrust_limit_n, dtype=float).reshape(ROTOR_COUNT).tolist()
        if [v if math.isfinite(v) else most_n for v in limit] != self._limit_n.tolist():
            return False
        if self._state is FaultState.CONFIRMED:
            lost = self._kind in (FaultKind.MOTOR, FaultKind.PROPELLER)
            return lost or self._kind is not FaultKind.DAMAGE and self._esc_sample is None
        if self._state is not FaultState.HEALTHY or self._run is not None:
            return False
        c = self._c
        return self._prev is None or time_s - self._prev.time_s < min(c.direct_confirm_s, c.saturated_confirm_s,
                                                                      c.confirm_s) - 1e-9

    def update(self, time_s: float, state_measured, thrust_cmd_n, thrust_limit_n=None,
               esc: EscSample | None = None) -> FaultStatus:
        """One telemetry frame. thrust_limit_n (4,): each rotor's limit as known without this
        detector (default and NaN entries: the airframe's thrust_max_n); esc: the newest ESC
        telemetry (None: the FC has none). A frame with a non-finite state or command is
        skipped and restarts the evidence."""
        self._status = None
        x = np.asarray(state_measured, dtype=float).reshape(rom.NX)
        cmd = np.asarray(thrust_cmd_n, dtype=float).reshape(ROTOR_COUNT)
        if not (np.isfinite(x).all() and np.isfinite(cmd).all()):
            self._prev = None                  # a broken frame: restart the evidence at the next good one
            return self.status
        if thrust_limit_n is not None:
            limit = np.asarray(thrust_limit_n, dtype=float).reshape(ROTOR_COUNT)
            self._limit_n = np.where(np.isfinite(limit), limit, self._af.thrust_max_n)
        asked_before, asked = self._asked_n, cmd.clip(self._af.thrust_min_n, self._limit_n).tolist()
        self._asked_n = asked
        target = self._expected_response(asked)
        prev, self._prev = self._prev, _Frame(time_s, x)
        dt = None if prev is None else time_s - prev.time_s
        if dt is None or not 0 < dt <= self._c.max_gap_s:
            self._window.clear()
            self._lag_n, self._cmd_lag_n, self._cmd_lag_low_n, self._cmd_lag_high_n = target, asked, asked, asked
            self._run = None
            return self.status
        averages, ends = self._model.motor_response(                           # three lags in one call
            self._lag_n + self._cmd_lag_n + self._cmd_lag_high_n,
            target + asked + [max(a, b) for a, b in zip(asked_before, asked)], dt)
        r = ROTOR_COUNT
        average_n = averages[:r]
        self._lag_n, self._cmd_lag_n, self._cmd_lag_high_n = ends[:r], ends[r:2 * r], ends[2 * r:]
        self._cmd_lag_low_n = self._model.spin_response_n(
            self._cmd_lag_low_n, [min(a, b) for a, b in zip(asked_before, asked)], dt)
        reading = self._esc_reading(time_s, esc)
        if reading is not None and self._state is FaultState.CONFIRMED and self._kind is not FaultKind.DAMAGE:
            # The ESC measures the confirmed rotor (only a damaged propeller hides from it): the
            # residual's evidence would not be weighed; its window goes on for a frame without one.
            self._window_fit(time_s, prev.state, x, average_n, dt)
            evidence = self._esc_evidence(reading)
        else:
            evidence = self._residual_evidence(time_s, prev.state, x, average_n, cmd, dt, reading)
            if reading is not None and (direct := self._esc_evidence(reading)).index is not None and \
                    self._state is not FaultState.CONFIRMED:
                evidence = direct
        self._count_run(evidence, dt)
        escs_speak = time_s - self._esc_time_s <= self._c.esc_max_age_s
        if (reading is None and escs_speak and self._state is FaultState.CONFIRMED
                and self._kind is not FaultKind.DAMAGE):
            return self.status                 # the ESC measures this rotor: no new frame, no news of it
        self._decide(time_s, evidence, cmd, dt, reading)
        return self.status

    # -- models ----------------------------------------------------------------------------------
    def _expected_response(self, asked_n: list[float]) -> list[float]:
        """What each rotor delivers for the command as far as the detector knows (the faulty
        rotor: its effectiveness and ceiling)."""
        target = list(asked_n)
        if self._state is FaultState.CONFIRMED:
            i = self._index
            target[i] = min(self._effectiveness * target[i], self._estimate_n)
        least_n = self._af.thrust_min_n
        return [max(t, least_n) for t in target]

    def _common_ceiling_n(self, reading: EscReading | None) -> float:
        """The ceiling a sagging battery may give every rotor: below it a shortfall is a rotor's."""
        if reading is not None and math.isfinite(reading.battery_ceiling_n):
            return (1.0 - self._c.shortfall_min / 3) * reading.battery_ceiling_n
        return self._c.sag_floor_share * float(np.max(self._limit_n))

    def _esc_reading(self, time_s: float, esc: EscSample | None) -> EscReading | None:
        """The newest ESC frame, once (None: none new, too old, or without any speed)."""
        if (self._propeller is None or esc is None or not esc.time_s > self._esc_time_s
                or time_s - esc.time_s > self._c.esc_max_age_s):
            return None
        esc_dt, self._esc_time_s = esc.time_s - self._esc_time_s, esc.time_s
        if not np.isfinite(esc.rpm).any():
            return None
        self._current_rpm = current_speed_rpm(esc, self._esc_sample, self._current_rpm)
        self._esc_sample = esc
        # Overspeed is judged against the most the rotor may have been asked: a rotor slowing
        # down after a command drop still turns faster than the lagged model says.
        reading = read_escs(esc, [max(a, b) for a, b in zip(self._cmd_lag_high_n, self._asked_n)], self._propeller,
                            current_rpm=self._current_rpm)
        self._esc_voltage_v = reading.voltage_v
        thrust = [t if math.isfinite(t) else lag for t, lag in zip(reading.thrust_n.tolist(), self._cmd_lag_n)]
        self._esc_thrust_n = thrust
        # The rotor speed follows its first-order lag: speed = heading + decay (previous - heading).
        rpm = reading.rpm.tolist()
        if not all(math.isfinite(r) for r in rpm):        # a rotor not reported: the speed of its thrust
            rpm = [r if math.isfinite(r) else m for r, m in zip(rpm, self._propeller.rpm(np.array(thrust)).tolist())]
        previous, self._esc_rpm = self._esc_rpm, rpm
        decay = self._model.motor_decay(esc_dt) if math.isfinite(esc_dt) else 1.0
        heading = rpm if previous is None or decay >= 1 else [max((r - decay * p) / (1 - decay), 0.0)
                                                               for r, p in zip(rpm, previous)]
        self._esc_heading_n = [min(t, h) for t, h in zip(thrust, self._propeller.thrust_n(heading).tolist())]
        return reading

    # -- evidence ----------------------------------------------------------------------------------
    def _esc_evidence(self, reading: EscReading) -> _Evidence:
        c = self._c
        expected = self._cmd_lag_n
        if math.isfinite(reading.battery_ceiling_n):
            common_n = self._common_ceiling_n(reading)
            expected = [min(e, common_n) for e in expected]
        deficit = [e - t for e, t in zip(expected, self._esc_thrust_n)]
        # A rotor is short only of the least it may have been asked (a rotor the FC is
        # spinning up between our frames is not short).
        least = [min(e, low) - t for e, low, t in zip(expected, self._cmd_lag_low_n, self._esc_thrust_n)]
        i = max(range(ROTOR_COUNT), key=least.__getitem__)      # the first of the largest, as np.argmax
        alone = all(v < c.deficit_min_n / 2 for j, v in enumerate(least) if j != i)
        large = least[i] >= c.deficit_min_n or (least[i] >= c.deficit_min_n / 2
                                                 and least[i] >= c.shortfall_min * expected[i])
        self._deficit_n = np.array(deficit)
        kind = _KIND_OF_CONDITION[reading.condition[i]]
        if kind is FaultKind.DEGRADED and self._esc_heading_n[i] <= _STOPPED_SHARE * expected[i]:
            kind = FaultKind.MOTOR                # still spinning down, but heading for a standstill
        least_n = self._af.thrust_min_n
        return _Evidence(index=i if alone and large else None, path=_Path.ESC, kind=kind,
                         delivered_n=[max(h, least_n) for h in self._esc_heading_n], expected_n=expected,
                         short=[d >= c.ceiling_deficit_min_n for d in deficit], significant=_EVERY_ROTOR)

    def _residual_evidence(self, time_s: float, x_prev: np.ndarray, x: np.ndarray, average_n: list[float],
                           cmd: np.ndarray, dt: float, reading: EscReading | None) -> _Evidence:
        c = self._c
        raw = self._window_fit(time_s, x_prev, x, average_n, dt)
        pooled = combine([f for _, f in self._window])
        i, explained, left = best_hypothesis(pooled)
        noise_chi2 = _NOISE_CHI2_MARGIN * len(CHANNELS) * len(self._window)   # what noise alone leaves
        consistent = explained >= c.chi2_min and left <= c.unexplained_max * explained + noise_chi2
        expected = pooled.expected_thrust_n
        delivered = expected - pooled.deficit_size_n
        short = min(expected[i], self._common_ceiling_n(reading)) - delivered[i]
        votes = consistent and pooled.deficit_n[i] >= c.deficit_min_n and short >= c.deficit_min_n
        if self._state is FaultState.HEALTHY and not votes:
            self._bias_per_s += min(dt / c.bias_time_constant_s, 1.0) * (raw / dt - self._bias_per_s)
        if reading is None:
            self._deficit_n = pooled.deficit_size_n
        saturated = (cmd[i] >= self._thrust_bound_n()[i] - c.saturation_margin_n
                     or expected[i] - delivered[i] >= c.gross_share * expected[i])
        kind = FaultKind.UNKNOWN
        if reading is not None and reading.condition[i] is RotorCondition.NORMAL:
            kind = FaultKind.DAMAGE
        if self._state is FaultState.SUSPECT:   # a damaged propeller loses its thrust at once: no lag to undo
            expected, delivered = self._since_suspicion(time_s, dt, lagged=kind is not FaultKind.DAMAGE)
        short = np.zeros(ROTOR_COUNT, dtype=bool)
        short[i] = consistent and pooled.deficit_size_n[i] >= c.ceiling_deficit_min_n
        return _Evidence(index=i if votes else None, path=_Path.SATURATED if saturated else _Path.RESIDUAL,
                         kind=kind, delivered_n=delivered, expected_n=expected, short=short,
                         significant=pooled.b**2 / pooled.a >= c.chi2_min)

    def _window_fit(self, time_s: float, x_prev: np.ndarray, x: np.ndarray, average_n: list[float],
                    dt: float) -> np.ndarray:
        """The interval's fit into the evidence window (the last window_s); its raw residual (6,)."""
        fit, raw = self._model.fit(x_prev, x, average_n, dt, self._bias_per_s)
        self._window.append((time_s, fit))
        while self._window[0][0] <= time_s - self._c.window_s + 1e-9:
            self._window.popleft()
        return raw

    def _since_suspicion(self, time_s: float, dt: float, lagged: bool) -> tuple[np.ndarray, np.ndarray]:
        """(expected, delivered) of each rotor over the intervals since the suspicion began (after
        the fault). lagged: delivered as the level it heads to: a rotor that lost thrust at the
        start of that span decays towards it through the motor lag, so its average over the span
        is delivered + (expected - delivered) g with g = tau / span (1 - exp(-span / tau)). Only
        over spans of a few motor time constants (a fast confirmation): the fault's instant is
        known to a frame, which over a longer span would make the correction the larger error."""
        since = combine([f for t, f in self._window if t > self._suspect_since_s - dt - 1e-9])
        expected, average = since.expected_thrust_n, since.expected_thrust_n - since.deficit_size_n
        span = time_s - self._suspect_since_s + dt
        if not lagged or span > _LAG_SPANS * self._af.motor_time_constant_s:
            return expected, average
        g = self._af.motor_time_constant_s / span * (1.0 - self._model.motor_decay(span))
        heading = (average - g * expected) / (1.0 - g) if g < 1.0 else average
        return expected, np.maximum(np.minimum(heading, average), self._af.thrust_min_n)

    def _count_run(self, evidence: _Evidence, dt: float) -> None:
        """The time covered by votes in a row for one rotor on one fast path (ESC, saturation)."""
        if evidence.index is None or evidence.path is _Path.RESIDUAL:
            self._run = None
            return
        same = self._run is not None and (self._run.path, self._run.index) == (evidence.path, evidence.index)
        self._run = _Run(evidence.path, evidence.index, dt + (self._run.covered_s if same else 0.0))

    # -- decisions ----------------------------------------------------------------------------------
    def _decide(self, time_s: float, evidence: _Evidence, cmd: np.ndarray, dt: float,
                reading: EscReading | None) -> None:
        if self._state is FaultState.CONFIRMED:
            self._refine(evidence, cmd, dt, reading)
            return
        if evidence.index is None:
            self._clear()
            return
        if self._state is FaultState.HEALTHY or evidence.index != self._index:
            self._state, self._index, self._suspect_since_s = FaultState.SUSPECT, evidence.index, time_s
        c = self._c
        fast_s = {_Path.ESC: c.direct_confirm_s, _Path.SATURATED: c.saturated_confirm_s}.get(evidence.path)
        fast = fast_s is not None and self._run is not None and self._run.covered_s >= fast_s - 1e-9
        if fast or time_s - self._suspect_since_s >= c.confirm_s - 1e-9:
            self._confirm(time_s, evidence, reading)

    def _confirm(self, time_s: float, evidence: _Evidence, reading: EscReading | None) -> None:
        i = self._index
        self._state, self._detected_at_s, self._kind = FaultState.CONFIRMED, time_s, evidence.kind
        delivered, expected = evidence.delivered_n[i], evidence.expected_n[i]
        if self._kind in (FaultKind.MOTOR, FaultKind.PROPELLER):
            self._estimate_n = self._af.thrust_min_n
        elif self._kind is FaultKind.DAMAGE and expected > self._c.deficit_min_n:
            self._effectiveness = float(np.clip(delivered / expected, 0.0, 1.0))
            self._overspeed = self._esc_overspeed(reading)
            self._estimate_n = self._damage_ceiling_n()
            self._lag_n[i] *= self._effectiveness    # the same speed, less thrust at once: no lag to wait for
        else:
            self._estimate_n = self._clip(delivered)
        self._window.clear()                   # the evidence was read against the healthy model
        self._run = None

    def _refine(self, evidence: _Evidence, cmd: np.ndarray, dt: float, reading: EscReading | None) -> None:
        """Move the confirmed rotor's model towards what it delivers: lower when it clearly gives
        less than the model says, higher when, asked above its estimate, it measurably gives more.
        An ESC that shows the rotor stopped or unloaded after all (a lost propeller takes a few
        frames to overspeed) names the kind and zeroes the estimate; unloaded renames a damaged
        propeller only once the residual finds it giving less than _LOST_SHARE of its command (a
        damaged propeller turns a little fast, and a current its ESC sampled while braking it,
        held until the next poll, reads as no load)."""
        c, i = self._c, self._index
        later = None if reading is None else _KIND_OF_CONDITION.get(reading.condition[i])
        gives_thrust = self._kind is FaultKind.DAMAGE and self._effectiveness >= _LOST_SHARE
        if (later is FaultKind.MOTOR or later is FaultKind.PROPELLER and not gives_thrust) and self._kind is not later:
            self._kind, self._effectiveness, self._estimate_n = later, 1.0, self._af.thrust_min_n
        delivered = evidence.delivered_n[i]
        if self._kind is FaultKind.DAMAGE:
            self._refine_damage(evidence, dt, reading)
            return
        asked = min(self._clip(float(cmd[i])), self._estimate_n + c.probe_n)
        at_ceiling = asked >= self._estimate_n - c.saturation_margin_n
        if evidence.short[i] and at_ceiling:
            self._estimate_n = self._clip(self._estimate_n + c.estimate_gain * (delivered - self._estimate_n))
        elif (at_ceiling and self._kind is not FaultKind.PROPELLER and evidence.significant[i]
              and min(delivered, asked) >= self._estimate_n + c.probe_n / 2):     # a lost propeller stays lost
            self._estimate_n = self._clip(self._estimate_n + c.rise_gain * (min(delivered, asked) - self._estimate_n))
        # Healthy again: back within probe_n of its limit, or near a hover share and delivering
        # all it is asked for recover_s (the NMPC need not ask it for more to show it).
        near_hover = self._estimate_n >= self._af.hover_thrust_per_rotor_n - c.probe_n
        self._healthy_s = self._healthy_s + dt if near_hover and not evidence.short[i] else 0.0
        if self._estimate_n >= self._limit_n[i] - c.probe_n or self._healthy_s >= c.recover_s - 1e-9:
            self._clear()

    def _refine_damage(self, evidence: _Evidence, dt: float, reading: EscReading | None) -> None:
        """A damaged propeller's effectiveness falls at once on a clear deficit (estimate_gain a
        frame) and follows what it delivers either way over _DAMAGE_AVERAGE_S once the evidence
        window is full (the confirmation's short span reads it low); its ESC's overspeed is
        averaged alike. Its ceiling follows both (companion.core.damaged_rotor)."""
        c, i = self._c, self._index
        delivered, expected = evidence.delivered_n[i], evidence.expected_n[i]
        average = min(dt / _DAMAGE_AVERAGE_S, 1.0)
        if expected > c.deficit_min_n:
            gain = c.estimate_gain if evidence.short[i] else average if self._window_full(dt) else 0.0
            share = min(self._effectiveness * delivered / expected, 1.0)
            self._effectiveness = max(self._effectiveness + gain * (share - self._effectiveness), 0.0)
        if (overspeed := self._esc_overspeed(reading)) is not None:
            self._overspeed = overspeed if self._overspeed is None else (
                self._overspeed + average * (overspeed - self._overspeed))
        self._estimate_n = self._damage_ceiling_n()

    def _window_full(self, dt: float) -> bool:
        return len(self._window) * dt >= self._c.window_s - 1e-9

    def _esc_overspeed(self, reading: EscReading | None) -> float | None:
        """The confirmed rotor's thrust k_t w^2 at its ESC's speed over its command through the
        lag, (w / w_asked)^2 (None: no new ESC speed, or too little asked to tell)."""
        i = self._index
        if reading is None or not math.isfinite(reading.rpm[i]) or self._cmd_lag_n[i] <= self._c.deficit_min_n:
            return None
        return float(self._propeller.thrust_n(reading.rpm[i]) / self._cmd_lag_n[i])

    def _damage_ceiling_n(self) -> float:
        """A damaged propeller's most: with its ESC's speed, its thrust coefficient's share
        (effectiveness over overspeed) at the speed a full command reaches on its lighter load;
        without, the effectiveness times the limit (a limit below the airframe's: that too). One
        giving less than _LOST_SHARE of its command may be a lost propeller whose motor has yet
        to overspeed: never more than the effectiveness times the limit (a nearly unloaded motor
        would turn far faster at a full command, for no thrust)."""
        i = self._index
        scaled = self._clip(self._effectiveness * self._limit_n[i])
        if (self._overspeed is None or self._overspeed <= 0 or self._limit_n[i] < self._af.thrust_max_n
                or self._effectiveness < _LOST_SHARE):
            return scaled
        return self._clip(damaged_ceiling_n(self._af, self._effectiveness / self._overspeed, self._esc_voltage_v))

    def _clip(self, thrust_n: float) -> float:
        """Within the confirmed rotor's range (as np.clip: NaN stays NaN)."""
        return float(min(max(thrust_n, self._af.thrust_min_n), self._limit_n[self._index]))
