"""The companion's run loop: telemetry in, NMPC setpoints out, at the control rate.

When to answer (lockstep and real time alike): after draining the link, the newest
M4_THRUSTER_STATUS (the last message of a telemetry frame) is answered when its instant is
at least one control period after the last answered one (the first is always answered). In
lockstep the FC's frames fall on our grid (multiples of period_ms), so every frame is
answered and the FC waits for it; in real time the freshest frame is answered at about our
rate. The setpoint carries that frame's time_boot_ms.

Joining the flight: once the FC is found, nothing goes out but our HEARTBEAT and the requests
until the FC has answered what it kept of an earlier run of the companion (M4_FAULT_STATUS:
a confirmed fault, the mission's progress) and its mode (CURRENT_MODE): a restarted
companion never overwrites the kept fault with a "healthy" of its own, resumes the mission
where it was instead of anchoring it where it finds the robot, and joins the FC's failsafe
landing instead of cancelling it (companion.controller). The newest frame is answered as
soon as the answers are in.

Parameters (companion/params.py, m4/mavlink/param_service.py): requests from a ground station,
routed by the FC, are answered at once; a value set is in force from the next step and kept in
the configuration's params_file.

Stale streams (companion.stream_watch): while a stream the controller needs is stale no
setpoint goes out; it is asked for again and reported (log, STATUSTEXT warning, the feed's
link topic); when it comes back, control resumes.

Telemetry loss: no telemetry for `telemetry_timeout_s` (wall clock) marks the link lost:
no setpoint goes out (none can: no frame), it is logged, sent as STATUSTEXT (warning) and
published. When telemetry returns, control resumes; if the FC's clock moved on by more
than a couple of periods meanwhile, the controller drops its warm start and the stale
previous state first.

The flight's end: the FC's HEARTBEAT with MAV_STATE_POWEROFF (the simulator's end) is said,
and the silence after it is the end of the flight, not a lost link (`end()` says which it was).

Signing (docs/authority.md): with a key, the signing timestamps are kept across restarts
(m4.mavlink.signing.StreamTimestamps: saved on a thread of its own, never on the loop, and
once more at exit), so a restarted companion refuses a captured packet;
without (`[link] signing = false`) it says so at start and, as STATUSTEXT WARNING, at every
lock-on.

The FC's modes (companion.controller): CURRENT_MODE's intended_custom_mode, the mode selected
at the FC (by a ground station), says what to fly: the mission (COMPANION, and any mode we do
not know), a hold or a landing; a change is logged. Its standard_mode LAND (the FC lands,
maybe by its failsafe) makes a takeover join the landing.

A confirmed fault is announced: STATUSTEXT MAV_SEVERITY_CRITICAL "thrust loss rotor N (kind)"
(that severity is used for nothing else), the same text on the feed's fault topic. When
more evidence re-settles the kind (a damaged propeller turns out lost), the new text is
announced once more, at most once per KIND_ANNOUNCE_MIN_S of the FC's clock (the latest
kind when that time has passed).
"""

from __future__ import annotations

import gc
import logging
import time
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from companion.autopilot_profile import PROJECT_FC, profile_of
from companion.config import CompanionConfig
from companion.controller import ControllerSettings, ControlStep, Controller
from companion.core import rom
from companion.core.com_offset import ComOffset
from companion.core.control_types import FaultState
from companion.core.esc_evidence import PropellerModel
from companion.fc_link import FcLink, LinkEvent, mission_progress
from companion.fc_mission import MISSION_MESSAGES, FcMission
from companion.feed_publisher import Feed, open_feed
from companion.loop_timing import LoopTiming
from companion.params import CompanionParams
from companion.flight_log import FlightLog, open_flight_log
from companion.stream_watch import Report, StreamWatch, blocking, labels
from companion.telemetry import (ESC_TELEMETRY, READ, THRUSTER_STATUS, TelemetryAssembler, VehicleSnapshot,
                                 rom_state)
