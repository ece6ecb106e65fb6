"""Which telemetry the flight controller sends when: message streams on the simulated clock.

A stream with interval I ms is sent at the simulated instants that are multiples of I, so
streams whose intervals divide one another stay aligned (at t = 20 ms ATTITUDE and
LOCAL_POSITION_NED carry the same time_boot_ms). Messages due at one instant go out in
`EMISSION_ORDER`, which ends with the lockstep frame in the contract's order. A link's lockstep
frame (`frame`) is FRAME less the streams stopped on that link, as an FC that honours the stop
sends no more of them; M4_THRUSTER_STATUS, which marks the frame, always.
"""

from __future__ import annotations

from m4.mavlink import mavlink

m = mavlink
FRAME = (m.MAVLINK_MSG_ID_ATTITUDE, m.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, m.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
         m.MAVLINK_MSG_ID_M4_JOINT_STATE, m.MAVLINK_MSG_ID_M4_THRUSTER_STATUS)
DEFAULT_INTERVALS_MS = {
    m.MAVLINK_MSG_ID_HEARTBEAT: 1000,
    m.MAVLINK_MSG_ID_CURRENT_MODE: 2000,          # and on every mode change (sitl/fc/modes.py)
    m.MAVLINK_MSG_ID_SYS_STATUS: 500,
    m.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1000,
    m.MAVLINK_MSG_ID_MISSION_CURRENT: 1000,       # and on every change (sitl/fc/mission_store.py)
    m.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 50,
    m.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS: 50,
    m.MAVLINK_MSG_ID_ATTITUDE: 10,
    m.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10,
    m.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 20,
    m.MAVLINK_MSG_ID_M4_JOINT_STATE: 20,
    m.MAVLINK_MSG_ID_M4_THRUSTER_STATUS: 20,
}
# A flight controller with ESC telemetry streams it too: 50 Hz, what ArduPilot's bidirectional
# DShot RPM supports comfortably (MAV_CMD_SET_MESSAGE_INTERVAL changes it).
ESC_TELEMETRY_INTERVALS_MS = {**DEFAULT_INTERVALS_MS, m.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4: 20}
_FIRST = tuple(i for i in ESC_TELEMETRY_INTERVALS_MS if i not in FRAME)


def _order(msg_id: int) -> tuple[int, int]:
    """Sort key: the frame last and in its order, everything else before it."""
    if msg_id in FRAME:
        return (2, FRAME.index(msg_id))
    if msg_id in _FIRST:
        return (0, _FIRST.index(msg_id))
    return (1, msg_id)


_ORDER = {msg_id: _order(msg_id) for msg_id in (*_FIRST, *FRAME)}     # the usual ones' keys, once


class StreamSchedule:
    def __init__(self, intervals_ms: dict[int, int] | None = None):
        self._defaults = dict(DEFAULT_INTERVALS_MS if intervals_ms is None else intervals_ms)
        self._interval_ms: dict[int, int] = dict(self._defaults)
        self._next_ms: dict[int, int] = {i: 0 for i in self._interval_ms}
        self._next_due_ms = self._earliest()      # min(_next_ms): asked at every instant, changed only here
        self.frame = self._frame()                # this link's lockstep frame (above)

    def _frame(self) -> tuple[int, ...]:
        return tuple(i for i in FRAME if i in self._interval_ms or i == FRAME[-1])

    def set_interval_us(self, msg_id: int, interval_us: float, now_ms: int) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL semantics: -1 stops, 0 restores the default, else the
        interval in microseconds (rounded to the 1 ms clock, at least 1 ms). Handled after the
        instant's own streams went out: the stream goes on at its next multiple after `now_ms`
        (never off its grid, whatever instant a resent command lands on)."""
        if interval_us < 0:
            self._interval_ms.pop(msg_id, None)
            self._next_ms.pop(msg_id, None)
            self._next_due_ms = self._earliest()
            self.frame = self._frame()
            return
        if interval_us == 0:
            if msg_id not in self._defaults:
                self.set_interval_us(msg_id, -1, now_ms)
                return
            interval = self._defaults[msg_id]
        else:
            interval = max(1, round(interval_us / 1000.0))
        self._interval_ms[msg_id] = interval
        self._next_ms[msg_id] = (now_ms // interval + 1) * interval
        self._next_due_ms = self._earliest()
        self.frame = self._frame()

    def interval_ms(self, msg_id: int) -> int | None:
        """The stream's interval in force (None: not sent)."""
        return self._interval_ms.get(msg_id)

    def next_due_ms(self) -> int | None:
        return self._next_due_ms

    def _earliest(self) -> int | None:
        return min(self._next_ms.values(), default=None)

    def due(self, now_ms: int, extra=()) -> list[int]:
        """Ids to send at `now_ms` (plus `extra`, e.g. the frame), in emission order; each
        stream sent is rescheduled."""
        if not extra and (self._next_due_ms is None or self._next_due_ms > now_ms):
            return []                    # most instants (every FC tick is one): nothing due
        ids = set(extra)
        if self._next_due_ms is not None and self._next_due_ms <= now_ms:
            for msg_id, t in self._next_ms.items():
                if t <= now_ms:
                    ids.add(msg_id)
                    iv = self._interval_ms[msg_id]
                    self._next_ms[msg_id] = (now_ms // iv + 1) * iv
            self._next_due_ms = self._earliest()
        return sorted(ids, key=_ORDER.get) if ids <= _ORDER.keys() else sorted(ids, key=_order)
