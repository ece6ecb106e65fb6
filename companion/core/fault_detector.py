"""Rotor thrust-loss detection, isolation and sizing, handed to the NMPC as a thrust bound.

Each telemetry frame the detector weighs the evidence of the interval since the previous
frame (companion.core.fault_residual: the reduced-order model's prediction error explained
by one rotor's thrust deficit; or, when the flight controller reports each thruster's
delivered thrust, that deficit directly). An interval "votes" for rotor i when the best
hypothesis is a deficit of at least deficit_min_n, the residual is significant (chi2 it
explains >= chi2_min) and one rotor explains it (what it leaves is small next to what it
explains). The evidence of the last window_s is pooled before voting.

The direct path compares each rotor's delivered thrust with its command passed through the
motor's first-order lag (airframe motor_time_constant_s), so a fast command step that the
motor is still following is no deficit. A frame votes for rotor i when its shortfall is at
least deficit_min_n, or at least half that and shortfall_min of the lagged command, while
every other rotor delivers what it is asked. Delivered thrust is a measurement, not an
inference: votes in a row that cover direct_confirm_s confirm at once (at 50 Hz two frames;
at 10 Hz one frame already spans three motor time constants, and waiting for a second would
cost 0.1 s of an unchecked fall).

    healthy --vote i--> suspect(i) --votes for i during confirm_s--> confirmed(i)
    suspect(i) --direct votes for i in a row covering direct_confirm_s--> confirmed(i)
    suspect(i) --no vote--> healthy;  suspect(i) --vote j--> suspect(j)

Confirmed is final (one rotor fault per flight). At confirmation the rotor's ceiling is
estimated as the thrust it delivered over the window (commanded - deficit), or on the
direct path as the thrust its lagged response is heading to (the level it saturates at,
from its last two delivered thrusts); afterwards it
is lowered whenever the rotor, commanded at its ceiling, clearly delivers less (a
significant residual it alone explains), never raised by noise. It is handed out in
thrust_max_estimate_n: a partial loss is a ceiling the rotor never exceeds, a total loss a
ceiling near 0. The NMPC keeps its cost and model and only sees a tighter bound (no
controller switch). While healthy, the residual the model always shows (mass, drag, trim)
is learnt slowly and removed.

Time and frames: time_s is the telemetry time; the state is the ROM state of the measured
robot (centre of mass, see companion.core.rom); thrust_cmd_n is the command in force during
the interval that ends at time_s (the last setpoint sent before this frame).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from companion.core import rom
from companion.core.control_types import FaultState, FaultStatus
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
    confirm_s: float = 0.1                # votes for one rotor during this long confirm it
    direct_confirm_s: float = 0.03        # delivered-thrust votes in a row covering this long confirm (~ motor lag)
    shortfall_min: float = 0.3            # share of its lagged command a rotor may fall short by (direct path)
    saturation_margin_n: float = 0.5      # a rotor commanded within this of its ceiling is at its ceiling
    ceiling_deficit_min_n: float = 0.5    # a deficit this large of the lost rotor at its ceiling lowers the estimate
    estimate_gain: float = 0.3            # weight of each such observation after confirmation
    bias_time_constant_s: float = 2.0     # learning time of the residual the model always shows
    max_gap_s: float = 0.5                # frames further apart restart the evidence

    def validate(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"FaultDetectorConfig.{f.name} must be finite and >= 0, got {value}")
        for name in ("velocity_noise_m_s", "rates_noise_rad_s", "deficit_min_n", "window_s",
                     "bias_time_constant_s", "max_gap_s"):
            if getattr(self, name) <= 0:
                raise ValueError(f"FaultDetectorConfig.{name} must be > 0")
        if self.estimate_gain > 1:
            raise ValueError(f"FaultDetectorConfig.estimate_gain must be <= 1, got {self.estimate_gain}")


@dataclass(frozen=True)
class _Evidence:
    rotor: int | None                  # 0-based rotor voted for, None: no vote
    consistent: int | None             # 0-based rotor that alone explains a significant residual (any size)
    deficit_n: np.ndarray              # (4,) expected - delivered thrust of each rotor over the interval
    ceiling_n: np.ndarray              # (4,) thrust each rotor delivers (direct: the level its lag heads to)
    direct: bool                       # from delivered-thrust telemetry


class FaultDetector:
    def __init__(self, af: Airframe, config: FaultDetectorConfig = FaultDetectorConfig()):
        config.validate()
        self._af, self._c = af, config
        self._model = ThrustResidualModel(af, ResidualNoise(
            velocity_m_s=config.velocity_noise_m_s, rates_rad_s=config.rates_noise_rad_s,
            force_n=config.force_model_error_n, torque_n_m=config.torque_model_error_n_m,
            torque_share=config.torque_model_share))
        self._limit_n = np.full(ROTOR_COUNT, af.thrust_max_n)
        self._estimate_n: float | None = None
        self._prev: tuple[float, np.ndarray] | None = None
        self._lag_n = np.zeros(ROTOR_COUNT)        # thrust the motors deliver (as reported, else modelled)
        self._cmd_lag_n = np.zeros(ROTOR_COUNT)    # the command through the motor lag: what healthy motors deliver
        self._direct_votes_s = 0.0                 # time covered by the direct votes in a row for the suspect rotor
        self._window: deque[tuple[float, IntervalFit]] = deque()
        self._bias_per_s = np.zeros(len(CHANNELS))
        self._rotor: int | None = None
        self._state = FaultState.HEALTHY
        self._suspect_since_s = 0.0
        self._detected_at_s: float | None = None
        self._deficit_n = np.zeros(ROTOR_COUNT)

    @property
    def status(self) -> FaultStatus:
        bounds = self._limit_n.copy()
        if self._state is FaultState.CONFIRMED:
            bounds[self._rotor] = self._estimate_n
        rotor = None if self._rotor is None else self._rotor + 1
        message = f"thrust loss rotor {rotor}" if self._state is FaultState.CONFIRMED else ""
        return FaultStatus(state=self._state, rotor=rotor, thrust_max_estimate_n=bounds,
                           detected_at_s=self._detected_at_s, message=message, deficit_n=self._deficit_n.copy())

    def update(self, time_s: float, state_measured, thrust_cmd_n, thrust_limit_n=None,
               thrust_delivered_n=None) -> FaultStatus:
        """One telemetry frame. thrust_limit_n (4,): each rotor's limit as known without this
        detector (default and NaN entries: the airframe's thrust_max_n); thrust_delivered_n
        (4,): the flight controller's per-thruster thrust, NaN (or None) when unknown. A frame
        with a non-finite state or command is skipped and restarts the evidence."""
        x = np.asarray(state_measured, dtype=float).reshape(rom.NX)
        cmd = np.asarray(thrust_cmd_n, dtype=float).reshape(ROTOR_COUNT)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(cmd))):
            self._prev = None                  # a broken frame: restart the evidence at the next good one
            return self.status
        if thrust_limit_n is not None:
            limit = np.asarray(thrust_limit_n, dtype=float).reshape(ROTOR_COUNT)
            self._limit_n = np.where(np.isfinite(limit), limit, self._af.thrust_max_n)
        ceiling = self._limit_n.copy()
        if self._state is FaultState.CONFIRMED:
            ceiling[self._rotor] = min(self._estimate_n, ceiling[self._rotor])
        target = np.clip(cmd, self._af.thrust_min_n, ceiling)
        delivered = None if thrust_delivered_n is None else np.asarray(thrust_delivered_n, dtype=float)
        prev, self._prev = self._prev, (time_s, x)
        dt = None if prev is None else time_s - prev[0]
        if dt is None or not 0 < dt <= self._c.max_gap_s:
            self._window.clear()
            self._lag_n = self._cmd_lag_n = target
            return self.status
        average_n, end_n = self._model.motor_response(self._lag_n, target, dt)
        self._cmd_lag_n = self._model.motor_response(self._cmd_lag_n, target, dt)[1]
        if delivered is not None and np.all(np.isfinite(delivered)):
            evidence = self._direct_evidence(delivered, dt)
            if evidence.rotor is None:
                self._direct_votes_s = 0.0
            else:                                # a vote: extends the run when it is for the same rotor
                self._direct_votes_s = dt + (self._direct_votes_s if evidence.rotor == self._rotor else 0.0)
            self._deficit_n = evidence.deficit_n
            self._lag_n = delivered
        else:
            evidence = self._model_evidence(time_s, prev[1], x, average_n, dt)
            self._lag_n = end_n
            self._direct_votes_s = 0.0
        self._decide(time_s, evidence, target)
        return self.status

    def _direct_evidence(self, delivered_n: np.ndarray, dt: float) -> _Evidence:
        c = self._c
        expected = self._cmd_lag_n
        deficit = expected - delivered_n
        i = int(np.argmax(deficit))
        alone = bool(np.all(np.delete(deficit, i) < c.deficit_min_n / 2))
        large = deficit[i] >= c.deficit_min_n or (deficit[i] >= c.deficit_min_n / 2
                                                   and deficit[i] >= c.shortfall_min * expected[i])
        decay = self._model.motor_decay(dt)       # delivered = heading + decay (previous - heading)
        heading_n = (delivered_n - decay * self._lag_n) / (1 - decay)
        return _Evidence(rotor=i if alone and large else None, consistent=i if alone else None, deficit_n=deficit,
                         ceiling_n=np.minimum(heading_n, delivered_n), direct=True)

    def _model_evidence(self, time_s: float, x_prev: np.ndarray, x: np.ndarray, average_n: np.ndarray,
                        dt: float) -> _Evidence:
        c = self._c
        fit, raw = self._model.fit(x_prev, x, average_n, dt, self._bias_per_s)
        self._window.append((time_s, fit))
        while self._window[0][0] <= time_s - c.window_s + 1e-9:
            self._window.popleft()
        pooled = combine([f for _, f in self._window])
        self._deficit_n = pooled.deficit_n
        i, explained, left = best_hypothesis(pooled)
        noise_chi2 = _NOISE_CHI2_MARGIN * len(CHANNELS) * len(self._window)   # what noise alone leaves
        consistent = explained >= c.chi2_min and left <= c.unexplained_max * explained + noise_chi2
        votes = consistent and pooled.deficit_n[i] >= c.deficit_min_n
        if self._state is FaultState.HEALTHY and not votes:
            self._bias_per_s += min(dt / c.bias_time_constant_s, 1.0) * (raw / dt - self._bias_per_s)
        return _Evidence(rotor=i if votes else None, consistent=i if consistent else None,
                         deficit_n=pooled.deficit_size_n,
                         ceiling_n=pooled.expected_thrust_n - pooled.deficit_size_n, direct=False)

    def _decide(self, time_s: float, evidence: _Evidence, target_n: np.ndarray) -> None:
        if self._state is FaultState.CONFIRMED:
            self._refine(evidence, target_n)
            return
        if evidence.rotor is None:
            self._state, self._rotor = FaultState.HEALTHY, None
            return
        if self._state is FaultState.HEALTHY or evidence.rotor != self._rotor:
            self._state, self._rotor, self._suspect_since_s = FaultState.SUSPECT, evidence.rotor, time_s
        fast = evidence.direct and self._direct_votes_s >= self._c.direct_confirm_s - 1e-9
        if fast or time_s - self._suspect_since_s >= self._c.confirm_s - 1e-9:
            self._state, self._detected_at_s = FaultState.CONFIRMED, time_s
            self._estimate_n = self._clip(evidence.ceiling_n[self._rotor])

    def _refine(self, evidence: _Evidence, target_n: np.ndarray) -> None:
        """Lower the ceiling estimate towards what the rotor delivered when, commanded at its
        ceiling, it clearly delivered less (a significant residual that this rotor alone
        explains). A rotor that delivers what it is asked says only that its ceiling is at
        least that: no update, so noise and model errors cannot ratchet the estimate down."""
        i = self._rotor
        if target_n[i] < self._estimate_n - self._c.saturation_margin_n:
            return
        if evidence.consistent != i or evidence.deficit_n[i] < self._c.ceiling_deficit_min_n:
            return
        observed = evidence.ceiling_n[i]
        self._estimate_n = self._clip(self._estimate_n + self._c.estimate_gain * (observed - self._estimate_n))

    def _clip(self, thrust_n: float) -> float:
        return float(np.clip(thrust_n, self._af.thrust_min_n, self._limit_n[self._rotor]))
