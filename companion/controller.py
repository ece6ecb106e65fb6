"""One control step of the companion: measured ROM state and time in, a safe setpoint out.

Pure logic (no MAVLink, no sockets): the mission reference, the disturbance estimate, the
fault detector and the NMPC, and after a touchdown during the landing the thrust cut. A
confirmed fault only lowers that rotor's thrust bound in the NMPC (no controller switch)
and, with on_fault = "hold", turns the reference into a hold.

The setpoint answers the instant of the state: thrusts are the NMPC's first input. The hips
follow the planned joint motion: the controller integrates the NMPC's hip accelerations into
a hip goal (angle and rate; the ROM's double integrator) and hands the FC's servo a
trajectory (M4_SETPOINT: an angle at that instant and the rate it moves at) that starts on
the goal and reaches the planned hip angle one control period later. The NMPC's hip states
are that goal, not the measured joints: a servo holding a load deflects a little, and
planning from the deflected angle would feed the deflection back into the goal (the legs
creep). The measured joints still place the centre of mass; when goal and joints drift
apart by more than HIP_RESYNC_RAD (a blocked leg) or after a gap, the goal restarts from
the measured joints. Every setpoint passes `safe_setpoint` (companion.core.control_types)
before it leaves.

Delay: the setpoint reaches the FC lead_s after the instant it answers (measured by the link;
0 in lockstep). The NMPC plans from the state predicted to that moment through the commands
already in flight and the rate feedback the FC closes around each (companion.core.prediction),
along the reference from that moment; each setpoint carries its own rate feedback
(companion.core.rate_feedback). The detector and the disturbance estimate compare each period
with the thrust the FC reports it commanded over it (companion.core.applied_thrust), not with
the setpoint we sent last.

Fault detection input: the measured state, the command in force over the last period (the
FC's report of its thrusts when it gives one, else ours)
and the FC's ESC telemetry when it has any (None: saturation and the model residual alone).
The FC's per-rotor limits count only as a common cap (the largest of them): a limit that drops
on one rotor is exactly what the detector must find itself, so it is not handed to it. The
NMPC's bounds are the detector's (thrust_bound_n); a fault is announced at each confirmation
(after a recovery, a second fault is announced too).

The real-time iteration ([nmpc] scheme = "rti"): `step` is its feedback (one QP); `prepare`,
called once the setpoint has left, is its preparation for the next step, at the state the plan
predicts then, along the reference from then, with this step's bounds and disturbance.

The detector after the send: a frame that cannot confirm a fault (FaultDetector.cannot_confirm:
a fault confirmed already, or the detector healthy and the frame too soon after the last for
one vote to confirm) is left by `step` for `read_deferred`, called once the setpoint has left
(before `prepare`), instead of read before the solve; any other frame (a suspicion that may
confirm, new limits) is read before it, so a fault confirmed at a frame bounds that frame's
setpoint. Once a fault is confirmed, a frame's refinement of its rotor's ceiling (or its
recovery) bounds the next setpoint, one period later. A frame's fault status goes out once the
detector has read it: with the setpoint when read before the solve, else alone right after it
(`read_deferred` returns it; the app sends it stamped with the frame), so a status is never
later than the frame it reads. A frame nobody read after the send is read by the next `step`
first. Likewise what only the next step needs of this one waits until the setpoint has left:
its command's record (the history the next step's in-force command and prediction come from)
and the hip goal one period on are kept by `prepare`, or by the next `step` first.

Takeover: at the flight's first step and after a gap in which our setpoints went stale at the
FC (its failsafe flew; FC_STALE_PERIODS, FC_STALE_MIN_S: the FC contract), the thrusts ramp
from what the FC reports commanding (companion.core.takeover), and, when the FC says its
failsafe is landing, the plan lands from there instead of flying the mission on. The
mission's clock stops while the FC flies: it is the FC's clock less the time paused, so after
a gap the mission goes on where it was left.

The FC's mode (m4.fc_mode: the one selected, CURRENT_MODE's intended_custom_mode) says what
to fly, and a change is followed at the next step: COMPANION the mission; HOLD a brake from
where the robot is and a hold where it stops (m4.mission_plan.stopping), the mission's clock
stopped until the mode changes again; LAND a landing from where the robot is (the mission's
`land_from`, as when joining the FC's failsafe landing; after it the mission is that landing).
The NMPC, the fault detector and the FC's fast loops fly every mode alike. A restarted companion starts from the progress
the FC kept (m4.mission_plan.MissionProgress) instead of anchoring the mission where it finds
the robot.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from companion.core import rom
from companion.core.applied_thrust import AppliedThrust
from companion.core.control_types import (FaultState, FaultStatus, one_period_apart, plausible_state, safe_setpoint,
                                          thrust_bound_list)
from companion.core.disturbance import DisturbanceEstimator
from companion.core.esc_evidence import EscSample, PropellerModel
from companion.core.fault_detector import FaultDetector, FaultDetectorConfig
from companion.core.nmpc import Nmpc, NmpcResult
from companion.core.nmpc_config import NmpcConfig
from companion.core.prediction import CommandHistory, Predictor, SentCommand
from companion.core.rate_feedback import RateFeedbackDesign
from companion.core.reference import MissionReference, ReferenceConfig, reference_rows
from companion.core.takeover import TakeoverRamp
from companion.core.touchdown import TouchdownConfig, TouchdownDetector
from companion.core.upset import UpsetConfig, UpsetDetector
from m4.airframe import ROTOR_COUNT, Airframe
from m4.fc_mode import FcMode
from m4.mission import Mission
from m4.mission_plan import MissionProgress, stopping
from m4.setpoint import RateFeedback, Setpoint, ShortfallCover

if TYPE_CHECKING:
    from companion.config import CompanionConfig

HIP_RESYNC_RAD = 0.2             # hip goal this far from the measured joint: restart it there
FC_STALE_PERIODS = 3             # the FC flies its failsafe once our last setpoint is this many
FC_STALE_MIN_S = 0.3             # periods old, and at least this (mavlink_defs/README.md, Failsafe)

DetectorFactory = Callable[[], FaultDetector]
ReferenceFactory = Callable[[float, np.ndarray], MissionReference]    # (t0_s, start com NED) -> the mission's


@dataclass(frozen=True)
class ControllerSettings:
    """What the controller needs of the companion's configuration."""

    airframe: Airframe
    control_period_s: float
    nmpc: NmpcConfig
    disturbance_gain: float
    mission: Mission = field(default_factory=Mission)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    touchdown: TouchdownConfig = field(default_factory=TouchdownConfig)
    fault_detector: FaultDetectorConfig = field(default_factory=FaultDetectorConfig)
    upset: UpsetConfig = field(default_factory=UpsetConfig)
    rate_feedback_bandwidth_rad_s: float = 0.0      # the FC's rate feedback around the plan (0: none)
    shortfall_cover: bool = False                   # the FC's cover for a rotor falling short

    @classmethod
    def of(cls, config: CompanionConfig) -> ControllerSettings:
        return cls(airframe=config.airframe, control_period_s=config.control_period_s, nmpc=config.nmpc,
                   disturbance_gain=config.disturbance_gain, mission=config.mission, reference=config.reference,
                   touchdown=config.touchdown, fault_detector=config.fault_detector, upset=config.upset,
                   rate_feedback_bandwidth_rad_s=config.rate_feedback_bandwidth_rad_s,
                   shortfall_cover=config.shortfall_cover)


