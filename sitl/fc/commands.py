"""Commands the simulated flight controller understands; every one is acknowledged.

COMMAND_LONG and COMMAND_INT alike (their first four params are the same floats):
- MAV_CMD_INJECT_FAILURE: unit FAILURE_UNIT_SYSTEM_MOTOR, type FAILURE_TYPE_OFF (motor
  stopped: kind MOTOR) or FAILURE_TYPE_OK (restored), instance rotor 1..4 or 0 for all. Other
  units/types: UNSUPPORTED.
- MAV_CMD_M4_ROTOR_LOSS: rotor 1..4 or 0, loss 0..1 (0 restores), kind M4_FAULT_KIND
  (UNKNOWN, 0, the default: DEGRADED, loss relative to hover thrust; m4.fault_kind.rotor_loss_kind).
- MAV_CMD_SET_MESSAGE_INTERVAL: message id, interval in us (-1 stop, 0 default).
- MAV_CMD_REQUEST_MESSAGE: message id; the message follows the ACCEPTED ack. For
  M4_FAULT_STATUS, the last one the companion sent, every field as it came (its fault and its
  mission's progress; MAV_RESULT_FAILED if none came yet); for
  AVAILABLE_MODES param2 picks the mode (its index from 1; 0: every mode, one message each).
- MAV_CMD_COMPONENT_ARM_DISARM: 1 arms; 0 disarms on the ground (in the air only with
  param2 = 21196, the force code ArduPilot and PX4 use).
Anything else: MAV_RESULT_UNSUPPORTED. Bad parameters: MAV_RESULT_DENIED.
The flight controller takes commands from its paired companion only (sitl/fc/flight_controller.py).
"""

from __future__ import annotations

import math

from m4.airframe import ROTOR_COUNT
from m4.fault_kind import FaultKind, rotor_loss_kind
from m4.mavlink import mavlink
from sitl.fc.modes import available_modes

m = mavlink
FORCE_DISARM = 21196


def _rotor(value: float) -> int | None:
    """A rotor number 0..4 from a float param, or None."""
    if not math.isfinite(value) or value != int(value) or not 0 <= value <= ROTOR_COUNT:
        return None
    return int(value)


class CommandHandler:
    def __init__(self, fc):
        self.fc = fc
        self._handlers = {
            m.MAV_CMD_INJECT_FAILURE: self._inject_failure,
            m.MAV_CMD_M4_ROTOR_LOSS: self._rotor_loss,
            m.MAV_CMD_SET_MESSAGE_INTERVAL: self._set_message_interval,
            m.MAV_CMD_REQUEST_MESSAGE: self._request_message,
            m.MAV_CMD_COMPONENT_ARM_DISARM: self._arm_disarm,
        }

    def handle(self, msg, now_ms: int) -> list[m.MAVLink_message]:
        """COMMAND_ACK (to the sender) first, then anything the command asked for."""
        params = (msg.param1, msg.param2, msg.param3, msg.param4)
        handler = self._handlers.get(msg.command)
        result, extra = (m.MAV_RESULT_UNSUPPORTED, []) if handler is None else handler(params, now_ms)
        return [self.ack(msg, result), *extra]

    def ack(self, msg, result: int) -> m.MAVLink_command_ack_message:
        """The COMMAND_ACK answering `msg` with `result`, to its sender."""
        self.fc.counters.commands_acked += 1
        return m.MAVLink_command_ack_message(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def _apply_loss(self, rotor: int, loss: float, kind: FaultKind):
        self.fc.set_rotor_loss(rotor, loss, kind)
        return m.MAV_RESULT_ACCEPTED, []

    def _inject_failure(self, params, now_ms):
        unit, failure_type, instance, _ = params
        if unit != m.FAILURE_UNIT_SYSTEM_MOTOR or failure_type not in (m.FAILURE_TYPE_OK, m.FAILURE_TYPE_OFF):
            return m.MAV_RESULT_UNSUPPORTED, []
        rotor = _rotor(instance)
        if rotor is None:
            return m.MAV_RESULT_DENIED, []
        return self._apply_loss(rotor, 1.0 if failure_type == m.FAILURE_TYPE_OFF else 0.0, FaultKind.MOTOR)

    def _rotor_loss(self, params, now_ms):
        rotor, loss, kind = _rotor(params[0]), params[1], rotor_loss_kind(params[2])
        if rotor is None or not (math.isfinite(loss) and 0.0 <= loss <= 1.0) or kind is None:
            return m.MAV_RESULT_DENIED, []
        return self._apply_loss(rotor, float(loss), kind)

    def _message_id(self, value: float) -> int | None:
        if not math.isfinite(value) or value != int(value) or not self.fc.telemetry_builder.can_build(int(value)):
            return None
        return int(value)

    def _set_message_interval(self, params, now_ms):
        msg_id, interval_us = self._message_id(params[0]), params[1]
        if msg_id is None or not math.isfinite(interval_us):
            return m.MAV_RESULT_DENIED, []
        self.fc.schedule.set_interval_us(msg_id, interval_us, now_ms)
        return m.MAV_RESULT_ACCEPTED, []

    def _request_message(self, params, now_ms):
        if params[0] == m.MAVLINK_MSG_ID_M4_FAULT_STATUS:
            f = self.fc.fault_status
            if f is None:
                return m.MAV_RESULT_FAILED, []
            return m.MAV_RESULT_ACCEPTED, [m.MAVLink_m4_fault_status_message(*(getattr(f, name) for name in f.fieldnames))]
        if params[0] == m.MAVLINK_MSG_ID_AVAILABLE_MODES:
            index = params[1]
            found = available_modes(int(index)) if math.isfinite(index) and index == int(index) else None
            return (m.MAV_RESULT_DENIED, []) if found is None else (m.MAV_RESULT_ACCEPTED, found)
        msg_id = self._message_id(params[0])
        if msg_id is None:
            return m.MAV_RESULT_DENIED, []
        return m.MAV_RESULT_ACCEPTED, [self.fc.telemetry_builder.build(msg_id, self.fc.snapshot(now_ms))]

    def _arm_disarm(self, params, now_ms):
        arm, force = params[0], params[1]
        if arm not in (0.0, 1.0):
            return m.MAV_RESULT_DENIED, []
        if arm == 0.0 and force != FORCE_DISARM and not self.fc.measured_state(now_ms).on_ground:
            return m.MAV_RESULT_DENIED, []
        self.fc.set_armed(arm == 1.0)
        return m.MAV_RESULT_ACCEPTED, []
