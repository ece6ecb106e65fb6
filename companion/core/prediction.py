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

import math
from collections import deque
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from companion.core import rom
from companion.core.casadi_call import BufferedFunction
from companion.core.codegen_cache import compiled
from companion.core.control_types import thrust_bounds
from companion.core.rom import ND, NX
from m4.airframe import ROTOR_COUNT, Airframe
from m4.setpoint import RateFeedback, ShortfallCover

_SUBSTEPS = 2
_MAX_PIECE_S = 0.01                 # longer stretches are split (RK4 accuracy, the motors' lag)
_TIME_EPS_S = 1e-6
HISTORY_S = 1.0                     # commands kept: longer leads are not predicted through
PIECES_PER_CALL = 32                # a lead of up to 32 pieces (0.3 s at 50 and 100 Hz) in one call


@dataclass(frozen=True)
class SentCommand:
    """A command we sent and the state it answered."""

    time_s: float                   # the telemetry instant it answers (FC clock)
    state: np.ndarray               # (20,) the measured state at that instant (hips: their goal)
    input: np.ndarray               # (8,) thrust_n as sent, hip_accel_rad_s2 as planned
    feedback: RateFeedback | None = None   # the rate feedback sent with it
    cover: ShortfallCover | None = None    # the shortfall cover sent with it
    fc_law: np.ndarray = field(init=False, repr=False, compare=False)   # its numbers as the prediction's pieces take them

    def __post_init__(self):
        object.__setattr__(self, "fc_law", _fc_law(self))      # once, after the send: not in the answer

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

    def in_flight(self, t0_s: float, t1_s: float, lead_s: float) -> list[tuple[float, SentCommand]]:
        """The commands the FC flies from t0_s to t1_s, oldest first, each with the instant it
        acts from: the one in force at t0_s (from t0_s), then each that takes over in (t0_s,
        t1_s); empty when none of ours is in force at t0_s. Read from the newest back to the
        one in force: a lead's worth of commands, not the whole history."""
        flown = []
        for command in reversed(self._commands):
            start_s = command.time_s + lead_s
            if start_s <= t0_s + _TIME_EPS_S:
                flown.append((t0_s, command))
                return flown[::-1]
            if start_s < t1_s - _TIME_EPS_S:
                flown.append((start_s, command))
        return []


class Predictor:
    """Forward prediction with the ROM dynamics `f` (rom.RomFunctions.f: x, u, d -> xdot) for
    commands sent every period_s (the rate feedback's planned rates are held after it). The
    pieces of a lead are flown by one CasADi function, up to `pieces_per_call` at a call (a
    longer lead takes more calls, the state and the thrusts carried over): the FC's command
    on the predicted rates, the motors' lag and the ROM's RK4 for every piece, none of it in
    Python. codegen: compiled to C (cached, companion.core.codegen_cache), else CasADi's VM;
    on preallocated buffers either way."""

    def __init__(self, af: Airframe, f: ca.Function, period_s: float, codegen: bool = False,
                 pieces_per_call: int = PIECES_PER_CALL):
        self._af = af
        flow = _flow(af, f, period_s, pieces_per_call)
        self._flow = BufferedFunction(compiled(flow) if codegen else flow, parameters=1)
        # a row a piece here: a column of the function's input, which is column-major
        self._pieces = self._flow.buffer("pieces").reshape(pieces_per_call, _PIECE_ROWS)

    def predict(self, x, time_s: float, lead_s: float, history: CommandHistory, disturbance,
                thrust_bound_n, thrust_now_n=None) -> np.ndarray:
        """The state at time_s + lead_s from x at time_s under the commands in flight, each
        rotor's thrust within what it can deliver now (thrust_bound_n: the NMPC's bounds, a lost rotor's from its estimate),
        starting from thrust_now_n (what the FC measured at time_s; None or NaN: the command in
        force); x itself when lead_s is 0, no command of ours is in force yet, or the
        prediction is not finite."""
        x = np.asarray(x, dtype=float).reshape(NX)
        end_s = time_s + lead_s
        flown = history.in_flight(time_s, end_s, lead_s) if lead_s > 0 else []
        if not flown:
            return x.copy()
        bound = thrust_bounds(self._af, thrust_bound_n)
        thrust = np.minimum(flown[0][1].thrust_n, bound)
        if thrust_now_n is not None:
            measured = np.asarray(thrust_now_n, dtype=float).reshape(ROTOR_COUNT)
            thrust = np.where(np.isfinite(measured), measured, thrust)
        tau = self._af.motor_time_constant_s
        timing, laws = [], []             # a piece's (length, its command in force since, decay, average); its command
        for (a, sent), b in zip(flown, [*(start_s for start_s, _ in flown[1:]), end_s]):
            pieces = max(1, math.ceil((b - a) / _MAX_PIECE_S - 1e-9))
            h = (b - a) / pieces
            decay = math.exp(-h / tau) if tau > 0 else 0.0
            average = 1.0 - (tau / h) * (1.0 - decay) if tau > 0 else 1.0     # share of the step done on average
            start_s = sent.time_s + lead_s
            timing += [(h, a + k * h - start_s, decay, average) for k in range(pieces)]
            laws += [sent.fc_law] * pieces
        xk, rows = x, self._pieces
        for first in range(0, len(laws), len(rows)):
            n = min(len(rows), len(laws) - first)
            rows[:n, :_LAW] = timing[first:first + n]
            rows[:n, _LAW:] = laws[first:first + n]
            rows[n:] = 0.0                # no length: idle
            xk, thrust = (r.copy() for r in self._flow.evaluate(xk, thrust, disturbance, bound))
        if not np.isfinite(xk).all():
            return x.copy()
        xk[rom.HIP], xk[rom.HIP_RATE] = x[rom.HIP], x[rom.HIP_RATE]
        return xk


