"""The simulated flight controller's MAVLink logic (system 1, component 1), without sockets.

It implements the contract of docs/flight-controller.md, where each rule (setpoint age and
staleness, authority, arming, failsafe, the fast loops) is stated once. It owns the plant's
actuator commands: the companion's M4_SETPOINT while setpoints are fresh, its own failsafe
(sitl/fc/failsafe.py) otherwise. STATUSTEXT announces each mode change and each rotor fault applied
(a command's or the scenario's: m4/fault_text.py). Commands (sitl/fc/commands.py) are
acknowledged; telemetry streams (sitl/fc/streams.py) are built from the measured plant state:
with an `estimator` (sitl/fc/estimator.py: a scenario's [sensors] profile "mocap" or "gps"),
its attitude, rates, position and velocity come from the estimator's raw sensors, never the
truth, and so do the rates of the fast loop.

Authority (docs/authority.md), as autopilots have it: setpoints and M4_FAULT_STATUS are taken
from the paired companion only (`companion_ids`, system 1 component 191 by default);
commands (sitl/fc/commands.py: rotor faults, arming, modes, stream rates, requests) from the
companion and from any ground station alike. With `require_signed`, only signed packets
count, from anyone. What it refuses is counted and logged once per 10 s per kind
(m4.log_limit), a command with COMMAND_ACK DENIED. Other command-like traffic (missions,
parameters) asks `from_commander` as the commands do. A setpoint is judged
by the instant it answers (time_boot_ms, the FC's clock), with `MAX_AGE_MIN_MS`,
`MAX_AGE_PERIODS` and `MAX_PERIOD_MS`; what it refuses is counted by reason. A second sender
using the companion's ids (its caller, sitl/serve.py, knows the addresses) is reported by
`second_sender` (m4/mavlink/second_sender.py): counted, a log line and a STATUSTEXT WARNING.

Modes (sitl/fc/modes.py, m4/fc_mode.py): `selected` is the mode a command chose (COMPANION
at arming); while setpoints are fresh it is the mode in force and the companion flies it
(its mission, a hold, a landing). While they are stale the failsafe flies and its mode is in
force (HOLD, LAND after 2 s; LAND at once when LAND is selected); the selection stays, except
that nothing but LAND can be selected then (nobody would fly it). Each change of the mode in
force, or of who flies it, is announced (STATUSTEXT) and sent as CURRENT_MODE.

Arming: the FC starts armed (the scenarios start in the air). Once it has landed or applied
a thrust cut it is disarmed: setpoints are refused (counted) and the motors stay off until
the companion or a ground station re-arms it with MAV_CMD_COMPONENT_ARM_DISARM(1).

Parameters (PARAM_* protocol, `params`: m4/mavlink/param_service.py over sitl/fc/params.py) are
answered to the companion and ground stations alike (with `require_signed`, signed only); their
values live here (`stale_min_ms`, the fast loops' switches) and in the failsafe and rotor watch.

It keeps the mission a ground station uploads (sitl/fc/mission_store.py: the mission protocol,
from the companion and ground stations alike, with `require_signed` signed only) for the
companion to fly, and reports its progress.

It keeps the last M4_FAULT_STATUS of its companion until it is armed again (a restarted
companion asks for it with MAV_CMD_REQUEST_MESSAGE: the fault and the mission's progress) and
answers TIMESYNC requests (tc1 = 0) with its clock in ns.

The caller (sitl/serve.py) steps the plant and calls, at each instant on the 1 ms clock:
`handle()` for each message received, `tick()` every TICK_MS, `telemetry()` when streams
are due, and `take_outbox()` to send what the FC has to say on its own.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.fault_kind import FaultKind
from m4.fault_text import fault_text
from m4.log_limit import RepeatLimiter
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.param_service import PARAM_IDS, ParamService
from m4.mavlink.second_sender import SecondSender
from m4.setpoint import RateFeedback, Setpoint, ShortfallCover
from m4.units import RAD_S_TO_RPM
from sitl.fc.commands import CommandHandler
from sitl.fc.esc_telemetry import EscTelemetry
from sitl.fc.estimator import Estimator
from sitl.fc.failsafe import Failsafe
from sitl.fc.fast_loop import FastLoop
from sitl.fc.gyro_shortfall import GyroShortfallMeter
from sitl.fc.mission_store import MISSION_IDS, MissionStore
from sitl.fc.modes import FcMode, current_mode
from sitl.fc.rotor_watch import RotorWatch
from sitl.fc.shortfall import ShortfallMeter
from sitl.plant.state import PlantState
from sitl.fc.streams import DEFAULT_INTERVALS_MS, ESC_TELEMETRY_INTERVALS_MS, FRAME, StreamSchedule
from sitl.fc.telemetry import Home, Snapshot, Telemetry, statustext

TICK_MS = 4                       # the failsafe controller and the staleness check: 250 Hz
STALE_PERIODS = 3
STALE_MIN_MS = 300
LOST_FRACTION = 0.5               # a rotor left with less than this of hover thrust: fly on three
MAX_PERIOD_MS = 1000              # a setpoint claiming a longer period is refused
MAX_AGE_MIN_MS = 150              # a setpoint answering an instant older than this (and
MAX_AGE_PERIODS = 2               # than this many of its periods) is too old to help
_CONTROL_IDS = frozenset({mavlink.MAVLINK_MSG_ID_M4_SETPOINT, mavlink.MAVLINK_MSG_ID_COMMAND_LONG,
                          mavlink.MAVLINK_MSG_ID_COMMAND_INT, mavlink.MAVLINK_MSG_ID_M4_FAULT_STATUS})
_COMMAND_IDS = (mavlink.MAVLINK_MSG_ID_COMMAND_LONG, mavlink.MAVLINK_MSG_ID_COMMAND_INT)


_ANNOUNCE = {                     # (mode in force, flown by the failsafe) -> STATUSTEXT
    (FcMode.COMPANION, False): (mavlink.MAV_SEVERITY_INFO, "FC: flying companion setpoints"),
    (FcMode.HOLD, False): (mavlink.MAV_SEVERITY_INFO, "FC HOLD: the companion holds"),
    (FcMode.LAND, False): (mavlink.MAV_SEVERITY_INFO, "FC LAND: the companion lands"),
    (FcMode.HOLD, True): (mavlink.MAV_SEVERITY_WARNING, "FC failsafe HOLD: no fresh setpoints"),
    (FcMode.LAND, True): (mavlink.MAV_SEVERITY_WARNING, "FC failsafe LAND: setpoints stale for 2 s"),
    (FcMode.LANDED, False): (mavlink.MAV_SEVERITY_NOTICE, "FC LANDED: thrust cut"),
}
_ANNOUNCE[FcMode.LANDED, True] = _ANNOUNCE[FcMode.LANDED, False]
_LAND_SELECTED = (mavlink.MAV_SEVERITY_WARNING, "FC failsafe LAND: no fresh setpoints")


def _clip(values: list[float], lo: float, hi: float) -> np.ndarray:
    """np.clip(values, lo, hi) (NaN and -0.0 kept alike) on four floats, for a fraction of the
    cost of np.clip's dispatch."""
    return np.array([min(max(v, lo), hi) for v in values])