@dataclass(frozen=True, kw_only=True)
class ControlStep:
    """What one control step decided; built by keyword only."""

    time_s: float
    setpoint: Setpoint
    state: np.ndarray             # (20,) the ROM state planned from: measured (predicted lead_s on), the hips their goal
    fault: FaultStatus
    fault_confirmed_now: bool     # the step at which the fault was confirmed (announce it)
    disturbance: np.ndarray       # (6,) estimate handed to the NMPC
    lead_s: float = 0.0           # how far ahead of time_s the setpoint acts (the state is predicted there)
    reference: np.ndarray | None = None   # (N+1, 20); None when no solve ran
    nmpc: NmpcResult | None = None        # None when no solve ran (thrust cut, not started, implausible state)
    crash: str | None = None      # why the flight is over ("upside down", "on the ground"): thrust cut for good
    crash_now: bool = False       # the step at which the crash was recognised (announce it)
    took_over: bool = False       # the step that took control from the FC's own controller
    followed: FcMode | None = None  # the FC's mode this step began to follow (None: no change)


def _drifted(goal_rad: list[float], hip_rad: list[float]) -> bool:
    """Whether the hip goal is not finite or has drifted from the measured joints by more than
    HIP_RESYNC_RAD (the goal then restarts from the joints)."""
    return not all(map(math.isfinite, goal_rad)) or max(abs(g - h) for g, h in zip(goal_rad, hip_rad)) > HIP_RESYNC_RAD


