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
- Modes (sitl/fc/modes.py): MAV_CMD_DO_SET_MODE (param1 with MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
  param2 our custom mode; with a sub mode in param3, PX4's main and sub mode, as MAVSDK sends
  them: AUTO.LOITER is HOLD, AUTO.LAND is LAND), MAV_CMD_DO_SET_STANDARD_MODE
  (param1 a MAV_STANDARD_MODE), MAV_CMD_NAV_LAND (LAND where it is; a location is not flown to).
  Refused while disarmed, and, but LAND, while the failsafe flies (TEMPORARILY_REJECTED).
Anything else: MAV_RESULT_UNSUPPORTED. Bad parameters: MAV_RESULT_DENIED.
Who may command (the companion and ground stations): sitl/fc/flight_controller.py. Every
command is answered; a refusal (DENIED, UNSUPPORTED, TEMPORARILY_REJECTED) is counted and,
once per 10 s for each sender, command and answer, logged with its reason and told to the
sender in a STATUSTEXT WARNING: a ground station retrying gets each retry answered, the log
one line.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from m4.airframe import ROTOR_COUNT
from m4.fault_kind import FaultKind, rotor_loss_kind
from m4.fc_mode import FcMode
from m4.log_limit import RepeatLimiter
from m4.mavlink import mavlink
from sitl.fc.modes import PX4_MODES, available_modes, by_standard_mode, mode_info
from sitl.fc.telemetry import statustext

m = mavlink
FORCE_DISARM = 21196
_REFUSALS = (m.MAV_RESULT_DENIED, m.MAV_RESULT_UNSUPPORTED, m.MAV_RESULT_TEMPORARILY_REJECTED)


class Call(NamedTuple):
    """One command as its handler sees it."""
    params: tuple[float, float, float, float]
    now_ms: int
    link: int                      # the link it came on
    sender: tuple[int, int]        # system, component


class Outcome(NamedTuple):
    result: int                    # MAV_RESULT
    extra: list = []               # messages that follow the ack (to the sender)
    reason: str = ""               # why it was refused (for the log and the sender)


def _whole(value: float) -> bool:
    return math.isfinite(value) and value == int(value)