from m4.airframe import ROTOR_COUNT
from m4.fc_mode import FcMode
from m4.mavlink import COMPANION_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.connect import listens_for_peer, open_link
from m4.mavlink.link import wait_readable
from m4.mavlink.param_service import ParamService
from m4.mavlink.signing import StreamTimestamps, load_key
from m4.mission_plan import MissionProgress
from m4.params_file import ParamFile

log = logging.getLogger("m4-companion")

_FOLLOWING = {FcMode.HOLD: "holding where the robot stops", FcMode.LAND: "landing where it is"}
RESUME_GAP_PERIODS = 2            # FC clock moved more than this many periods during a loss: reset
KIND_ANNOUNCE_MIN_S = 1.0         # a re-settled fault kind is announced at most this often


@dataclass
class LoopCounters:
    answered: int = 0             # setpoints sent
    skipped_incomplete: int = 0   # frames without the full picture yet (e.g. no joint state)
    link_losses: int = 0
    skipped_stale: int = 0        # frames not answered: a stream the controller needs is stale
    control_errors: int = 0       # control steps that raised (a defect; the FC's failsafe covers)
    solve_ms_max: float = 0.0


class _RateMark(NamedTuple):
    """Where the link's message rate was last measured from."""
    wall_s: float                 # the clock's reading
    received: int                 # messages from the FC by then


class _Announcement(NamedTuple):
    time_s: float                 # FC time
    text: str


def collect_due() -> None:
    """The garbage collection the interpreter would run at its next allocation, now (called with
    the collector disabled, so that nothing starts one meanwhile): once the young generation's
    count is past its threshold, the oldest generation whose count is. Young alone would leave the
    older ones to an automatic collection that never comes while every poll ends with the young
    count reset. Python does not expose the interpreter's guard that puts a full collection off
    while few objects were promoted since the last: here it runs when due (about every 100 young
    ones); after `m4-companion run`'s gc.freeze it walks only what was made since (0.01 ms, 10 ms
    of a companion not frozen)."""
    counts, thresholds = gc.get_count(), gc.get_threshold()
    if counts[0] > thresholds[0]:
        gc.collect(2 if counts[2] > thresholds[2] else 1 if counts[1] > thresholds[1] else 0)