@dataclass(frozen=True)
class HipGoal:
    """The servos' goal now: the ROM's hip states the NMPC plans from."""

    angle_rad: list[float]        # (4,)
    rate_rad_s: list[float]       # (4,)


@dataclass
class Flight:
    """What the controller knows of this flight since start(): forgotten by restart()."""

    reference: MissionReference
    touchdown: TouchdownDetector
    upset: UpsetDetector
    fault_announced: bool = False
    paused_s: float = 0.0         # the FC's clock less the mission's: when the mission began, time the FC's failsafe flew, and holds
    mode: FcMode = FcMode.COMPANION     # the FC's mode followed
    hold: Callable | None = None  # in HOLD: the hold's state(t) on the FC's clock (m4.mission_plan.stopping)
    hold_since_s: float = 0.0

    def mission_time_s(self, time_s: float) -> float:
        held_s = time_s - self.hold_since_s if self.hold is not None else 0.0
        return time_s - self.paused_s - held_s


class Controller:
    """The companion's controller: its airframe, mission, NMPC and detector settings.

    nmpc, new_detector and new_reference are built from the settings unless given (tests
    inject their own). The flight begins with start() at the first plausible measured state,
    which anchors the mission there; until then step() answers with the fallback.
    """

    def __init__(self, settings: ControllerSettings, *, nmpc: Nmpc | None = None,
                 new_detector: DetectorFactory | None = None, new_reference: ReferenceFactory | None = None):
        self.settings = s = settings
        self.af = af = s.airframe
        self.period_s = s.control_period_s
        self.nmpc = nmpc or Nmpc(af, s.nmpc)
        propeller = PropellerModel.from_airframe(af)
        codegen = s.nmpc.codegen              # every model evaluated each step: compiled, or none of them
        self._new_detector = new_detector or (
            lambda: FaultDetector(af, self.settings.fault_detector, propeller, codegen))
        self.mission = s.mission          # what the next start() (or fly()) plans
        self._new_reference = new_reference or (
            lambda t0_s, start_ned_m: MissionReference(self.mission, start_ned_m, af, s.reference, t0_s=t0_s))
        self.disturbance = DisturbanceEstimator(af, self.period_s, s.disturbance_gain, codegen=codegen)
        self.predictor = Predictor(af, self.nmpc.rom.f, self.period_s, codegen)
        self.rate_feedback = RateFeedbackDesign(af, s.rate_feedback_bandwidth_rad_s, s.shortfall_cover)
        self.detector = self._new_detector()
        self.flight: Flight | None = None
        self.sent = CommandHistory()
        self.applied = AppliedThrust(self.period_s)
        self.ramp = TakeoverRamp(self.period_s)
        self._hip_goal: HipGoal | None = None
        self._solved: tuple[float, float, np.ndarray, np.ndarray, bool] | None = None   # (time_s, lead_s, bound, d, confirmed)
        self._last_step_s: float | None = None
        self._takeover = True             # the next step takes control from the FC's own controller
        self._deferred: tuple | None = None   # a frame for the detector after the send: update()'s arguments
        self._unrecorded: tuple | None = None  # the last step's command and hip goal, kept once the setpoint has left
        self._cap_limit_n = (math.nan, np.full(ROTOR_COUNT, math.nan))   # the detector's limits array, by its cap

    @property
    def started(self) -> bool:
        return self.flight is not None

    @property
    def frame_unread(self) -> bool:
        """The last step's frame is left for the detector after the send: read_deferred() reads it
        and returns the status after it."""
        return self._deferred is not None

    def start(self, time_s: float, x_measured, kept: MissionProgress | None = None) -> bool:
        """The flight begins at time_s: the mission is anchored at this measured state, or, with
        `kept` (what an earlier run of the companion flew), goes on where that left it. False
        (nothing changes) when the state is not plausible."""
        x = np.asarray(x_measured, dtype=float).reshape(rom.NX)
        if not plausible_state(self.af, x):
            return False
        if kept is None:                 # the mission's clock starts here, whatever the FC's reads (ArduPilot's: since boot)
            reference = self._new_reference(0.0, x[rom.P])
        else:
            reference = self._new_reference(kept.plan.start_time_s, kept.plan.start_ned_m)
            reference.restore(kept.plan)
        ground_z = reference.ground_com_z_ned_m
        self.flight = Flight(reference, TouchdownDetector(ground_z, self.settings.touchdown),
                             UpsetDetector(ground_z, self.settings.upset),
                             paused_s=time_s if kept is None else time_s - kept.time_s)
        return True

    def fly(self, mission: Mission, time_s: float, x_measured) -> None:
        """From time_s the flight flies `mission` (one from the flight controller), anchored where
        the centre of mass is; before the flight starts, start() anchors it. The detector, the
        touchdown and upset watches go on."""
        self.mission = mission
        if self.flight is not None:
            start_ned_m = np.asarray(x_measured, dtype=float).reshape(rom.NX)[rom.P]
            self.flight.reference = self._new_reference(self.flight.mission_time_s(time_s), start_ned_m)

    def mission_item(self, time_s: float) -> int | None:
        """The mission's item flown at time_s (m4.mission_plan.MissionPlan.item; None before the
        flight started)."""
        if self.flight is None:
            return None
        return self.flight.reference.item(self.flight.mission_time_s(time_s))

    def mission_progress(self, time_s: float) -> MissionProgress | None:
        """The mission at time_s, for the FC to keep (None before the flight started)."""
        if self.flight is None:
            return None
        return MissionProgress(self.flight.mission_time_s(time_s), self.flight.reference.progress)

    def resume(self) -> None:
        """After a gap in the telemetry (link loss): the previous plan, state and hip goal are
        stale. The disturbance estimate is kept (it describes the robot, not the moment)."""
        self.read_deferred()
        self.nmpc.reset()
        self._unrecorded = None
        self.sent.clear()
        self.applied.clear()
        self._hip_goal = None
        self._solved = None

    def restart(self) -> None:
        """The flight controller rebooted: its clock, and so the mission's time, starts over.
        Everything about the flight so far is forgotten but the NMPC itself; start() again."""
        self.resume()
        self.disturbance.reset()
        self.detector = self._new_detector()
        self._deferred = None
        self.flight = None
        self._last_step_s = None
        self._takeover = True

    def retune_detector(self, config: FaultDetectorConfig) -> None:
        """The detector's thresholds changed in flight (a parameter): from its next frame on, and
        for a detector built anew after an FC reboot."""
        self.read_deferred()               # a frame before the change is read by the thresholds it came under
        self.settings = replace(self.settings, fault_detector=config)
        self.detector.retune(config)

    def restore_fault(self, rotor: int, thrust_max_estimate_n: float, detected_at_s: float) -> None:
        """A fault confirmed by an earlier run of the companion (the FC kept it): the detector
        starts from it; the next step confirms it (bound, reference hold, announcement)."""
        self.read_deferred()
        self.detector.restore(rotor, thrust_max_estimate_n, detected_at_s)

    def step(self, time_s: float, x_measured, esc: EscSample | None = None, thrust_limit_n=None,
             lead_s: float | None = 0.0, thrust_cmd_n=None, fc_landing: bool = False,
             fc_mode: FcMode = FcMode.COMPANION) -> ControlStep:
        """The setpoint answering the telemetry instant time_s for the measured ROM state, to act
        lead_s later; thrust_cmd_n is what the FC reports it commands at time_s (None: it does
        not say); fc_landing: the FC says its failsafe is landing (its mode in force); fc_mode:
        the mode selected at the FC, which says what to fly. A lead not measured
        yet (None, or not finite) is planned as 0, and the disturbance estimate waits for it
        (_estimate_disturbance)."""
        af = self.af
        self.read_deferred()               # the last frame first, had nobody read it after the send
        self._record()
        self._note_gap(time_s)
        lead_known = lead_s is not None and math.isfinite(lead_s)
        lead_s = max(float(lead_s), 0.0) if lead_known else 0.0
        x = np.asarray(x_measured, dtype=float).reshape(rom.NX)
        self.applied.report(time_s, self._thrust_telemetry(thrust_cmd_n))
        usable = plausible_state(af, x)
        if usable:
            x = self._with_hip_goal(x)
        in_force, in_force_thrust_n = self._in_force_last_period(time_s, lead_s)
        fault, confirmed_now = self._detect(time_s, x, usable, in_force_thrust_n, esc,
                                            self._thrust_telemetry(thrust_limit_n))
        if confirmed_now:
            self.disturbance.reset()      # it held the lost rotor's effect, which the bound now models
            self.flight.reference.fault_detected(self.flight.mission_time_s(time_s), x[rom.P])
        d = self._estimate_disturbance(time_s, x, usable and lead_known, in_force, in_force_thrust_n,
                                       fault.thrust_bound_n, lead_s)
        if self.flight is None or not usable:
            return self._fallback(time_s, x, fault, confirmed_now, d)
        took_over = self._takeover
        if took_over:
            self._take_over(time_s, x, thrust_cmd_n, fc_landing)
        followed = self._follow(time_s, x, fc_mode)
        upset, crashed_before = self.flight.upset, self.flight.upset.crash is not None
        landing = self.flight.reference.landing_started(self.flight.mission_time_s(time_s))
        if upset.update(time_s, x, landing) is not None:
            return self._cut(time_s, x, fault, confirmed_now, d, upset.crash, crash_now=not crashed_before)
        if self._touched_down(time_s, x):
            return self._cut(time_s, x, fault, confirmed_now, d)
        c = self.nmpc.config
        x_plan = self.predictor.predict(x, time_s, lead_s, self.sent, d, fault.thrust_bound_n)
        x_ref = self._reference(time_s, lead_s, c.horizon, c.dt_s)
        res = self.nmpc.solve(x_plan, x_ref, fault.thrust_bound_n, d)
        hip_accel_rad_s2 = res.u[rom.HIP_ACCEL].tolist()
        x_next = res.x_pred[1] if res.ok else x_plan          # a failed solve plans no change of the rates
        confirmed = fault.state is FaultState.CONFIRMED
        sp = self._setpoint(x_plan, res.u[rom.THRUST], hip_accel_rad_s2, fault.thrust_bound_n,
                            self.rate_feedback.feedback(x_plan, x_next, c.dt_s, fault.thrust_bound_n),
                            self.rate_feedback.cover(x_plan[rom.HIP], confirmed))
        if self.ramp.active:
            sp = replace(sp, thrust_n=self.ramp.limit(sp.thrust_n, fault.thrust_bound_n))
        self._unrecorded = (time_s, x, x_plan, sp, hip_accel_rad_s2)
        self._solved = (time_s, lead_s, fault.thrust_bound_n, d, confirmed)
        return ControlStep(time_s=time_s, setpoint=sp, state=x_plan, fault=fault, fault_confirmed_now=confirmed_now,
                           disturbance=d, lead_s=lead_s, reference=x_ref, nmpc=res, took_over=took_over,
                           followed=followed)

    def prepare(self) -> None:
        """After the last step's setpoint was sent (and its frame read, `read_deferred`): the NMPC
        prepares the next step's solve (the real-time iteration's preparation; nothing with the
        SQP, or when the last step solved nothing: what was prepared before is dropped), and the
        FC's rate feedback and cover are designed for the hip goal the next step starts from.
        The next step is expected one period on, at the same lead, with the same bounds."""
        self._record()
        solved, self._solved = self._solved, None
        if solved is None or self.flight is None:
            self.nmpc.unprepare()
            return
        time_s, lead_s, thrust_bound_n, d, confirmed = solved
        if self._hip_goal is not None:
            self.rate_feedback.prepare(self._hip_goal.angle_rad, thrust_bound_n, confirmed)
        c = self.nmpc.config
        x_ref = self._reference(time_s + self.period_s, lead_s, c.horizon, c.dt_s)
        self.nmpc.prepare(x_ref, thrust_bound_n, d)

    # ------------------------------------------------------------------------------------------
    def _note_gap(self, time_s: float) -> None:
        """A gap since the last step long enough for our setpoints to go stale at the FC: its
        failsafe flew meanwhile, so the mission's clock stood still and this step takes over."""
        last, period = self._last_step_s, self.period_s
        self._last_step_s = time_s
        if last is not None and time_s - last > max(FC_STALE_PERIODS * period, FC_STALE_MIN_S):
            self._takeover = True
            if self.flight is not None and self.flight.hold is None:      # a hold stops the clock already
                self.flight.paused_s += time_s - last - period

    def _take_over(self, time_s: float, x: np.ndarray, thrust_cmd_n, fc_landing: bool) -> None:
        """Thrusts ramp from the FC's own; a landing FC is joined, not cancelled."""
        self._takeover = False
        self.ramp.begin(self._thrust_telemetry(thrust_cmd_n))
        if fc_landing:
            self.flight.reference.land_from(self.flight.mission_time_s(time_s), x[rom.P])

    def _follow(self, time_s: float, x: np.ndarray, mode: FcMode) -> FcMode | None:
        """Follow the FC's selected mode; the mode when it changed at this step, else None."""
        f = self.flight
        if mode is f.mode:
            return None
        if f.hold is not None:                  # the hold ends: the mission's clock goes on
            f.paused_s += time_s - f.hold_since_s
            f.hold = None
        if mode is FcMode.HOLD:
            f.hold = stopping(time_s, x[rom.P], x[rom.V], self.settings.reference.accel_max_m_s2).state
            f.hold_since_s = time_s
        elif mode is FcMode.LAND:
            f.reference.land_from(f.mission_time_s(time_s), x[rom.P])
        f.mode = mode
        return mode

    def _reference(self, time_s: float, lead_s: float, horizon: int, dt_s: float) -> np.ndarray:
        """The NMPC's reference rows from lead_s after the FC's instant time_s: the hold's, or
        the mission's."""
        f = self.flight
        if f.hold is not None:
            return reference_rows(f.hold, self.af, time_s + lead_s, horizon, dt_s)
        return f.reference.reference(f.mission_time_s(time_s) + lead_s, horizon, dt_s)

    def _thrust_telemetry(self, thrust_n) -> list[float] | None:
        """Per-rotor thrusts from the FC with what cannot be a thrust (non-finite, negative,
        beyond twice the airframe's maximum) as NaN: unknown."""
        if thrust_n is None:
            return None
        t = np.asarray(thrust_n, dtype=float).reshape(ROTOR_COUNT).tolist()    # four floats: cheaper than numpy's calls
        most = 2.0 * self.af.thrust_max_n
        if all(0.0 <= v <= most for v in t):
            return t
        return [v if 0.0 <= v <= most else math.nan for v in t]      # false for NaN and inf

    def _consecutive(self, time_s: float) -> bool:
        newest = self.sent.newest
        if newest is None:
            return False
        return one_period_apart(newest.time_s, time_s, self.period_s)

    def _in_force_last_period(self, time_s: float, lead_s: float) -> tuple[SentCommand | None, np.ndarray | None]:
        """The command the FC flew over the period that ends at time_s (None: none of ours) and
        its thrusts: as the FC reports them when it does (companion.core.applied_thrust), else
        ours; the hips are as we planned them."""
        ours = self.sent.in_force(time_s - 0.5 * self.period_s, lead_s)
        if ours is None:
            return None, None
        reported = self.applied.over_period(time_s, lead_s)
        return ours, ours.thrust_n if reported is None else reported

    def _detect(self, time_s, x, usable, in_force_thrust_n, esc, limit_n) -> tuple[FaultStatus, bool]:
        """The detector's status after this frame (before it, for a frame left for after the send);
        True at each new confirmation in a flight."""
        if not usable or in_force_thrust_n is None:
            return self.detector.status, False
        if self._on_ground_in_landing(time_s, x):
            self.detector.hold()
            return self.detector.status, False
        cap = self.af.thrust_max_n
        known = [] if limit_n is None else [v for v in limit_n if v == v]    # from _thrust_telemetry: NaN or finite
        if known:
            cap = min(max(max(known), self.af.thrust_min_n), self.af.thrust_max_n)
        if cap != self._cap_limit_n[0]:
            self._cap_limit_n = (cap, np.full(ROTOR_COUNT, cap))
        frame = (time_s, x, in_force_thrust_n, self._cap_limit_n[1], esc)
        if self.detector.cannot_confirm(time_s, frame[3]):
            self._deferred = frame
            return self.detector.status, False
        return self._detected(self.detector.update(*frame))

    def read_deferred(self) -> FaultStatus | None:
        """The frame the last step left for after the send, read now: the detector's status after
        it (None: none was left)."""
        frame, self._deferred = self._deferred, None
        if frame is None:
            return None
        status, _ = self._detected(self.detector.update(*frame))    # it cannot confirm (cannot_confirm)
        return status

    def _detected(self, status: FaultStatus) -> tuple[FaultStatus, bool]:
        """The detector's new status, and True at each new confirmation in a flight."""
        flight = self.flight
        if flight is not None and status.state is FaultState.HEALTHY:
            flight.fault_announced = False    # recovered: the next confirmation is a new fault
        confirmed_now = status.state is FaultState.CONFIRMED and flight is not None and not flight.fault_announced
        if confirmed_now:
            flight.fault_announced = True
        return status, confirmed_now

    def _estimate_disturbance(self, time_s, x, usable, in_force, in_force_thrust_n, thrust_bound_n,
                              lead_s) -> np.ndarray:
        """Updated over the last period with our command within the current bounds. A rotor lost
        but not yet confirmed shows up here as a disturbance within a few periods, so the NMPC
        compensates it before the detector confirms it (measured on the SITL at 50 Hz: altitude
        loss 0.14 m against 0.43 m when the update used the FC's delivered thrust, which hides
        the loss); at confirmation the estimate restarts, the bound taking over. Its gain is
        scaled by period / (period + lead_s): behind a link delay the estimate moves slower
        (companion.core.disturbance). Until the link has measured the lead the estimate does not
        move (the caller passes usable False): it would move at the full gain of a link without
        delay, and one update on a noisy state then puts newtons of phantom force into the plan
        (measured on propeller-loss at 50 ms each way: 12 N at the first consecutive frame, a
        wobble of 6 deg and 0.13 m that the fault at 1 s met half-settled)."""
        if not (usable and in_force is not None and self._consecutive(time_s)):
            return self.disturbance.estimate.copy()
        u = in_force.input.copy()                 # its thrusts within the bounds (the bound when equal, as numpy's)
        bound_n = thrust_bound_list(self.af, thrust_bound_n)
        u[rom.THRUST] = [b if t >= b else t for t, b in zip(in_force_thrust_n.tolist(), bound_n, strict=True)]
        return self.disturbance.update(self.sent.newest.state, u, x, gain_scale=self.period_s / (self.period_s + lead_s))

    def _on_ground_in_landing(self, time_s: float, x: np.ndarray) -> bool:
        """Landing with the centre of mass at ground height: the ground may carry the robot (a
        crosswind at touchdown looked like a lost rotor to the fault detector)."""
        flight = self.flight
        return (flight is not None and flight.reference.landing_started(flight.mission_time_s(time_s))
                and flight.touchdown.at_ground_height(float(x[rom.P][2])))

    def _touched_down(self, time_s: float, x: np.ndarray) -> bool:
        if not self.flight.reference.landing_started(self.flight.mission_time_s(time_s)):
            return False
        return self.flight.touchdown.update(time_s, float(x[rom.P][2]), float(x[rom.V][2]))

    def _with_hip_goal(self, x_measured: np.ndarray) -> np.ndarray:
        """The NMPC's state: measured, but the hip goal in place of the measured joints."""
        hip = x_measured[rom.HIP]
        goal = self._hip_goal
        if goal is None or _drifted(goal.angle_rad, hip.tolist()):
            fixed = self.nmpc.config.fixed_hip_rad        # the fixed-posture variant: the legs go there
            start = ([fixed] * ROTOR_COUNT if fixed is not None
                     else hip.clip(self.af.hip_min_rad, self.af.hip_max_rad).tolist())
            goal = self._hip_goal = HipGoal(start, [0.0] * ROTOR_COUNT)
        x = x_measured.copy()
        x[rom.HIP], x[rom.HIP_RATE] = goal.angle_rad, goal.rate_rad_s
        return x

    def _setpoint(self, x: np.ndarray, thrust_n: np.ndarray, hip_accel_rad_s2: list[float], thrust_bound_n,
                  rate_feedback: RateFeedback | None, shortfall_cover: ShortfallCover | None) -> Setpoint:
        """Thrusts now; the hips from the goal now to the planned goal one period later (the FC's
        servo moves its goal from the angle at the rate, so the rate is the chord's); the FC's
        rate feedback and cover with them."""
        tau = self.period_s                               # four hips: Python floats, cheaper than numpy's calls
        hip, rate = x[rom.HIP].tolist(), x[rom.HIP_RATE].tolist()
        chord = [(h + r * tau + 0.5 * a * tau**2 - h) / tau
                 for h, r, a in zip(hip, rate, hip_accel_rad_s2, strict=True)]
        return safe_setpoint(self.af, thrust_n, hip, chord, thrust_bound_n, hip, rate_feedback=rate_feedback,
                             shortfall_cover=shortfall_cover)

    def _record(self) -> None:
        """Once the last step's setpoint has left: its command into the history, and the hip goal
        one period on (where the setpoint's hips lead, at the planned rate) for the next step."""
        if self._unrecorded is None:
            return
        (time_s, x, x_plan, sp, hip_accel_rad_s2), self._unrecorded = self._unrecorded, None
        af, tau = self.af, self.period_s
        rate_max = af.hip_rate_max_rad_s
        next_rate = [min(max(r + a * tau, -rate_max), rate_max)
                     for r, a in zip(x_plan[rom.HIP_RATE].tolist(), hip_accel_rad_s2, strict=True)]
        goal = [min(max(h + r * tau, af.hip_min_rad), af.hip_max_rad)
                for h, r in zip(sp.hip_rad.tolist(), sp.hip_rate_rad_s.tolist(), strict=True)]
        self._hip_goal = HipGoal(goal, [r if math.isfinite(r) else 0.0 for r in next_rate])
        self.sent.add(SentCommand(time_s, x, np.concatenate([sp.thrust_n, hip_accel_rad_s2]), sp.rate_feedback,
                                  sp.shortfall_cover))

    def _cut(self, time_s, x, fault, confirmed_now, d, crash: str | None = None, crash_now: bool = False) -> ControlStep:
        """Thrust cut (after a touchdown, or for good after a crash), the hips held."""
        sp = safe_setpoint(self.af, np.zeros(ROTOR_COUNT), x[rom.HIP], np.zeros(ROTOR_COUNT),
                           fault.thrust_bound_n, x[rom.HIP], thrust_cut=True)
        self.ramp.end()
        self.sent.clear()
        self._hip_goal = None
        self._solved = None
        return ControlStep(time_s=time_s, setpoint=sp, state=x, fault=fault, fault_confirmed_now=confirmed_now,
                           disturbance=d, crash=crash, crash_now=crash_now)

    def _fallback(self, time_s, x, fault, confirmed_now, d) -> ControlStep:
        """No usable state or no flight yet: hover thrust within the bounds, hips held where they
        are, legs stopped."""
        sp = safe_setpoint(self.af, np.full(ROTOR_COUNT, np.nan), x[rom.HIP], np.zeros(ROTOR_COUNT),
                           fault.thrust_bound_n, x[rom.HIP])
        self.sent.clear()
        self._hip_goal = None
        self._solved = None
        return ControlStep(time_s=time_s, setpoint=sp, state=x, fault=fault, fault_confirmed_now=confirmed_now,
                           disturbance=d)
