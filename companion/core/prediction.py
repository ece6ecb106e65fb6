"""The measured state moved forward to the instant the next setpoint will act.

The setpoint answering telemetry instant t (FC clock) reaches the flight controller lead_s
later (the telemetry's way down, our step, the setpoint's way up; measured by the link:
companion.link_delay). Until then the FC flies the setpoints already in flight: the one
answering instant tau acts from tau + lead_s on. The NMPC plans from the state at t + lead_s,
which this predicts with the ROM's dynamics (the NMPC's own, RK4), each sent command held
over the stretch it is in force, the motors following it with their first-order lag
(airframe motor_time_constant_s) from the thrust the FC measured at t, plus the rate feedback
the FC closes around each command (m4.setpoint.RateFeedback) on the predicted body rates, as
the FC does on its gyro, and the cover the FC gives a rotor falling short of a command
(m4.setpoint.ShortfallCover) where the command asks a rotor for more than its bound. The hips are not predicted: their states are the goal the
controller keeps (companion.controller), which already is where the sent commands lead them.

Pure logic: no clock, no I/O. With lead_s = 0 (lockstep, or a link without delay) the state
is returned as measured.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import casadi as ca
import numpy as np

from companion.core import rom
from companion.core.casadi_call import BufferedFunction
from companion.core.codegen_cache import compiled
from companion.core.control_types import thrust_bounds
from companion.core.rom import ND, NU, NX
from m4.airframe import ROTOR_COUNT, Airframe
from m4.setpoint import RateFeedback, ShortfallCover

_SUBSTEPS = 2
_MAX_PIECE_S = 0.01                 # longer stretches are split (RK4 accuracy, the motors' lag)
_TIME_EPS_S = 1e-6
HISTORY_S = 1.0                     # commands kept: longer leads are not predicted through


@dataclass(frozen=True)
class SentCommand:
    """A command we sent and the state it answered."""

    time_s: float                   # the telemetry instant it answers (FC clock)
    state: np.ndarray               # (20,) the measured state at that instant (hips: their goal)
    input: np.ndarray               # (8,) thrust_n as sent, hip_accel_rad_s2 as planned
    feedback: RateFeedback | None = None   # the rate feedback sent with it
    cover: ShortfallCover | None = None    # the shortfall cover sent with it

    @property
    def thrust_n(self) -> np.ndarray:
        return self.input[rom.THRUST]


class CommandHistory:
    """The commands sent over the last HISTORY_S, oldest first."""

    def __init__(self):
        self._commands: deque[SentCommand] = deque()

    def __bool__(self) -> bool:
        return bool(self._commands)

    @property
    def newest(self) -> SentCommand | None:
        return self._commands[-1] if self._commands else None

    def add(self, command: SentCommand) -> None:
        self._commands.append(command)
        while self._commands[0].time_s < command.time_s - HISTORY_S:
            self._commands.popleft()

    def clear(self) -> None:
        self._commands.clear()

    def in_force(self, t_s: float, lead_s: float) -> SentCommand | None:
        """The command acting at FC instant t_s: the newest one whose instant plus lead_s has
        come (None: none of ours yet)."""
        for command in reversed(self._commands):
            if command.time_s + lead_s <= t_s + _TIME_EPS_S:
                return command
        return None

    def acting_from(self, t0_s: float, t1_s: float, lead_s: float) -> list[float]:
        """The instants in (t0_s, t1_s) at which another of our commands takes over."""
        return [c.time_s + lead_s for c in self._commands if t0_s + _TIME_EPS_S < c.time_s + lead_s < t1_s - _TIME_EPS_S]


class Predictor:
    """Forward prediction with the ROM dynamics `f` (rom.RomFunctions.f: x, u, d -> xdot) for
    commands sent every period_s (the rate feedback's planned rates are held after it); codegen:
    its flow compiled to C (cached, companion.core.codegen_cache), else CasADi's VM, on
    preallocated buffers either way (a piece of a lead costs one call, not a DM round trip)."""

    def __init__(self, af: Airframe, f: ca.Function, period_s: float, codegen: bool = False):
        self._af = af
        self._period_s = period_s
        x, u, d, dt = ca.SX.sym("x", NX), ca.SX.sym("u", NU), ca.SX.sym("d", ND), ca.SX.sym("dt")
        flow = ca.Function("m4_rom_flow", [x, u, d, dt], [rom.rk4(f, x, u, d, dt, _SUBSTEPS)])
        self._flow = BufferedFunction(compiled(flow) if codegen else flow)

    def predict(self, x, time_s: float, lead_s: float, history: CommandHistory, disturbance,
                thrust_bound_n, thrust_now_n=None) -> np.ndarray:
        """The state at time_s + lead_s from x at time_s under the commands in flight, each
        rotor's thrust within what it can deliver now (thrust_bound_n: the NMPC's bounds, a lost rotor's from its estimate),
        starting from thrust_now_n (what the FC measured at time_s; None or NaN: the command in
        force); x itself when lead_s is 0, no command of ours is in force yet, or the
        prediction is not finite."""
        x = np.asarray(x, dtype=float).reshape(NX)
        if not lead_s > 0 or history.in_force(time_s, lead_s) is None:
            return x.copy()
        end_s = time_s + lead_s
        bound = thrust_bounds(self._af, thrust_bound_n)
        edges = [time_s, *history.acting_from(time_s, end_s, lead_s), end_s]
        thrust = np.minimum(history.in_force(time_s, lead_s).thrust_n, bound)
        if thrust_now_n is not None:
            measured = np.asarray(thrust_now_n, dtype=float).reshape(ROTOR_COUNT)
            thrust = np.where(np.isfinite(measured), measured, thrust)
        tau = self._af.motor_time_constant_s
        xk = x.copy()
        for a, b in zip(edges[:-1], edges[1:]):
            sent = history.in_force(a, lead_s)
            pieces = max(1, int(np.ceil((b - a) / _MAX_PIECE_S - 1e-9)))
            h = (b - a) / pieces
            decay = np.exp(-h / tau) if tau > 0 else 0.0
            average = 1.0 - (tau / h) * (1.0 - decay) if tau > 0 else 1.0     # share of the step done on average
            for k in range(pieces):
                command = self._command(sent, xk, a + k * h - (sent.time_s + lead_s), bound)
                u = np.concatenate([thrust + (command - thrust) * average, np.zeros(ROTOR_COUNT)])   # hips: on their goal
                xk = self._flow(xk, u, disturbance, h)[0].ravel()
                thrust = command + (thrust - command) * decay
        if not np.isfinite(xk).all():
            return x.copy()
        xk[rom.HIP], xk[rom.HIP_RATE] = x[rom.HIP], x[rom.HIP_RATE]
        return xk

    def _command(self, sent: SentCommand, x, acting_s: float, bound) -> np.ndarray:
        """What the FC commands acting_s after `sent` took effect, the robot at state x: the
        thrusts sent plus their rate feedback and the cover for what the bounds hold back,
        within the bounds."""
        af = self._af
        thrust = sent.thrust_n
        if sent.feedback is not None:
            thrust = thrust + sent.feedback.thrust_change_n(x[rom.RATES], acting_s, self._period_s)
        thrust = thrust.clip(af.thrust_min_n, af.thrust_max_n)
        if sent.cover is not None:
            thrust = thrust + sent.cover.thrust_change_n(np.maximum(thrust - bound, 0.0))
        return thrust.clip(af.thrust_min_n, bound)
