"""The companion's side of the MAVLink link to its flight controller (system 1, component 191).

- Lock-on: only the flight controller's system and component are heard (others are dropped
  and counted as foreign); the first address that sends the FC's HEARTBEAT (signed, when a
  signing key is set) is the FC, and from then on a udpin link hears and answers only that
  address (a stray sender, even with the FC's ids, can neither feed us nor redirect our
  replies). Nothing is sent before, except on a link with a fixed peer (udpout, tcp,
  serial: `heartbeat_before_lock`), where our heartbeat is how the FC learns of us.
- Heartbeat at 1 Hz as MAV_TYPE_ONBOARD_CONTROLLER.
- Message intervals: the telemetry frame's streams are asked for at the control period with
  MAV_CMD_SET_MESSAGE_INTERVAL, one command at a time, each resent until acknowledged.
- Out: M4_SETPOINT, M4_FAULT_STATUS, STATUSTEXT.
- Health counters: bad CRC (garbled packets), bad signature (unsigned or badly signed,
  dropped by signing), foreign (other systems, components or addresses).

The transport is anything with `receive_from()`, `send(msg)` and `lock_peer(address)` (see
m4.mavlink.link and m4.mavlink.stream_link).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.controller import Setpoint
from companion.core.fault_detector import FaultStatus
from m4.mavlink import FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from companion.telemetry import STREAMS

HEARTBEAT_PERIOD_S = 1.0
COMMAND_RETRY_S = 0.5
COMMAND_ATTEMPTS = 5
STATUSTEXT_MAX = 50


@dataclass(frozen=True)
class LinkHealth:
    locked: bool
    bad_crc: int
    bad_signature: int
    foreign: int
    intervals_acked: int
    intervals_pending: int


def _floats(values) -> list[float]:
    return [float(v) for v in np.asarray(values, dtype=float).reshape(-1)]


class FcLink:
    def __init__(self, link, fc_system_id: int = FC_SYSTEM_ID, fc_component_id: int = FC_COMPONENT_ID,
                 heartbeat_before_lock: bool = False):
        self.link = link
        self.heartbeat_before_lock = heartbeat_before_lock
        self.fc_ids = (fc_system_id, fc_component_id)
        self.fc_address = None
        self._foreign = 0
        self._next_heartbeat_s = 0.0
        self._intervals: list[tuple[int, float]] = []      # (msg id, interval us) still to be acked
        self._sent_at_s: float | None = None
        self._attempts = 0
        self.intervals_acked = 0
        self._signing = link.mav.signing.secret_key is not None

    @property
    def locked(self) -> bool:
        return self.fc_address is not None

    # -- in ----------------------------------------------------------------------------------------
    def receive(self) -> list[mavlink.MAVLink_message]:
        """The messages from the flight controller that have arrived; the rest is counted."""
        out = []
        for sender, msgs in self.link.receive_from():
            for msg in msgs:
                if (msg.get_srcSystem(), msg.get_srcComponent()) != self.fc_ids:
                    self._foreign += 1
                    continue
                if not self.locked:
                    if msg.get_msgId() != mavlink.MAVLINK_MSG_ID_HEARTBEAT or (self._signing and not msg.get_signed()):
                        continue
                    self.fc_address = sender
                    self.link.lock_peer(sender)
                if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_COMMAND_ACK:
                    self._on_ack(msg)
                out.append(msg)
        return out

    def _on_ack(self, msg) -> None:
        if msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL and self._intervals and self._sent_at_s is not None:
            self._intervals.pop(0)
            self._sent_at_s = None
            self._attempts = 0
            self.intervals_acked += 1

    # -- periodic ----------------------------------------------------------------------------------
    def request_intervals(self, period_s: float) -> None:
        """Ask for the telemetry frame's streams every period_s (again from the start)."""
        interval_us = float(round(period_s * 1e6))
        self._intervals = [(msg_id, interval_us) for msg_id in STREAMS]
        self._sent_at_s = None
        self._attempts = 0

    def tick(self, now_s: float) -> None:
        """Heartbeat when due; the pending interval request sent or resent."""
        if not (self.locked or self.heartbeat_before_lock):
            return
        if now_s >= self._next_heartbeat_s:
            self.link.send(mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3))
            self._next_heartbeat_s = now_s + HEARTBEAT_PERIOD_S
        if self.locked and self._intervals and (self._sent_at_s is None or now_s - self._sent_at_s >= COMMAND_RETRY_S):
            if self._attempts >= COMMAND_ATTEMPTS:
                self._intervals.pop(0)           # the FC does not answer this one: go on with the others
                self._attempts = 0
                if not self._intervals:
                    return
            msg_id, interval_us = self._intervals[0]
            self.link.send(mavlink.MAVLink_command_long_message(
                *self.fc_ids, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, self._attempts, float(msg_id), interval_us,
                0.0, 0.0, 0.0, 0.0, 0.0))
            self._sent_at_s = now_s
            self._attempts += 1

    def next_due_s(self, now_s: float) -> float:
        """When tick() has something to do next."""
        if not (self.locked or self.heartbeat_before_lock):
            return now_s + HEARTBEAT_PERIOD_S          # nothing to send before the FC shows up
        due = self._next_heartbeat_s
        if self._intervals:
            due = min(due, now_s if self._sent_at_s is None else self._sent_at_s + COMMAND_RETRY_S)
        return due

    # -- out ---------------------------------------------------------------------------------------
    def send_setpoint(self, time_ms: int, period_ms: int, sp: Setpoint) -> None:
        flags = mavlink.M4_SETPOINT_FLAG_THRUST_CUT if sp.thrust_cut else 0
        self.link.send(mavlink.MAVLink_m4_setpoint_message(
            *self.fc_ids, int(time_ms), int(period_ms), _floats(sp.thrust_n), _floats(sp.hip_angle_rad),
            _floats(sp.hip_rate_rad_s), flags))

    def send_fault_status(self, time_ms: int, status: FaultStatus) -> None:
        detected_ms = 0 if status.detected_at_s is None else round(status.detected_at_s * 1000)
        estimate = np.nan_to_num(status.thrust_max_estimate_n, nan=0.0, posinf=0.0, neginf=0.0)
        self.link.send(mavlink.MAVLink_m4_fault_status_message(
            int(time_ms), status.rotor or 0, _floats(estimate), detected_ms, int(status.state)))

    def statustext(self, severity: int, text: str) -> None:
        self.link.send(mavlink.MAVLink_statustext_message(severity, text.encode("ascii", "replace")[:STATUSTEXT_MAX]))

    def health(self) -> LinkHealth:
        signing = self.link.signing_counters()
        return LinkHealth(locked=self.locked, bad_crc=max(self.link.bad_packets - signing.rejected, 0),
                          bad_signature=signing.rejected, foreign=self._foreign + self.link.foreign_datagrams,
                          intervals_acked=self.intervals_acked, intervals_pending=len(self._intervals))