@dataclass(frozen=True)
class ReceivedSetpoint:
    time_ms: int                  # the telemetry instant it answers (our clock)
    period_ms: int
    command: Setpoint

    def stale_after_ms(self, min_ms: int) -> int:
        periods_ms = STALE_PERIODS * self.period_ms
        return self.time_ms + (min_ms if min_ms > periods_ms else periods_ms)     # max(), no call: every tick


class _Measured(NamedTuple):
    """The plant's measured state at one instant of the FC's clock (read once per instant)."""
    time_ms: int
    state: PlantState


class _Gyro(NamedTuple):
    """The gyro's body rates (FRD, rad/s) at one instant of the FC's clock (read once per instant;
    Python floats: both fast-loop users take them apart)."""
    time_ms: int
    rates_frd_rad_s: list[float]


@dataclass
class FcCounters:
    setpoints_accepted: int = 0
    setpoints_dropped: int = 0      # every setpoint refused; by reason in `dropped_by_reason`
    commands_acked: int = 0
    refused_foreign: int = 0        # setpoints and fault status from anyone but the companion; unsigned commands
    commands_refused: int = 0       # commands answered other than ACCEPTED or FAILED (sitl/fc/commands.py)
    dropped_by_reason: collections.Counter = field(default_factory=collections.Counter)

    def drop(self, reason: str) -> None:
        self.setpoints_dropped += 1
        self.dropped_by_reason[reason] += 1