# A piece's column: its length, how long its command has been in force at its start, the
# motors' decay over it and the share of the step they make on average, then its command's
# numbers (SentCommand.fc_law).
_LAW = 4
_PIECE_ROWS = _LAW + 4 + 3 + 3 + 12 + 16


def _fc_law(command: SentCommand) -> np.ndarray:
    """The command's numbers as a piece takes them: its thrusts, its rate feedback's planned
    rates, their change and its gain (column-major), its cover's gain (column-major); zeros
    for a feedback or a cover it does not have."""
    fb, cover = command.feedback, command.cover
    return np.concatenate([
        command.thrust_n,
        *((fb.rates_ref_frd_rad_s, fb.rates_ref_change_frd_rad_s2, fb.gain_n_per_rad_s.ravel(order="F"))
          if fb is not None else (np.zeros(3), np.zeros(3), np.zeros(12))),
        cover.gain.ravel(order="F") if cover is not None else np.zeros(16)])


def _flow(af: Airframe, f: ca.Function, period_s: float, pieces: int) -> ca.Function:
    """(x, thrust, d, bound; pieces: one column a piece) -> (x, thrust) after the pieces.
    A piece: the FC's command (m4.setpoint: the thrusts sent plus the rate feedback on the
    state's rates, within the rotors' range, plus the cover for what the bounds hold back,
    within the bounds), the motors' first-order lag towards it, the ROM's RK4 under their
    average thrust, the hips on their goal."""
    x, thrust = ca.SX.sym("x", NX), ca.SX.sym("thrust", ROTOR_COUNT)
    d, bound, piece = ca.SX.sym("d", ND), ca.SX.sym("bound", ROTOR_COUNT), ca.SX.sym("piece", _PIECE_ROWS)
    length_s, in_force_s, decay, average = (piece[i] for i in range(_LAW))
    sent, ref, ref_change = piece[_LAW:_LAW + 4], piece[_LAW + 4:_LAW + 7], piece[_LAW + 7:_LAW + 10]
    gain = ca.reshape(piece[_LAW + 10:_LAW + 22], ROTOR_COUNT, 3)
    cover = ca.reshape(piece[_LAW + 22:], ROTOR_COUNT, ROTOR_COUNT)
    rates_ref = ref + ref_change * ca.fmin(ca.fmax(in_force_s, 0.0), period_s)
    command = ca.fmin(ca.fmax(sent + ca.mtimes(gain, rates_ref - x[rom.RATES]), af.thrust_min_n), af.thrust_max_n)
    command = command + ca.mtimes(cover, ca.fmax(command - bound, 0.0))
    command = ca.fmin(ca.fmax(command, af.thrust_min_n), bound)
    u = ca.vertcat(thrust + (command - thrust) * average, ca.DM.zeros(ROTOR_COUNT))
    fly = ca.Function("m4_prediction_piece", [x, thrust, piece, d, bound],
                      [rom.rk4(f, x, u, d, length_s, _SUBSTEPS), command + (thrust - command) * decay])
    stay = ca.Function("m4_prediction_idle", [x, thrust, piece, d, bound], [x, thrust])
    either = ca.Function.conditional("m4_prediction_step", [stay], fly)       # an idle piece costs a branch
    x_in, thrust_in, d_in = ca.MX.sym("x", NX), ca.MX.sym("thrust", ROTOR_COUNT), ca.MX.sym("d", ND)
    bound_in, piece_in = ca.MX.sym("bound", ROTOR_COUNT), ca.MX.sym("piece", _PIECE_ROWS)
    step = ca.Function("m4_prediction_next", [x_in, thrust_in, piece_in, d_in, bound_in],
                       either(piece_in[0] > 0, x_in, thrust_in, piece_in, d_in, bound_in))
    chained = step.mapaccum("m4_prediction_pieces", pieces, 2)
    pieces_in = ca.MX.sym("pieces", _PIECE_ROWS, pieces)
    xs, thrusts = chained(x_in, thrust_in, pieces_in, ca.repmat(d_in, 1, pieces), ca.repmat(bound_in, 1, pieces))
    return ca.Function(f"m4_prediction_{pieces}", [x_in, thrust_in, d_in, bound_in, pieces_in],
                       [xs[:, -1], thrusts[:, -1]], ["x", "thrust", "d", "bound", "pieces"], ["x_end", "thrust_end"])