class CompanionApp:
    def __init__(self, config: CompanionConfig, fc: FcLink, controller: Controller, feed: Feed | None = None,
                 clock=time.monotonic, flight_log: FlightLog | None = None,
                 signing_state: StreamTimestamps | None = None):
        self.config = config
        self.signing_state = signing_state
        self.fc = fc
        self.controller = controller
        self.feed = feed or Feed.disabled()
        self.flight_log = flight_log or FlightLog.disabled()
        self.clock = clock
        self.period_ms = max(1, round(1000.0 * config.control_period_s))
        self.telemetry = TelemetryAssembler()
        self._com_offset = ComOffset(config.airframe)
        self._propeller = PropellerModel.from_airframe(config.airframe)
        self.counters = LoopCounters()
        self._last_answered_ms: int | None = None
        self._stop = False
        self._received = 0                       # messages from the FC, for the link's rate
        self._rate_mark: _RateMark | None = None
        self._msgs_per_s = 0.0
        self._delay_warned = False
        self._announced: _Announcement | None = None         # the last fault announcement
        self.timing = LoopTiming(config.control_period_s)
        self._frame_ms: int | None = None        # the newest frame (its M4_THRUSTER_STATUS) not yet answered
        self._kept_mission: MissionProgress | None = None     # what the FC kept of an earlier run's mission
        self._fc_landing = False                 # the FC's mode in force, as it last said: it lands
        self._fc_mode = FcMode.COMPANION         # the mode selected at the FC: what we fly
        self.streams = StreamWatch(config.control_period_s)
        self.params = ParamService(CompanionParams(config, self._retune).table, *fc.own_ids,
                                   "companion", None if config.params_path is None else ParamFile(config.params_path),
                                   log.info)
        self.profile = PROJECT_FC                # until the FC's HEARTBEAT names its autopilot
        # No mission file: the FC's mission, when it has one (companion.fc_mission).
        self.fc_mission = None if config.mission_path is not None else \
            FcMission(fc, fc.own_ids, config.fc_mission_on_fault)
        if config.mission_path is not None:
            log.info("flying the mission file %s (it takes precedence over the flight controller's)",
                     config.mission_path)
        else:
            log.info("no mission file: flying the flight controller's mission when it has one")
        self._new_mission = None                 # a mission from the FC not flown yet
        self.fc_shut_down_s: float | None = None     # FC time at which the FC said it shuts down (its flight's end)

    # -- the loop ----------------------------------------------------------------------------------
    def stop(self) -> None:
        self._stop = True

    def run(self) -> None:
        while not self._stop:
            now = self.clock()
            wait_readable([self.fc.link], min(self.fc.next_due_s(now) - now, 0.1))
            self.poll()

    def poll(self) -> None:
        """Everything that has arrived, what it means, then the answer and the periodic messages.
        No garbage collection runs in it: one due meanwhile runs at its end (`collect_due`), off
        the answer (a young generation's took 0.1-1.3 ms, in the middle of whichever answer it
        fell on), not at the next allocation of a tracked object after it."""
        collecting = gc.isenabled()
        gc.disable()
        try:
            self._poll()
        finally:
            if collecting:
                collect_due()
                gc.enable()

    def _poll(self) -> None:
        now = self.clock()
        since = self.flight_log.position()          # a new flight found in this poll starts with its packets
        received = self.fc.receive(now)
        # before the answer and the poll's pack: a new flight's first packets, read in this poll, go to its own file
        self.flight_log.observe(received.messages, since, LinkEvent.REBOOTED in received.events)
        self._received += len(received.messages)
        messages = self._profiled(received.messages)          # before LOCKED asks for the profile's streams
        for event in received.events:
            self._on_event(event, now)
        for msg in messages:
            msg_id = msg.get_msgId()
            if msg_id in READ:
                if self.telemetry.add(msg, now) and msg_id == THRUSTER_STATUS:
                    self._frame_ms = msg.time_boot_ms
            elif msg_id == mavlink.MAVLINK_MSG_ID_M4_FAULT_STATUS:
                self._on_kept_status(msg)
            elif msg_id == mavlink.MAVLINK_MSG_ID_CURRENT_MODE:
                self._on_mode(msg)
            elif msg_id in MISSION_MESSAGES and self.fc_mission is not None and \
                    (flown := self.fc_mission.on_message(msg, now)) is not None:
                self._new_mission = flown.mission
        for msg in received.param_requests:
            if replies := self.params.handle(msg):
                self.fc.link.send_all(replies)
        self._watch_streams(now)
        if self._frame_ms is not None and self._due(self._frame_ms) and not self._joining(now):
            self._answer(self._frame_ms, now)
        while self.flight_log.notices:             # a gap in the flight log (it has no link of its own)
            self.fc.statustext(mavlink.MAV_SEVERITY_WARNING, self.flight_log.notices.popleft())
        if self.fc_mission is not None and (flown := self.fc_mission.tick(now)) is not None:
            self._new_mission = flown.mission
        self.fc.tick(now)
        self.flight_log.pack()                     # the poll's records made here, after the send: not by the writer

    def _retune(self, config: CompanionConfig) -> None:
        """A parameter was set (companion/params.py): the settable ones are read from here each step,
        and the detector's thresholds from its own copy."""
        self.config = config
        self.controller.retune_detector(config.fault_detector)

    def _profiled(self, messages: list) -> list:
        """The messages as the profile of the FC's autopilot has them read, after its HEARTBEATs
        (the one place they are handled: they may change the profile)."""
        for msg in messages:
            if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                self._on_fc_heartbeat(msg)
        return self.profile.translate(messages)

    def _joining(self, now: float) -> bool:
        """Still waiting for what the FC kept, or for its mission (the first download)?"""
        return self.fc.kept_state_pending() or (self.fc_mission is not None and self.fc_mission.pending(now))

    def _on_mode(self, msg) -> None:
        """The FC's CURRENT_MODE: is it landing, and which mode is selected (another FC's mode,
        or one we do not know: our mission)."""
        self._fc_landing = msg.standard_mode == mavlink.MAV_STANDARD_MODE_LAND
        mode = FcMode.of(msg.intended_custom_mode)
        self._fc_mode = FcMode.COMPANION if mode is None else mode

    def _on_kept_status(self, msg) -> None:
        """The FC's copy of the last M4_FAULT_STATUS it had from us (from before this process
        started, when we asked at lock-on): a confirmed fault becomes the detector's, the
        mission's progress where the flight starts from."""
        if not self.controller.started:
            self._kept_mission = mission_progress(msg)
        rotor = msg.rotor
        if msg.state != FaultState.CONFIRMED or not 1 <= rotor <= ROTOR_COUNT or \
                self.controller.detector.status.state is FaultState.CONFIRMED:
            return
        ceiling_n, detected_s = float(msg.thrust_max_estimate_n[rotor - 1]), msg.detected_time_boot_ms / 1000.0
        self.controller.restore_fault(rotor, ceiling_n, detected_s)
        log.warning("fault kept by the flight controller: rotor %d confirmed at t=%.3f s, ceiling %.1f N; the "
                    "detector starts from it", rotor, detected_s, ceiling_n)

    def _on_event(self, event: LinkEvent, now: float) -> None:
        if event is LinkEvent.LOCKED:
            if self.fc.previous_address is None:
                log.info("flight controller found at %s; asking for telemetry every %d ms", self.fc.fc_address,
                         self.period_ms)
            else:
                log.warning("flight controller found again at %s (it was at %s); asking for telemetry every %d ms",
                            self.fc.fc_address, self.fc.previous_address, self.period_ms)
            self.fc.request_kept_state()               # first: nothing of ours goes out before it is answered
            self._ask_for_streams()
            if self.fc_mission is not None:
                self.fc_mission.on_locked(now)
            if not self.config.link.signing:
                self.fc.statustext(mavlink.MAV_SEVERITY_WARNING, "companion: MAVLink signing OFF")
        elif event is LinkEvent.REBOOTED:
            log.warning("the flight controller's clock went back after a silence: it rebooted; the mission "
                        "starts over")
            self.telemetry.clear()
            self._last_answered_ms = self._frame_ms = self._kept_mission = None
            self.controller.restart()
        elif event is LinkEvent.TELEMETRY:
            self._on_telemetry_back()
        else:
            self._on_lost()

    # -- answering ---------------------------------------------------------------------------------
    def _due(self, t_ms: int) -> bool:
        last = self._last_answered_ms
        return last is None or t_ms - last >= self.period_ms

    def _answer(self, t_ms: int, read_s: float) -> None:
        """Answer the frame at FC instant t_ms, read at read_s (our clock)."""
        self._frame_ms = None
        snap = self.telemetry.snapshot()
        if snap is None:
            self.counters.skipped_incomplete += 1
            return
        if blocking(self.streams.stale):
            self.counters.skipped_stale += 1
            return
        t_s, x = t_ms / 1000.0, rom_state(snap, self._com_offset)
        esc = None if ESC_TELEMETRY in self.streams.stale else snap.esc
        try:
            if self._new_mission is not None:
                self.controller.fly(self._new_mission, t_s, x)
                self._new_mission = None
            if not self.controller.started and self.controller.start(t_s, x, self._kept_mission):
                self._say_started(t_s, x)
            step = self.controller.step(t_s, x, esc, snap.thrust_limit_n, lead_s=self.fc.delay.lead_s,
                                        thrust_cmd_n=self._frame_thrust_cmd(snap, t_ms), fc_landing=self._fc_landing,
                                        fc_mode=self._fc_mode)
        except Exception:           # a defect, not bad input: say it, send nothing, let the FC's failsafe fly
            self.counters.control_errors += 1
            log.exception("control step at t=%.3f s failed; no setpoint for this instant", t_ms / 1000.0)
            self.controller.resume()
            return
        sent_s = self.clock()
        status_later = self.controller.frame_unread      # the detector reads the frame after the send
        self.fc.send_setpoint(t_ms, self.period_ms, step.setpoint, sent_s, None if status_later else step.fault,
                              self.controller.mission_progress(t_s))
        self.timing.answered(read_s, sent_s)
        try:
            if (fault := self.controller.read_deferred()) is not None:
                self.fc.send_fault_status(t_ms, fault, self.controller.mission_progress(t_s))   # the frame's own status
                step = replace(step, fault=fault)
            self.controller.prepare()                           # the NMPC's next QP, off the critical path
        except Exception:           # a defect, not bad input: say it; the next step starts the NMPC afresh
            self.counters.control_errors += 1
            log.exception("after the setpoint at t=%.3f s: the detector or the NMPC's preparation failed", t_ms / 1000.0)
            self.controller.resume()
        if (report := self.timing.report(sent_s)) is not None:
            log.warning("t=%.3f s: %s", t_s, report.text)
            self.fc.statustext(mavlink.MAV_SEVERITY_WARNING, report.statustext)
        self.flight_log.decision(t_ms, step, sent_s - read_s)
        if self.fc_mission is not None and (item := self.controller.mission_item(t_s)) is not None:
            self.fc_mission.report(item)
        self._last_answered_ms = t_ms
        self.counters.answered += 1
        if step.nmpc is not None:
            self.counters.solve_ms_max = max(self.counters.solve_ms_max, step.nmpc.solve_ms)
        if step.fault_confirmed_now or self._kind_resettled(step):
            self._announce_fault(step)
        if step.followed is not None:
            log.info("t=%.3f s: the flight controller's mode is %s: %s", t_s, step.followed.name,
                     _FOLLOWING.get(step.followed, "flying the mission"))
        if step.took_over:
            log.info("t=%.3f s: control taken from the flight controller's own%s", t_s,
                     ": it was landing, the companion lands" if self._fc_landing else "")
        if step.crash_now:
            log.error("t=%.3f s: crash recognised (%s): thrust cut for good; no re-arm will be sent", t_s, step.crash)
            self.fc.statustext(mavlink.MAV_SEVERITY_EMERGENCY, f"companion: crash ({step.crash}), thrust cut")
        self._watch_delay(t_s)
        self._publish(step, snap, x)

    def _say_started(self, t_s: float, x: np.ndarray) -> None:
        kept = self._kept_mission
        if kept is None:
            log.info("t=%.3f s: mission anchored at the centre of mass (%.2f, %.2f, %.2f) m NED", t_s, *x[rom.P])
            return
        plan = kept.plan
        log.warning("t=%.3f s: mission resumed as the flight controller kept it: at %.3f s of its clock (%s), "
                    "started at (%.2f, %.2f, %.2f) m NED; the robot is at (%.2f, %.2f, %.2f)", t_s, kept.time_s,
                    plan.state.name.lower(), *plan.start_ned_m, *x[rom.P])

    @staticmethod
    def _frame_thrust_cmd(snap: VehicleSnapshot, t_ms: int) -> np.ndarray | None:
        """What the FC reports it commands at the frame's instant (None: no report of that instant)."""
        return snap.thrust_cmd_n if snap.times_ms.get(THRUSTER_STATUS) == t_ms else None

    def _esc_thrust_n(self, snap: VehicleSnapshot) -> np.ndarray:
        """The thrust each ESC's reported speed implies (NaN without ESC telemetry): for the feed."""
        if snap.esc is None:
            return np.full(ROTOR_COUNT, np.nan)
        return self._propeller.thrust_n(snap.esc.rpm)

    def _kind_resettled(self, step: ControlStep) -> bool:
        """The announced fault's text changed (its kind: the same rotor stays confirmed) and the
        last announcement is KIND_ANNOUNCE_MIN_S old."""
        if step.fault.state is not FaultState.CONFIRMED or self._announced is None:
            return False
        last = self._announced
        return step.fault.message != last.text and step.time_s - last.time_s >= KIND_ANNOUNCE_MIN_S - 1e-9

    def _announce_fault(self, step: ControlStep) -> None:
        text = step.fault.message
        self._announced = _Announcement(step.time_s, text)
        self.fc.statustext(mavlink.MAV_SEVERITY_CRITICAL, text)
        bounds = ", ".join(f"{b:.1f}" for b in step.fault.thrust_max_estimate_n)
        log.error("t=%.3f s: %s (thrust bounds now %s N)", step.time_s, text, bounds)

    def _watch_delay(self, t_s: float) -> None:
        """Say (log, STATUSTEXT warning) when the setpoints' lead passes the threshold, and when
        it is back below 80 % of it."""
        lead, threshold = self.fc.delay.lead_s, self.config.link.delay_warning_s
        if lead is None or self._delay_warned == (lead > (0.8 if self._delay_warned else 1.0) * threshold):
            return
        self._delay_warned = not self._delay_warned
        rtt = self.fc.delay.round_trip_s
        if self._delay_warned:
            log.warning("t=%.3f s: setpoints reach the FC %.0f ms after the instant they answer (round trip %.0f "
                        "ms), above %.0f ms; the controller predicts through it", t_s, 1e3 * lead, 1e3 * rtt,
                        1e3 * threshold)
            self.fc.statustext(mavlink.MAV_SEVERITY_WARNING, f"companion: link delay {1e3 * lead:.0f} ms")
        else:
            log.info("t=%.3f s: setpoint lead back to %.0f ms (round trip %.0f ms)", t_s, 1e3 * lead, 1e3 * rtt)
            self.fc.statustext(mavlink.MAV_SEVERITY_NOTICE, f"companion: link delay back to {1e3 * lead:.0f} ms")

    def _publish(self, step: ControlStep, snap: VehicleSnapshot, x) -> None:
        """The feed, after the send: each topic's fields are gathered only when it will go out."""
        t, f, sp, feed = step.time_s, step.fault, step.setpoint, self.feed
        if feed.wants("state"):
            feed.state(t, pos_ned_m=x[rom.P], vel_ned_m_s=x[rom.V], euler_rad=x[rom.EULER],
                       rates_frd_rad_s=x[rom.RATES], hip_rad=snap.hip_rad, thrust_n=self._esc_thrust_n(snap))
        if feed.wants("setpoint"):
            feed.setpoint(t, thrust_n=sp.thrust_n, hip_rad=sp.hip_rad, hip_rate_rad_s=sp.hip_rate_rad_s,
                          thrust_cut=sp.thrust_cut)
        feed.fault(t, state=int(f.state), rotor=f.rotor, thrust_max_estimate_n=f.thrust_max_estimate_n,
                   message=f.message, detected_at_s=f.detected_at_s)
        if step.nmpc is not None and feed.wants("nmpc"):
            r = step.nmpc
            feed.nmpc(t, solve_ms=r.solve_ms, iterations=r.iterations, status=r.status, cost=r.cost, ok=r.ok,
                      fallback=r.fallback, altitude_first=r.altitude_first, dt_s=self.config.nmpc.dt_s,
                      predicted_p_ned_m=r.x_pred[:, rom.P], lead_s=step.lead_s,
                      overruns=self.timing.overruns, rate_hz=self.timing.rate_hz(self.clock()),
                      disturbance_force_ned_n=step.disturbance[:3], disturbance_torque_frd_n_m=step.disturbance[3:])
        self._publish_link(t)

    def _publish_link(self, t_s: float | None) -> None:
        if not self.feed.wants("link"):
            return
        h, now = self.fc.health(), self.clock()
        last = self.telemetry.last_received_s()
        mark = self._rate_mark
        if mark is None or now - mark.wall_s >= 1.0:
            if mark is not None:
                self._msgs_per_s = (self._received - mark.received) / (now - mark.wall_s)
            self._rate_mark = _RateMark(now, self._received)
        self.feed.link(t_s, connected=self.fc.connected, last_msg_age_s=None if last is None else now - last,
                       msgs_per_s=self._msgs_per_s, bad_crc=h.bad_crc, bad_signature=h.bad_signature,
                       dropped_foreign=h.foreign, setpoint_lead_s=self.fc.delay.lead_s,
                       round_trip_s=self.fc.delay.round_trip_s, control_rate_hz=self.timing.rate_hz(now),
                       overruns=self.timing.overruns, flight_log_paused=self.flight_log.paused,
                       flight_log_gaps=self.flight_log.gaps, stale_streams=labels(self.streams.stale))

    # -- stale streams -----------------------------------------------------------------------------
    def _watch_streams(self, now: float) -> None:
        news = self.streams.update(self.telemetry.stale(self.streams.limit_s), now, self.fc.fc_time_ms)
        if ask := self.profile.asked_again(news.ask):
            self.fc.request_intervals(self.config.control_period_s, ask)
        if news.resumed:
            self._resume_after_gap()
        if news.report is not None:
            self._report_streams(news.report)

    def _report_streams(self, report: Report) -> None:
        t_s, names = report.since_ms / 1000.0, "+".join(labels(report.now))
        if not report.now:
            log.info("t=%.3f s: %s fresh again", t_s, "+".join(labels(report.was)))
            self.fc.statustext(mavlink.MAV_SEVERITY_NOTICE, "companion: telemetry fresh again")
        elif not blocking(report.now):
            log.warning("t=%.3f s: ESC telemetry stale: asked for again; the detector goes on without it", t_s)
            self.fc.statustext(mavlink.MAV_SEVERITY_WARNING, "companion: stale ESC, flying without it")
        else:
            log.warning("t=%.3f s: %s stale (nothing for %.0f ms while the other streams came): asked for again; "
                        "no setpoints until it is back (the flight controller flies)", t_s, names,
                        1000.0 * self.streams.limit_s)
            self.fc.statustext(mavlink.MAV_SEVERITY_WARNING, f"companion: stale {names}: no setpoints")
        self._publish_link(self.fc.fc_time_ms / 1000.0)

    # -- link loss ---------------------------------------------------------------------------------
    def _on_telemetry_back(self) -> None:
        t_ms = self.fc.fc_time_ms
        if self._last_answered_ms is None:
            log.info("telemetry flowing (t=%.3f s)", t_ms / 1000.0)
            return
        log.warning("telemetry back after the FC's clock moved %d ms; control resumes", t_ms - self._last_answered_ms)
        self._resume_after_gap()
        self.fc.statustext(mavlink.MAV_SEVERITY_NOTICE, "companion: telemetry back, control resumes")
        self._ask_for_streams()
        self._publish_link(t_ms / 1000.0)

    def _resume_after_gap(self) -> None:
        """Control resumes; after more than RESUME_GAP_PERIODS the controller drops its warm start."""
        if self._last_answered_ms is not None and \
                self.fc.fc_time_ms - self._last_answered_ms > RESUME_GAP_PERIODS * self.period_ms:
            self.controller.resume()

    def _ask_for_streams(self) -> None:
        """The profile's streams at the control rate, then its stops (each command acknowledged):
        at lock-on, at the profile's change and when telemetry comes back (a rebooted FC streams
        its defaults again)."""
        self.fc.request_intervals(self.config.control_period_s, self.profile.streams)
        self.fc.stop_streams(self.profile.stopped)

    def _on_fc_heartbeat(self, msg) -> None:
        """A HEARTBEAT naming another autopilot changes the profile and the streams asked for; the
        FC saying it shuts down (MAV_STATE_POWEROFF) makes the silence that follows the flight's end."""
        if (profile := profile_of(msg)) != self.profile:
            self.profile = profile
            log.info("the flight controller runs %s: asking for its streams every %d ms", profile.name,
                     self.period_ms)
            self._ask_for_streams()
        if msg.system_status != mavlink.MAV_STATE_POWEROFF:
            self.fc_shut_down_s = None
        elif self.fc_shut_down_s is None:
            self.fc_shut_down_s = (self.fc.fc_time_ms or 0) / 1000.0
            log.info("t=%.3f s: the flight controller shuts down (HEARTBEAT MAV_STATE_POWEROFF): the flight is over",
                     self.fc_shut_down_s)

    def end(self) -> str:
        """How the flight stands as the companion stops: its normal end, a lost link, or neither."""
        if self.fc_shut_down_s is not None:
            return f"the flight ended: the flight controller shut down at t={self.fc_shut_down_s:.3f} s"
        if self.fc.fc_time_ms is None:
            return "no flight: the flight controller never sent telemetry"
        if not self.fc.connected:
            return f"telemetry lost at t={self.fc.fc_time_ms / 1000.0:.3f} s and not back"
        return f"stopped in flight at t={self.fc.fc_time_ms / 1000.0:.3f} s, the flight controller still sending"

    def _on_lost(self) -> None:
        if self.fc_shut_down_s is not None:
            log.info("telemetry ended after the flight controller's shutdown: the end of the flight, not a lost link")
            self._publish_link(self.fc_shut_down_s)
            return
        self.counters.link_losses += 1
        last_s = None if self._last_answered_ms is None else self._last_answered_ms / 1000.0
        log.warning("no telemetry for %.2f s: link lost, setpoints stopped", self.fc.telemetry_timeout_s)
        self.fc.statustext(mavlink.MAV_SEVERITY_WARNING, "companion: telemetry lost, setpoints stopped")
        self._publish_link(last_s)