class FlightController:
    def __init__(self, airframe: Airframe, plant, home: Home | None = None, lockstep: bool = False,
                 companion_ids: tuple[int, int] = (FC_SYSTEM_ID, COMPANION_COMPONENT_ID), require_signed: bool = False,
                 log: Callable[[str], None] = lambda text: None, esc: EscTelemetry | None = None,
                 estimator: Estimator | None = None, links: int = 1):
        self.airframe = airframe
        self.companion_ids = companion_ids
        self.require_signed = require_signed
        self.log = log
        self._repeats = RepeatLimiter()
        self.second_sender = SecondSender("the companion", companion_ids, "FC", log,
                                          lambda text: self.announce(mavlink.MAV_SEVERITY_WARNING, text))
        self.armed = True
        self.fault_status: mavlink.MAVLink_m4_fault_status_message | None = None
        self.rotor_watch = RotorWatch(airframe)
        self.shortfall = ShortfallMeter(airframe, TICK_MS / 1000.0)
        self._esc_shortfall_n: list[float] | None = None   # None: no ESC telemetry
        self.gyro_shortfall = GyroShortfallMeter(airframe, TICK_MS / 1000.0)
        self._gyro_shortfall_n: list[float] | None = None  # None: the setpoint in force gives no effectiveness
        self._measured_tick_ms: int | None = None
        self._gyro_read: _Gyro | None = None
        self.lockstep = lockstep
        self.plant = plant
        self.esc = esc                          # None: no ESC telemetry (many FCs have none)
        self.estimator = estimator              # None: the plant's measured state as it is ("ideal")
        self.telemetry_builder = Telemetry(airframe, home, esc_telemetry=esc is not None)
        self.mission = MissionStore(self.telemetry_builder.home, log)
        self.telemetry_builder.add(mavlink.MAVLINK_MSG_ID_MISSION_CURRENT, lambda snap: self.mission.current_message())
        intervals = DEFAULT_INTERVALS_MS if esc is None else ESC_TELEMETRY_INTERVALS_MS
        self.schedules = [StreamSchedule(intervals) for _ in range(links)]    # each link's own stream rates
        self.failsafe = Failsafe(airframe)
        self.counters = FcCounters()
        # parameters (sitl/fc/params.py), with the failsafe's and the rotor watch's
        self.stale_min_ms = STALE_MIN_MS
        self.rate_feedback_enabled = True
        self.shortfall_cover_enabled = True
        self.params: ParamService | None = None         # the parameter protocol (sitl/vehicle.py sets it up)
        self.setpoint: ReceivedSetpoint | None = None
        self.mode: FcMode | None = None         # the mode in force
        self.selected = FcMode.COMPANION        # the mode commanded
        self._by_failsafe = False               # the failsafe flies the mode in force
        self._told_selected: FcMode | None = None     # the selection CURRENT_MODE last told
        self._announced: tuple[int, str] | None = None  # the last STATUSTEXT on the mode
        self._applied: ReceivedSetpoint | None = None
        self._applied_at_ms = 0
        self._fast: tuple[ReceivedSetpoint, FastLoop] | None = None    # the fast loop of the setpoint in force
        self._plan: tuple[ReceivedSetpoint, tuple] | None = None       # and its plan for the gyro meter (_flown_plan)
        self._outbox: list[mavlink.MAVLink_message] = []
        self._measured: _Measured | None = None
        self._commands = CommandHandler(self)

    # -- the plant as the FC sees it -------------------------------------------------------
    def measured_state(self, now_ms: int) -> PlantState:
        if self._measured is None or self._measured.time_ms != now_ms:
            self._measured = _Measured(now_ms, self._sensed(self.plant.measured_state()))
        return self._measured.state

    def _sensed(self, measured: PlantState) -> PlantState:
        if self.estimator is None:
            return measured
        self.estimator.feed(self.plant.take_sensor_samples())
        return self.estimator.report(measured)

    def _gyro(self, now_ms: int) -> list[float]:
        """The body rates the fast loops fly on, read once per instant: the gyro, less the
        estimator's bias if it has one."""
        if self._gyro_read is None or self._gyro_read.time_ms != now_ms:
            if self.estimator is None:
                rates = self.plant.measured_rates_frd_rad_s()
            else:
                self.estimator.feed(self.plant.take_sensor_samples())
                rates = self.estimator.rates_frd_rad_s
            self._gyro_read = _Gyro(now_ms, rates.tolist())
        return self._gyro_read.rates_frd_rad_s

    def _command_plant(self, thrust_n, hip_rad, hip_rate_rad_s=None) -> None:
        self.plant.command(thrust_n, hip_rad, hip_rate_rad_s)
        self._measured = None

    def _fast_loop(self, now_ms: int) -> None:
        """The companion's thrusts plus, every tick, its rate feedback on our gyro and the other
        rotors' cover for a rotor our ESCs or our gyro show falling short (sitl/fc/fast_loop.py)."""
        if self._fast is None or self._fast[0] is not self.setpoint:
            af = self.airframe
            self._fast = (self.setpoint, FastLoop(self.setpoint.command, af.thrust_min_n, af.thrust_max_n))
        thrust_n = self._fast[1].thrust_n(self._gyro(now_ms), (now_ms - self._applied_at_ms) / 1000.0,
                                          self.setpoint.period_ms / 1000.0, self._shortfall_n())
        self.plant.command_thrust(thrust_n)
        self._measured = None

    def set_rotor_loss(self, rotor: int, loss: float, kind: FaultKind = FaultKind.DEGRADED) -> None:
        """Rotor 1..4 (0: all) fails as `kind` (sitl/plant/thrusters.py); loss 0 restores it.
        Said as STATUSTEXT INFO (m4.fault_text), whoever asked (a command, the scenario): the
        flight's logs carry the fault."""
        for r in range(1, ROTOR_COUNT + 1) if rotor == 0 else (rotor,):
            self.plant.set_rotor_loss(r, loss, kind)
        self._measured = None
        self.announce(mavlink.MAV_SEVERITY_INFO, fault_text(rotor, loss, kind))

    # -- modes -------------------------------------------------------------------------------
    def _set_mode(self, mode: FcMode, by_failsafe: bool) -> None:
        """The mode in force and who flies it: announced when the announcement changes,
        CURRENT_MODE sent when the mode in force or the selection changes."""
        land_selected = mode == FcMode.LAND and by_failsafe and self.selected == FcMode.LAND
        announcement = _LAND_SELECTED if land_selected else _ANNOUNCE[mode, by_failsafe]
        if announcement != self._announced:
            self._announced = announcement
            self._outbox.append(statustext(*announcement))
        if (mode, self.selected) != (self.mode, self._told_selected):
            self._outbox.append(current_mode(mode, self.selected))
        self.mode, self._by_failsafe, self._told_selected = mode, by_failsafe, self.selected

    def fresh(self, now_ms: int) -> bool:
        """The companion's setpoints are fresh: it flies."""
        return self.setpoint is not None and now_ms <= self.setpoint.stale_after_ms(self.stale_min_ms)

    def select_mode(self, mode: FcMode, now_ms: int) -> None:
        """Make `mode` the selected one (sitl/fc/commands.py judged it possible) and put it in
        force at once: the companion flies it, or, LAND while the failsafe holds, the failsafe
        lands now."""
        self.selected = mode
        if self._by_failsafe and mode == FcMode.LAND and self.mode == FcMode.HOLD:
            self.failsafe.engage(self.measured_state(now_ms), now_ms, may_land=True, land=True)
        self.tick(now_ms)

    def set_armed(self, armed: bool) -> None:
        """Arm (the next fresh setpoint, or the failsafe, flies) or disarm (motors off)."""
        if armed != self.armed:
            self.armed = armed
            self.announce(mavlink.MAV_SEVERITY_NOTICE, "FC armed" if armed else "FC disarmed")
            self.setpoint = None
            if armed:
                self.fault_status = None        # a new flight: the last one's fault and mission stay behind
                self.selected = FcMode.COMPANION
            else:
                self._outbox += self.mission.landed()

    def _watch_rotors(self, now_ms: int, thrust_cmd_n, rpm) -> None:
        """The FC's own lost-rotor check on the speeds its ESCs report (sitl/fc/rotor_watch.py)
        against what it commanded them."""
        if self.rotor_watch.lost is not None:
            return
        speed_rad_s = [r / RAD_S_TO_RPM for r in rpm]
        if self.rotor_watch.update(thrust_cmd_n, speed_rad_s, now_ms) is not None:
            self.announce(mavlink.MAV_SEVERITY_CRITICAL, f"FC: rotor {self.rotor_watch.lost} lost (ESC speed)")

    def tick(self, now_ms: int) -> None:
        """Choose who flies (companion or failsafe) and command the plant accordingly; the ESCs
        answer this output frame."""
        self._outbox += self.mission.tick(now_ms)
        self._measure(now_ms)
        if not self.armed:
            self._set_mode(FcMode.LANDED, by_failsafe=False)
            self._command_plant(np.zeros(ROTOR_COUNT), self.failsafe.hip_rad)
            return
        if self.fresh(now_ms):
            sp = self.setpoint.command
            if sp.thrust_cut:
                self.set_armed(False)
                self.tick(now_ms)
                return
            self._set_mode(self.selected, by_failsafe=False)
            fast = sp.rate_feedback is not None or sp.shortfall_cover is not None
            if self.setpoint is not self._applied:
                if fast:        # the fast loop commands the thrusts at once (finite: it keeps none of the last)
                    self.plant.command_hips(sp.hip_rad, sp.hip_rate_rad_s)
                else:
                    self._command_plant(sp.thrust_n, sp.hip_rad, sp.hip_rate_rad_s)
                self._applied, self._applied_at_ms = self.setpoint, now_ms
            if fast:
                self._fast_loop(now_ms)
            return
        state = self.measured_state(now_ms)
        self.failsafe.set_lost_rotor(self.lost_rotor())
        if not self._by_failsafe:
            self.failsafe.engage(state, now_ms, may_land=self.mode is not None, land=self.selected == FcMode.LAND)
        out = self.failsafe.update(state, now_ms)
        self._set_mode(out.mode, by_failsafe=True)
        self._command_plant(out.thrust_n, out.hip_rad)
        if out.mode == FcMode.LANDED:
            self.set_armed(False)

    def _measure(self, now_ms: int) -> None:
        """Once per tick, what the last tick's output gave: the ESCs answer it, and both
        shortfall meters read it. A setpoint arriving runs tick() at its instant too (or between
        ticks, in real time): measuring again would age the meters' motor model by a tick that
        did not pass, and the ESC meter would read a rotor the cover slows as one that lost its
        load."""
        if now_ms == self._measured_tick_ms or now_ms % TICK_MS:
            return
        self._measured_tick_ms = now_ms
        rotors = self.plant.rotor_state()
        if self.esc is not None:
            self.esc.sample(now_ms, rotors)
            rpm = self.esc.rpm(now_ms)
            self._esc_shortfall_n = self.shortfall.update(rotors.thrust_cmd_n, rpm)
            self._watch_rotors(now_ms, rotors.thrust_cmd_n, rpm)
        self._measure_on_gyro(now_ms, rotors.thrust_cmd_n)

    def _measure_on_gyro(self, now_ms: int, commanded) -> None:
        """The rotors' shortfall on our gyro (sitl/fc/gyro_shortfall.py) against the setpoint we
        flew over the last tick (commanded: what we sent the ESCs); the filter runs whoever flies."""
        companion_flies = self.mode not in (None, FcMode.LANDED) and not self._by_failsafe
        planned, accel, effectiveness = commanded, (0.0, 0.0), None
        if self._applied is not None and companion_flies:
            planned, change, effectiveness = self._flown_plan()
            if change is not None and now_ms - self._applied_at_ms < self._applied.period_ms:
                accel = change
        self._gyro_shortfall_n = self.gyro_shortfall.update(self._gyro(now_ms), commanded, planned, accel,
                                                            effectiveness)

    def _flown_plan(self) -> tuple[list[float], tuple[float, float] | None, np.ndarray | None]:
        """The setpoint in force as the gyro meter takes it, taken apart once per setpoint: its
        thrusts, its planned roll and pitch rate change (None: no rate feedback), its effectiveness."""
        if self._plan is None or self._plan[0] is not self._applied:
            sp = self._applied.command
            change = None if sp.rate_feedback is None else tuple(sp.rate_feedback.rates_ref_change_frd_rad_s2[:2].tolist())
            cover = sp.shortfall_cover
            self._plan = (self._applied, (sp.thrust_n.tolist(), change,
                                          None if cover is None else cover.effectiveness_frd_rad_s2_per_n))
        return self._plan[1]

    def _shortfall_n(self) -> list[float] | None:
        """Each rotor's shortfall, the larger of what the ESCs and the gyro measure (None: neither)."""
        esc, gyro = self._esc_shortfall_n, self._gyro_shortfall_n
        if esc is None or gyro is None:
            return gyro if esc is None else esc
        return [g if g > e else e for e, g in zip(esc, gyro)]          # max(e, g) without the call, every tick

    def lost_rotor(self) -> int | None:
        """The rotor the companion last reported lost (confirmed, below LOST_FRACTION of hover
        thrust), else the one the FC's own ESC telemetry shows lost (sitl/fc/rotor_watch.py, when
        it has ESC telemetry), or None."""
        f = self.fault_status
        if f is not None and f.state == mavlink.M4_FAULT_STATE_CONFIRMED and 1 <= f.rotor <= ROTOR_COUNT:
            if f.thrust_max_estimate_n[f.rotor - 1] < LOST_FRACTION * self.airframe.hover_thrust_per_rotor_n:
                return f.rotor
        return self.rotor_watch.lost

    # -- messages in ---------------------------------------------------------------------------
    @staticmethod
    def addressed_to_me(msg) -> bool:
        return msg.target_system in (0, FC_SYSTEM_ID) and msg.target_component in (0, FC_COMPONENT_ID)

    def from_companion(self, msg) -> bool:
        """Sent by the paired companion (and signed, when signing is required)."""
        return ((msg.get_srcSystem(), msg.get_srcComponent()) == self.companion_ids
                and (not self.require_signed or msg.get_signed()))

    def from_commander(self, msg) -> bool:
        """May command the FC: anyone (the companion, a ground station), signed when signing is
        required."""
        return not self.require_signed or msg.get_signed()

    def _say(self, key, text: str) -> None:
        self._repeats.say(key, text, self.log)

    def handle(self, msg, now_ms: int, link: int = 0) -> list[mavlink.MAVLink_message]:
        """React to one received message (on link `link`); returns the replies for its sender
        (acks, requested messages)."""
        msg_id = msg.get_msgId()
        if msg_id == mavlink.MAVLINK_MSG_ID_TIMESYNC:
            return [mavlink.MAVLink_timesync_message(now_ms * 1_000_000, msg.ts1)] if msg.tc1 == 0 else []
        if msg_id in PARAM_IDS and self.params is not None:
            return (self.params.handle(msg) or []) if self.from_commander(msg) else []
        if msg_id in MISSION_IDS:           # from the companion and ground stations alike; with signing, only signed
            if not self.from_commander(msg) or not self.addressed_to_me(msg):
                return []
            return self.mission.handle(msg, now_ms, self.from_companion(msg))
        if msg_id not in _CONTROL_IDS or (msg_id != mavlink.MAVLINK_MSG_ID_M4_FAULT_STATUS
                                          and not self.addressed_to_me(msg)):
            return []
        if msg_id in _COMMAND_IDS:
            return self._commands.handle(msg, now_ms, link) if self.from_commander(msg) else self._refuse(msg)
        if not self.from_companion(msg):
            return self._refuse(msg)
        if msg_id == mavlink.MAVLINK_MSG_ID_M4_SETPOINT:
            self._on_setpoint(msg, now_ms)
            return []
        self.fault_status = msg
        return []

    def _refuse(self, msg) -> list[mavlink.MAVLink_message]:
        self.counters.refused_foreign += 1
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.get_msgId() in _COMMAND_IDS:
            why = "unsigned (the FC has a signing key)"
        else:
            unsigned = " or unsigned" if self.require_signed else ""
            why = f"not the paired companion {self.companion_ids[0]}/{self.companion_ids[1]}{unsigned}"
        self._say(("foreign", msg.get_msgId()), f"refused {msg.get_type()} from {src[0]}/{src[1]}: {why}")
        if msg.get_msgId() in _COMMAND_IDS:
            return [self._commands.ack(msg, mavlink.MAV_RESULT_DENIED)]
        return []

    def _setpoint_fault(self, msg, values: list[list[float]], now_ms: int) -> str | None:
        """Why a setpoint from the companion cannot be applied (None: it can)."""
        if not 1 <= msg.period_ms <= MAX_PERIOD_MS:
            return "period"
        if msg.time_boot_ms > now_ms:
            return "future"
        if now_ms - msg.time_boot_ms > max(MAX_AGE_MIN_MS, MAX_AGE_PERIODS * msg.period_ms):
            return "too old"
        if self.setpoint is not None and msg.time_boot_ms < self.setpoint.time_ms:
            return "out of order"
        if not all(math.isfinite(v) for field in values for v in field):
            return "not finite"
        if not self.armed:
            return "disarmed"
        return None

    def _on_setpoint(self, msg, now_ms: int) -> None:
        values = [[float(v) for v in field] for field in (msg.thrust_n, msg.hip_angle_rad, msg.hip_rate_rad_s)]
        reason = self._setpoint_fault(msg, values, now_ms)
        if reason is not None:
            self.counters.drop(reason)
            self._say(("setpoint", reason), f"t={now_ms / 1000:.3f} s: setpoint for t={msg.time_boot_ms / 1000:.3f} s "
                                            f"refused: {reason}")
            return
        af = self.airframe
        thrust, hip, rate = values
        self.setpoint = ReceivedSetpoint(msg.time_boot_ms, msg.period_ms, Setpoint(
            thrust_n=_clip(thrust, af.thrust_min_n, af.thrust_max_n),
            hip_rad=_clip(hip, af.hip_min_rad, af.hip_max_rad),
            hip_rate_rad_s=_clip(rate, -af.hip_rate_max_rad_s, af.hip_rate_max_rad_s),
            thrust_cut=bool(msg.flags & mavlink.M4_SETPOINT_FLAG_THRUST_CUT),
            rate_feedback=RateFeedback.from_fields(msg.rates_ref_frd_rad_s, msg.rates_ref_change_frd_rad_s2,
                                                   msg.rate_gain) if self.rate_feedback_enabled else None,
            shortfall_cover=ShortfallCover.from_fields(msg.shortfall_gain, msg.effectiveness_frd_rad_s2_per_n)
            if self.shortfall_cover_enabled else None))
        self.counters.setpoints_accepted += 1
        self.tick(now_ms)

    # -- messages out --------------------------------------------------------------------------
    def snapshot(self, now_ms: int) -> Snapshot:
        state = self.measured_state(now_ms)
        landed = self.mode == FcMode.LANDED or bool(state.on_ground)
        return Snapshot(t_ms=now_ms, state=state, custom_mode=int(self.selected if self.mode is None else self.mode), armed=self.armed, landed=landed,
                        esc=None if self.esc is None else self.esc.report(now_ms), intended_mode=int(self.selected))

    @property
    def schedule(self) -> StreamSchedule:
        """The first link's stream rates (the companion's)."""
        return self.schedules[0]

    def schedule_for(self, link: int) -> StreamSchedule:
        """The stream rates of link `link` (MAV_CMD_SET_MESSAGE_INTERVAL sets the sender's link's)."""
        return self.schedules[link]

    def telemetry(self, now_ms: int, frame: bool = False, link: int = 0) -> list[mavlink.MAVLink_message]:
        """The streams due at `now_ms` on link `link` (with `frame`: plus the link's lockstep
        frame, less what it stopped), in order. In lockstep M4_THRUSTER_STATUS goes out only in
        frames: it tells the companion to answer."""
        schedule = self.schedules[link]
        ids = schedule.due(now_ms, schedule.frame if frame else ())
        if not ids:
            return []
        if self.lockstep and not frame:
            ids = [i for i in ids if i != FRAME[-1]]
            if not ids:
                return []
        snap = self.snapshot(now_ms)
        return [self.telemetry_builder.build(i, snap) for i in ids]

    def next_event_ms(self, now_ms: int) -> int:
        """The next instant at which the FC has something to do."""
        nxt = (now_ms // TICK_MS + 1) * TICK_MS              # the next tick
        for schedule in self.schedules:
            due = schedule.next_due_ms()
            if due is not None and due < nxt:
                nxt = max(due, now_ms + 1)
        return nxt

    def relayed(self, msg) -> mavlink.MAVLink_message | None:
        """The companion's STATUSTEXT at CRITICAL or above (its fault, a crash) as our own, for
        the ground stations: autopilots announce their own failures, and ground stations print
        the autopilot's texts (MAVProxy no other). None for anything else."""
        if (msg.get_msgId() != mavlink.MAVLINK_MSG_ID_STATUSTEXT or not self.from_companion(msg)
                or msg.severity > mavlink.MAV_SEVERITY_CRITICAL):
            return None
        return statustext(msg.severity, msg.text)

    def power_off(self, now_ms: int) -> list[mavlink.MAVLink_message]:
        """Its last word as it shuts down (the simulation's end): a HEARTBEAT with system_status
        MAV_STATE_POWEROFF, so that the companion tells the flight's end from a lost link."""
        beat = self.telemetry_builder.heartbeat(self.snapshot(now_ms))
        beat.system_status = mavlink.MAV_STATE_POWEROFF
        return [beat]

    def announce(self, severity: int, text: str) -> None:
        self._outbox.append(statustext(severity, text))

    def take_outbox(self) -> list[mavlink.MAVLink_message]:
        out, self._outbox = self._outbox, []
        return out

