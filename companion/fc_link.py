"""The companion's side of the MAVLink link to its flight controller (system 1, component 191).

- Lock-on: only the flight controller's system and component are heard (others are dropped
  and counted as foreign); the first address that sends a message with the FC's ids (signed,
  when a signing key is set: the FC signs everything) is the FC, and from then on a udpin
  link hears and answers only that address (a stray sender, even with the FC's ids, can
  neither feed us nor redirect our replies; not even a message read in the same batch as the
  lock-on). Its telemetry is as good a proof as its HEARTBEAT (unsigned, either can be forged;
  signed, neither), and it comes every few ms instead of once a second: a restarted companion
  takes control within a control period or two of hearing the FC. Nothing is sent before,
  except on a link with a fixed peer (udpout, tcp, serial: `heartbeat_before_lock`), where our
  heartbeat is how the FC learns of us.
- Re-acquisition: once the telemetry is LOST, the link hears other addresses again (still
  answering only the FC's) and the next address to prove itself the FC (as above) is locked
  on to: a restarted FC on a new source port is found with its first message (LOCKED again,
  `previous_address` the old one).
- Liveness: telemetry (the frame's streams) that stops for `telemetry_timeout_s` is LOST;
  the first telemetry after that (or ever) is TELEMETRY. When the FC's clock (time_boot_ms)
  goes back after such a silence, the FC REBOOTED: its clock, and the mission's, start over.
  `receive(now_s)` returns these events with the messages; nobody compares state before and
  after a call.
- One datagram per control step: the setpoint, the fault status and, when due, a TIMESYNC
  request (one sendto, one wake-up of the FC).
- Delay: a TIMESYNC request goes with a setpoint in the same datagram (companion.link_delay:
  how late our setpoints act at the FC); the FC's TIMESYNC requests are answered with our clock.
- Heartbeat at 1 Hz as MAV_TYPE_ONBOARD_CONTROLLER.
- Commands (companion.fc_commands: one at a time, each resent until acknowledged): the
  telemetry frame's streams at the control period (MAV_CMD_SET_MESSAGE_INTERVAL; again for a
  stream gone stale); what the FC kept and its mode (MAV_CMD_REQUEST_MESSAGE: M4_FAULT_STATUS,
  CURRENT_MODE), which arrive as messages; `kept_state_pending()` until both are answered.
- Out: M4_SETPOINT, M4_FAULT_STATUS (the detector's status and the mission's progress, which
  the FC keeps for a restarted companion: `mission_progress()` reads it back), STATUSTEXT.
- Parameter requests (PARAM_REQUEST_LIST, _READ, _SET) from anyone (a ground station's,
  routed by the FC), once locked on and arriving from the FC's address (signed, when signing is
  on: the link drops the rest), are handed over apart (`Received.param_requests`).
- Health counters: bad CRC (garbled packets), bad signature (unsigned or badly signed,
  dropped by signing), foreign (other systems, components or addresses), second sender.
- A second sender claiming the FC's ids (m4/mavlink/second_sender.py) is counted and reported
  (log, STATUSTEXT WARNING, rate-limited): a packet signing refused (unsigned, badly signed,
  replayed) or let pass unsigned (HEARTBEAT) though we sign, and, while the telemetry flows,
  one from another address than the FC's.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from companion.core.control_types import FaultStatus
from companion.fc_commands import Command, CommandQueue
from companion.link_delay import LinkDelay
from companion.telemetry import REQUESTED, STREAMS
from m4.mavlink import FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.param_service import PARAM_IDS
from m4.mavlink.second_sender import OTHER_ADDRESS, SecondSender, address_text
from m4.mavlink.signing import SigningCounters, refusal
from m4.mission_plan import MissionProgress, PlanProgress, PlanState
from m4.setpoint import Setpoint

HEARTBEAT_PERIOD_S = 1.0
STATUSTEXT_MAX = 50
DEFAULT_TELEMETRY_TIMEOUT_S = 0.3
# Before its first setpoint a companion asks what the FC kept; the control waits for the
# answer, so a lost request is asked again sooner than other commands (a round trip on a
# 50 ms link is 0.1 s).
KEPT_STATE_RETRY_S = 0.2
KEPT_STATE = (mavlink.MAVLINK_MSG_ID_M4_FAULT_STATUS, mavlink.MAVLINK_MSG_ID_CURRENT_MODE)


class FcTransport(Protocol):
    """Everything FcLink uses of a MAVLink link (m4.mavlink.link.UdpLink,
    m4.mavlink.stream_link.StreamLink, or a test's fake)."""

    @property
    def signing_key(self) -> bytes | None: ...          # None: nothing signed or checked

    @property
    def source_ids(self) -> tuple[int, int]: ...        # (system, component) it sends as: ours

    @property
    def bad_packets(self) -> int: ...                   # garbled or rejected by signing

    @property
    def foreign_datagrams(self) -> int: ...             # from another address than the locked peer

    def receive_from(self) -> list[tuple[Any, list[mavlink.MAVLink_message]]]: ...   # [(sender, msgs)]

    def send(self, msg: mavlink.MAVLink_message) -> None: ...

    def send_all(self, msgs: list[mavlink.MAVLink_message]) -> None: ...   # back to back (one datagram if they fit)

    def lock_peer(self, address: Any, hear_others: bool = False) -> None: ...
    # answer only `address` from now on; hear only it too, unless hear_others

    def signing_counters(self) -> SigningCounters: ...

    on_refused: Any                                     # told of refused packets claiming an identity

    def fileno(self) -> int: ...                        # to wait on; < 0: nothing to wait on

    def close(self) -> None: ...


class LinkEvent(enum.Enum):
    LOCKED = "locked"          # the FC proved itself (its HEARTBEAT, signed when signing is on)
    REBOOTED = "rebooted"      # its clock went back after a silence
    TELEMETRY = "telemetry"    # telemetry flows: the first ever, or back after LOST
    LOST = "lost"              # no telemetry for telemetry_timeout_s


@dataclass(frozen=True)
class Received:
    """What one receive() brought: events in the order given in LinkEvent, then the FC's messages,
    then the parameter requests (from anyone, through the FC)."""

    events: tuple[LinkEvent, ...]
    messages: list[mavlink.MAVLink_message]
    param_requests: list[mavlink.MAVLink_message] = field(default_factory=list)


@dataclass(frozen=True)
class LinkHealth:
    locked: bool
    bad_crc: int
    bad_signature: int
    foreign: int
    commands_acked: int
    commands_pending: int
    second_sender: int          # packets from a second sender claiming the FC's ids


def _floats(values) -> list[float]:
    return np.asarray(values, dtype=float).ravel().tolist()


def _ms(time_s: float) -> int:
    return round(time_s * 1000)


def _fault_status_message(time_ms: int, status: FaultStatus,
                          mission: MissionProgress | None) -> mavlink.MAVLink_m4_fault_status_message:
    detected_ms = 0 if status.detected_at_s is None else _ms(status.detected_at_s)
    estimate = np.asarray(status.thrust_max_estimate_n, dtype=float)
    estimate = np.where(np.isfinite(estimate), estimate, 0.0)
    plan = PlanProgress(PlanState.NONE, 0.0, (0.0, 0.0, 0.0)) if mission is None else mission.plan
    return mavlink.MAVLink_m4_fault_status_message(
        int(time_ms), status.rotor or 0, _floats(estimate), detected_ms, int(status.state), int(status.kind),
        int(plan.state), 0 if mission is None else _ms(mission.time_s), _ms(plan.start_time_s),
        list(plan.start_ned_m), _ms(plan.change_time_s), list(plan.change_ned_m))


def mission_progress(msg: mavlink.MAVLink_m4_fault_status_message) -> MissionProgress | None:
    """The mission progress an M4_FAULT_STATUS carries (None: no plan in it, or not a sane one)."""
    if msg.mission_state not in set(PlanState) or msg.mission_state == PlanState.NONE:
        return None
    start, change = _floats(msg.mission_start_ned_m), _floats(msg.mission_change_ned_m)
    if not np.isfinite(start + change).all():
        return None
    plan = PlanProgress(PlanState(msg.mission_state), msg.mission_start_time_ms / 1000.0, tuple(start),
                        msg.mission_change_time_ms / 1000.0, tuple(change))
    return MissionProgress(msg.mission_time_ms / 1000.0, plan)


_NO_EVENTS: frozenset[LinkEvent] = frozenset()


class FcLink:
    def __init__(self, link: FcTransport, fc_system_id: int = FC_SYSTEM_ID, fc_component_id: int = FC_COMPONENT_ID,
                 heartbeat_before_lock: bool = False, telemetry_timeout_s: float = DEFAULT_TELEMETRY_TIMEOUT_S):
        self.link = link
        self.heartbeat_before_lock = heartbeat_before_lock
        self.telemetry_timeout_s = telemetry_timeout_s
        self.fc_ids = (fc_system_id, fc_component_id)
        self.fc_address = None
        self.previous_address = None                        # the FC's address before a re-acquisition
        self.connected = False                              # telemetry flowing (LinkEvent.TELEMETRY .. LOST)
        self.fc_time_ms: int | None = None                  # the FC's newest telemetry instant
        self.last_telemetry_s: float | None = None          # when it arrived (our clock)
        self._foreign = 0
        self._next_heartbeat_s = 0.0
        self.own_ids = link.source_ids                      # what the FC addresses its answers to
        self.commands = CommandQueue(self.fc_ids, self.own_ids)
        self.delay = LinkDelay()
        self._signing = link.signing_key is not None
        self.second_sender = SecondSender("the flight controller", self.fc_ids, "companion",
                                          logging.getLogger("m4-companion").warning, self._warn_fc)
        link.on_refused = self._refused

    @property
    def locked(self) -> bool:
        return self.fc_address is not None

    # -- in ----------------------------------------------------------------------------------------
    def receive(self, now_s: float) -> Received:
        """The messages from the flight controller that have arrived (the rest is counted), and
        what they, or their absence until now_s, mean."""
        events: set[LinkEvent] = set()
        out, param_requests = [], []
        for sender, msgs in self.link.receive_from():
            for msg in msgs:
                msg_id = msg.get_msgId()
                if msg_id in PARAM_IDS and sender == self.fc_address:
                    param_requests.append(msg)      # a ground station's (or the FC's), routed to us
                    continue
                if (msg.get_srcSystem(), msg.get_srcComponent()) != self.fc_ids:
                    self._foreign += 1
                    continue
                if self._signing and not msg.get_signed():      # a HEARTBEAT passes signing unsigned
                    self.second_sender(address_text(sender), refusal(self.link.signing_key, msg.get_msgbuf()))
                if sender != self.fc_address:        # the transport may read ahead of a lock, or hear others
                    if not (self._proves_fc(msg) and self._may_lock()):
                        self._foreign += self.locked
                        if self.connected:
                            self._refused(sender, *self.fc_ids, OTHER_ADDRESS)
                        continue
                    self._lock(sender)
                    events.add(LinkEvent.LOCKED)
                if msg_id == mavlink.MAVLINK_MSG_ID_COMMAND_ACK:
                    self.commands.on_ack(msg)
                elif msg_id == mavlink.MAVLINK_MSG_ID_TIMESYNC:
                    self._on_timesync(msg, now_s)
                elif msg_id in STREAMS:
                    events |= self._on_telemetry(int(msg.time_boot_ms), now_s)
                out.append(msg)
        if self.connected and now_s >= self.loss_deadline_s():
            self.connected = False
            self.link.lock_peer(self.fc_address, hear_others=True)     # a restarted FC may come from elsewhere
            events.add(LinkEvent.LOST)
        return Received(tuple(e for e in LinkEvent if e in events) if events else (), out, param_requests)

    def _warn_fc(self, text: str) -> None:
        """A STATUSTEXT WARNING to the FC, once there is one (nothing is sent before)."""
        if self.locked:
            self.statustext(mavlink.MAV_SEVERITY_WARNING, text)

    def _refused(self, sender, system: int, component: int, why: str) -> None:
        """A packet claiming `system/component` refused here or by the link (FcTransport.on_refused)."""
        if (system, component) == self.fc_ids:
            detail = f"the flight controller is at {address_text(self.fc_address)}" if why == OTHER_ADDRESS else ""
            self.second_sender(address_text(sender), why, detail)

    def _proves_fc(self, msg) -> bool:
        return msg.get_signed() or not self._signing

    def _may_lock(self) -> bool:
        """Not locked yet, or locked to an FC whose telemetry was lost."""
        return not self.locked or (not self.connected and self.last_telemetry_s is not None)

    def _lock(self, sender) -> None:
        self.previous_address, self.fc_address = self.fc_address, sender
        self.link.lock_peer(sender)

    def _on_telemetry(self, time_ms: int, now_s: float) -> frozenset[LinkEvent] | set[LinkEvent]:
        if self.connected and self.fc_time_ms is not None and time_ms >= self.fc_time_ms:
            self.fc_time_ms, self.last_telemetry_s = time_ms, now_s     # flowing (every frame): nothing to tell
            return _NO_EVENTS
        events = set()
        if not self.connected:
            self.connected = True
            self.link.lock_peer(self.fc_address)
            events.add(LinkEvent.TELEMETRY)
        silent_s = None if self.last_telemetry_s is None else now_s - self.last_telemetry_s
        if self.fc_time_ms is not None and time_ms < self.fc_time_ms and silent_s >= self.telemetry_timeout_s:
            events.add(LinkEvent.REBOOTED)
            self.delay.reset()
            self.fc_time_ms = time_ms
        elif self.fc_time_ms is None or time_ms > self.fc_time_ms:
            self.fc_time_ms = time_ms
        self.last_telemetry_s = now_s
        return events

    def loss_deadline_s(self) -> float:
        """When the telemetry counts as lost if nothing more comes (inf while not flowing)."""
        if not self.connected or self.last_telemetry_s is None:
            return float("inf")
        return self.last_telemetry_s + self.telemetry_timeout_s

    def _on_timesync(self, msg, now_s: float) -> None:
        if msg.tc1 == 0:                     # the FC asks: our clock, its ts1 back
            self.link.send(mavlink.MAVLink_timesync_message(round(now_s * 1e9), msg.ts1))
        else:
            self.delay.answered(msg.tc1, msg.ts1, now_s)

    # -- periodic ----------------------------------------------------------------------------------
    def request_intervals(self, period_s: float, ids=REQUESTED) -> None:
        """Ask for the streams `ids` (default: the telemetry frame's and the ESC telemetry) every
        period_s (again from the start for these)."""
        interval_us = float(round(period_s * 1e6))
        self.commands.replace([Command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(i), interval_us)) for i in ids])

    def stop_streams(self, ids) -> None:
        """Ask the FC to stop streaming `ids` (MAV_CMD_SET_MESSAGE_INTERVAL -1)."""
        self.commands.replace([Command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(i), -1.0)) for i in ids])

    def request_kept_state(self) -> None:
        """Ask for the M4_FAULT_STATUS the FC keeps of its companion (a restarted companion's
        memory of a confirmed fault and of its mission; an ack says when there is none), then
        for the FC's CURRENT_MODE (landing or not); both come as messages."""
        request = mavlink.MAV_CMD_REQUEST_MESSAGE
        self.commands.replace([Command(request, (float(i),), KEPT_STATE_RETRY_S) for i in KEPT_STATE])

    def kept_state_pending(self) -> bool:
        """Is a request of request_kept_state() still unanswered (and not given up)?"""
        return self.commands.pending > 0 and \
            any(self.commands.waiting(mavlink.MAV_CMD_REQUEST_MESSAGE, float(i)) for i in KEPT_STATE)

    def tick(self, now_s: float) -> None:
        """Heartbeat when due; the pending command sent or resent."""
        if not (self.locked or self.heartbeat_before_lock):
            return
        if now_s >= self._next_heartbeat_s:
            self.link.send(mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3))
            self._next_heartbeat_s = now_s + HEARTBEAT_PERIOD_S
        if self.locked and (msg := self.commands.next_message(now_s)) is not None:
            self.link.send(msg)

    def next_due_s(self, now_s: float) -> float:
        """When tick() or the loss watchdog in receive() has something to do next."""
        if not (self.locked or self.heartbeat_before_lock):
            return now_s + HEARTBEAT_PERIOD_S          # nothing to send before the FC shows up
        due = min(self._next_heartbeat_s, self.loss_deadline_s())
        if self.locked:
            due = min(due, self.commands.next_due_s(now_s))
        return due

    # -- out ---------------------------------------------------------------------------------------
    def send_setpoint(self, time_ms: int, period_ms: int, sp: Setpoint, now_s: float,
                      fault: FaultStatus | None = None, mission: MissionProgress | None = None) -> None:
        """The setpoint answering FC instant time_ms, with the fault status and the mission's
        progress (when a fault status is given) and a TIMESYNC request (when one is due), in
        one datagram. A frame the detector reads after the send has its status sent alone right
        after (send_fault_status): two datagrams that step (at 50 and 100 Hz, every healthy one)."""
        flags = mavlink.M4_SETPOINT_FLAG_THRUST_CUT if sp.thrust_cut else 0
        fb, cover = sp.rate_feedback, sp.shortfall_cover
        extensions = {} if fb is None else dict(rates_ref_frd_rad_s=_floats(fb.rates_ref_frd_rad_s),
                                                rates_ref_change_frd_rad_s2=_floats(fb.rates_ref_change_frd_rad_s2),
                                                rate_gain=_floats(fb.gain_n_per_rad_s.ravel()))
        if cover is not None:
            extensions["shortfall_gain"] = _floats(cover.gain.ravel())
            if cover.effectiveness_frd_rad_s2_per_n is not None:
                extensions["effectiveness_frd_rad_s2_per_n"] = _floats(cover.effectiveness_frd_rad_s2_per_n.T.ravel())
        msgs = [mavlink.MAVLink_m4_setpoint_message(
            *self.fc_ids, int(time_ms), int(period_ms), _floats(sp.thrust_n), _floats(sp.hip_rad),
            _floats(sp.hip_rate_rad_s), flags, **extensions)]
        if fault is not None:
            msgs.append(_fault_status_message(time_ms, fault, mission))
        if self.delay.request_due(time_ms):
            msgs.append(mavlink.MAVLink_timesync_message(0, self.delay.requested(time_ms, now_s)))
        self.link.send_all(msgs)

    def send_fault_status(self, time_ms: int, fault: FaultStatus, mission: MissionProgress | None = None) -> None:
        """The fault status after FC instant time_ms, alone: the detector read that instant's
        frame after its setpoint left."""
        self.link.send(_fault_status_message(time_ms, fault, mission))

    def statustext(self, severity: int, text: str) -> None:
        self.link.send(mavlink.MAVLink_statustext_message(severity, text.encode("ascii", "replace")[:STATUSTEXT_MAX]))

    def health(self) -> LinkHealth:
        signing = self.link.signing_counters()
        return LinkHealth(locked=self.locked, bad_crc=max(self.link.bad_packets - signing.rejected, 0),
                          bad_signature=signing.rejected, foreign=self._foreign + self.link.foreign_datagrams,
                          commands_acked=self.commands.acked, commands_pending=self.commands.pending,
                          second_sender=self.second_sender.count)