def open_app(config: CompanionConfig) -> CompanionApp:
    """The app with its link open, its feed open or trying to be, and its NMPC built (compiled on
    a first start). A bad URL, a port in use, signing on without a key, or a bad key/feed setting
    raises LinkError/ConfigError."""
    signing = config.link.signing_files()
    key = load_key(signing[0]) if signing is not None else None
    if signing is None:
        log.warning("MAVLink signing is OFF ([link] signing = false): anyone on the link can command the flight "
                    "controller as this companion and feed it telemetry")
    link = open_link(config.link.fc_url, FC_SYSTEM_ID, COMPANION_COMPONENT_ID, key=key)
    feed = None
    try:
        signing_state = StreamTimestamps([link.mav], signing[1]).keep_saving() if signing is not None else None
        feed = open_feed(config.feed)
        controller = Controller(ControllerSettings.of(config))
    except BaseException:
        link.close()
        if feed is not None:
            feed.close()
        raise
    link.tlog = flight_log = open_flight_log(config.log)      # every packet both ways, from here on
    fc = FcLink(link, config.link.fc_system_id, config.link.fc_component_id,
                heartbeat_before_lock=not listens_for_peer(config.link.fc_url),
                telemetry_timeout_s=config.link.telemetry_timeout_s)
    return CompanionApp(config, fc, controller, feed, flight_log=flight_log, signing_state=signing_state)


def close_app(app: CompanionApp) -> None:
    if app.signing_state is not None:
        app.signing_state.close()
    app.fc.link.close()
    app.feed.close()
    app.flight_log.close()