def _name(enum: str, value: int) -> str:
    entry = m.enums[enum].get(value)
    return entry.name if entry is not None else str(value)


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
            m.MAV_CMD_DO_SET_MODE: self._set_mode,
            m.MAV_CMD_DO_SET_STANDARD_MODE: self._set_standard_mode,
            m.MAV_CMD_NAV_LAND: self._land,
        }
        self._repeats = RepeatLimiter()

    def handle(self, msg, now_ms: int, link: int = 0) -> list[m.MAVLink_message]:
        """COMMAND_ACK (to the sender) first, then anything the command asked for, or why not."""
        call = Call((msg.param1, msg.param2, msg.param3, msg.param4), now_ms, link,
                    (msg.get_srcSystem(), msg.get_srcComponent()))
        handler = self._handlers.get(msg.command)
        out = Outcome(m.MAV_RESULT_UNSUPPORTED, reason="not a command this FC knows") if handler is None else handler(call)
        if out.result in _REFUSALS:
            return [self.ack(msg, out.result), *self._refused(msg.command, call, out)]
        return [self.ack(msg, out.result), *out.extra]

    def _refused(self, command: int, call: Call, out: Outcome) -> list[m.MAVLink_message]:
        """Counted; logged and told to the sender once per 10 s for each sender, command and answer."""
        self.fc.counters.commands_refused += 1
        held = self._repeats.admit((call.sender, command, out.result))
        if held is None:
            return []
        name, result = _name("MAV_CMD", command), _name("MAV_RESULT", out.result).removeprefix("MAV_RESULT_")
        repeats = f" (and {held} more like it in the last {self._repeats.interval_s:g} s)" if held else ""
        self.fc.log(f"t={call.now_ms / 1000:.3f} s: {name} from {call.sender[0]}/{call.sender[1]} refused: "
                    f"{result}{f', {out.reason}' if out.reason else ''}{repeats}")
        short = name.removeprefix("MAV_CMD_").removeprefix("DO_")
        return [statustext(m.MAV_SEVERITY_WARNING, f"FC refused {short}: {out.reason or result}")]

    def ack(self, msg, result: int) -> m.MAVLink_command_ack_message:
        """The COMMAND_ACK answering `msg` with `result`, to its sender."""
        self.fc.counters.commands_acked += 1
        return m.MAVLink_command_ack_message(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def _apply_loss(self, rotor: int, loss: float, kind: FaultKind):
        self.fc.set_rotor_loss(rotor, loss, kind)
        return Outcome(m.MAV_RESULT_ACCEPTED)

    def _inject_failure(self, call: Call) -> Outcome:
        unit, failure_type, instance, _ = call.params
        if unit != m.FAILURE_UNIT_SYSTEM_MOTOR or failure_type not in (m.FAILURE_TYPE_OK, m.FAILURE_TYPE_OFF):
            return Outcome(m.MAV_RESULT_UNSUPPORTED, reason="motor OFF and OK only")
        rotor = _rotor(instance)
        if rotor is None:
            return Outcome(m.MAV_RESULT_DENIED, reason=f"no rotor {instance:g} (1..{ROTOR_COUNT}, 0 all)")
        return self._apply_loss(rotor, 1.0 if failure_type == m.FAILURE_TYPE_OFF else 0.0, FaultKind.MOTOR)

    def _rotor_loss(self, call: Call) -> Outcome:
        rotor, loss, kind = _rotor(call.params[0]), call.params[1], rotor_loss_kind(call.params[2])
        if rotor is None or not (math.isfinite(loss) and 0.0 <= loss <= 1.0) or kind is None:
            return Outcome(m.MAV_RESULT_DENIED, reason="rotor 0..4, loss 0..1, a known kind")
        return self._apply_loss(rotor, float(loss), kind)

    def _message_id(self, value: float) -> int | None:
        if not math.isfinite(value) or value != int(value) or not self.fc.telemetry_builder.can_build(int(value)):
            return None
        return int(value)

    def _set_message_interval(self, call: Call) -> Outcome:
        msg_id, interval_us = self._message_id(call.params[0]), call.params[1]
        if msg_id is None or not math.isfinite(interval_us):
            return Outcome(m.MAV_RESULT_DENIED, reason=f"no stream {call.params[0]:g}, or no interval")
        self.fc.schedule_for(call.link).set_interval_us(msg_id, interval_us, call.now_ms)
        return Outcome(m.MAV_RESULT_ACCEPTED)

    def _request_message(self, call: Call) -> Outcome:
        params = call.params
        if params[0] == m.MAVLINK_MSG_ID_M4_FAULT_STATUS:
            f = self.fc.fault_status
            if f is None:
                return Outcome(m.MAV_RESULT_FAILED)
            return Outcome(m.MAV_RESULT_ACCEPTED,
                           [m.MAVLink_m4_fault_status_message(*(getattr(f, name) for name in f.fieldnames))])
        if params[0] == m.MAVLINK_MSG_ID_AVAILABLE_MODES:
            found = available_modes(int(params[1])) if _whole(params[1]) else None
            if found is None:
                return Outcome(m.MAV_RESULT_DENIED, reason=f"no mode index {params[1]:g}")
            return Outcome(m.MAV_RESULT_ACCEPTED, found)
        msg_id = self._message_id(params[0])
        if msg_id is None:
            return Outcome(m.MAV_RESULT_DENIED, reason=f"no message {params[0]:g} to send")
        return Outcome(m.MAV_RESULT_ACCEPTED, [self.fc.telemetry_builder.build(msg_id, self.fc.snapshot(call.now_ms))])

    def _arm_disarm(self, call: Call) -> Outcome:
        arm, force = call.params[0], call.params[1]
        if arm not in (0.0, 1.0):
            return Outcome(m.MAV_RESULT_DENIED, reason="param1 must be 1 (arm) or 0 (disarm)")
        if arm == 0.0 and force != FORCE_DISARM and not self.fc.measured_state(call.now_ms).on_ground:
            return Outcome(m.MAV_RESULT_DENIED, reason=f"in the air (force: param2 {FORCE_DISARM})")
        self.fc.set_armed(arm == 1.0)
        return Outcome(m.MAV_RESULT_ACCEPTED)

    def _set_mode(self, call: Call) -> Outcome:
        base, custom, sub = call.params[0], call.params[1], call.params[2]
        if not _whole(base) or not int(base) & m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return Outcome(m.MAV_RESULT_DENIED, reason="custom modes only")
        if math.isfinite(sub) and sub != 0:
            mode = PX4_MODES.get((custom, sub))
            if mode is None:
                return Outcome(m.MAV_RESULT_DENIED, reason=f"no PX4 mode {custom:g}.{sub:g}")
            return self._select(mode, call)
        mode = FcMode.of(int(custom)) if _whole(custom) else None
        if mode is None:
            return Outcome(m.MAV_RESULT_DENIED, reason=f"no mode {custom:g}")
        return self._select(mode, call)

    def _set_standard_mode(self, call: Call) -> Outcome:
        mode = by_standard_mode(int(call.params[0])) if _whole(call.params[0]) else None
        if mode is None:
            return Outcome(m.MAV_RESULT_DENIED, reason=f"no standard mode {call.params[0]:g}")
        return self._select(mode, call)

    def _land(self, call: Call) -> Outcome:
        return self._select(FcMode.LAND, call)

    def _select(self, mode: FcMode, call: Call) -> Outcome:
        fc = self.fc
        if not mode_info(mode).selectable:
            return Outcome(m.MAV_RESULT_DENIED, reason=f"{mode.name} is not selectable")
        if not fc.armed:
            return Outcome(m.MAV_RESULT_TEMPORARILY_REJECTED, reason="disarmed")
        if mode != FcMode.LAND and not fc.fresh(call.now_ms):
            return Outcome(m.MAV_RESULT_TEMPORARILY_REJECTED, reason="no setpoints")
        if mode != fc.selected:
            fc.log(f"t={call.now_ms / 1000:.3f} s: mode {mode.name} selected by {call.sender[0]}/{call.sender[1]}")
        fc.select_mode(mode, call.now_ms)
        return Outcome(m.MAV_RESULT_ACCEPTED)
