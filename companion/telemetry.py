"""The flight controller's telemetry assembled into one picture of the vehicle, and its ROM state.

Pure logic: feed decoded messages (ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION_NED,
M4_JOINT_STATE, M4_THRUSTER_STATUS) with the companion's monotonic clock to `add()`; ask
for `snapshot()` and `rom_state()`.

Each stream keeps its newest sample by the FC's `time_boot_ms`: a duplicate or an older
stamp is dropped and counted. After a reboot of the FC (which the link notices:
companion.fc_link) `clear()` starts every stream over. A message with a
non-finite field (or a quaternion that is not a unit one) is rejected and counted; in
M4_THRUSTER_STATUS a NaN means "the FC cannot tell" (contract) and is kept as NaN.

Freshness: `stale(limit_s)` names the streams the controller needs that have brought nothing
for limit_s while the others came: the attitude (stale when neither ATTITUDE nor
ATTITUDE_QUATERNION is fresh), position, joints, thrusters, and the ESC telemetry once some
has come. Both clocks must say so: the FC's (its newest instant on any stream, less the
stream's newest) and ours (the newest arrival on any, less the stream's last). A link gap
that stops everything ages nothing on either (the link's own timeout covers that), nor does a
delay; in lockstep the FC's clock waits for our answer, so a wait ages nothing on its clock;
one sample stamped far ahead ages nothing on ours. A stream that stops alone ages on both,
whether a MAV_CMD_SET_MESSAGE_INTERVAL stopped it or a flood starved it.

ESC telemetry (ArduPilot's ESC_TELEMETRY_1_TO_4: rpm, current in cA, voltage in cV per ESC)
carries no timestamp: it is stamped with the FC's clock as the other streams last showed it
(the newest time_boot_ms received so far), and a frame is taken only when that clock has
moved on since the last one. A voltage of 0 means "not reported" (NaN). Many flight
controllers send none: the snapshot's `esc` is then None.

Frames: everything stays NED/FRD as on the wire. LOCAL_POSITION_NED is the hull centre (the
IMU); the ROM's p and v are the whole robot's centre of mass, offset by
`Airframe.com_offset_frd_m(hip)` (in closed form: companion.core.com_offset) rotated into NED,
its velocity including omega x r and the offset's own motion with the legs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from m4.airframe import ROTOR_COUNT
from m4.attitude import euler_from_quat_wxyz, rotation_rows
from companion.core.com_offset import ComOffset
from companion.core.esc_evidence import EscSample
from m4.mavlink import mavlink

ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE
ATTITUDE_QUATERNION = mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION
LOCAL_POSITION = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
JOINT_STATE = mavlink.MAVLINK_MSG_ID_M4_JOINT_STATE
THRUSTER_STATUS = mavlink.MAVLINK_MSG_ID_M4_THRUSTER_STATUS
STREAMS = (ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION, JOINT_STATE, THRUSTER_STATUS)
ESC_TELEMETRY = mavlink.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4
READ = STREAMS + (ESC_TELEMETRY,)            # what the companion reads of the FC's telemetry
# What it asks the FC to stream: one attitude message, ATTITUDE (the snapshot's at a shared instant);
# ATTITUDE_QUATERNION is asked for only when the attitude goes stale (companion.stream_watch).
REQUESTED = tuple(i for i in READ if i != ATTITUDE_QUATERNION)
# What the controller needs, each with the messages that carry it (the first names it).
NEEDED = ((ATTITUDE, ATTITUDE_QUATERNION), (LOCAL_POSITION,), (JOINT_STATE,), (THRUSTER_STATUS,))
LABELS = {ATTITUDE: "attitude", LOCAL_POSITION: "position", JOINT_STATE: "joints", THRUSTER_STATUS: "thrusters",
          ESC_TELEMETRY: "ESC"}
_QUAT_NORM_TOLERANCE = 0.05


def _finite(first: tuple[float, ...], second: tuple[float, ...]) -> bool:
    return all(map(math.isfinite, first)) and all(map(math.isfinite, second))


def _attitude(msg) -> tuple[tuple[float, ...], ...] | None:
    euler, rates = (msg.roll, msg.pitch, msg.yaw), (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
    return (euler, rates) if _finite(euler, rates) else None


def _quaternion(msg) -> tuple[tuple[float, ...], ...] | None:
    quat, rates = (msg.q1, msg.q2, msg.q3, msg.q4), (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
    return (quat, rates) if _finite(quat, rates) and abs(math.hypot(*quat) - 1.0) <= _QUAT_NORM_TOLERANCE else None


def _position(msg) -> tuple[tuple[float, ...], ...] | None:
    pos, vel = (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)
    return (pos, vel) if _finite(pos, vel) else None


def _joints(msg) -> tuple[tuple[float, ...], ...] | None:
    hip, hip_rate = tuple(msg.hip_angle_rad), tuple(msg.hip_rate_rad_s)
    return (hip, hip_rate) if _finite(hip, hip_rate) else None


def _thrusters(msg) -> tuple[tuple[float, ...], ...] | None:
    """NaN kept: the FC cannot tell."""
    cmd, limit = tuple(msg.thrust_cmd_n), tuple(msg.thrust_limit_n)
    return (cmd, limit) if len(cmd) == ROTOR_COUNT and len(limit) == ROTOR_COUNT else None


# Each stream's fields as floats, named with units and frames by the comments (None: the message
# is rejected: a non-finite field, a quaternion that is not a unit one, a thruster array of
# another length):
_READERS = {
    ATTITUDE: _attitude,              # (euler_rad, rates_frd_rad_s)
    ATTITUDE_QUATERNION: _quaternion,  # (quat_wxyz, rates_frd_rad_s)
    LOCAL_POSITION: _position,        # (pos_ned_m, vel_ned_m_s)
    JOINT_STATE: _joints,             # (hip_rad, hip_rate_rad_s)
    THRUSTER_STATUS: _thrusters,      # (thrust_cmd_n, thrust_limit_n)
}


class Sample(NamedTuple):
    time_ms: int              # the FC's clock
    received_s: float         # the companion's monotonic clock
    values: tuple[tuple[float, ...], ...]      # the stream's fields (_READERS)


@dataclass
class TelemetryCounters:
    accepted: int = 0
    stale: int = 0            # duplicate or older time_boot_ms than the stream's newest
    nonfinite: int = 0        # NaN/inf field or a quaternion that is not a unit one


class VehicleSnapshot(NamedTuple):
    """The newest sample of every stream; hull centre position (NED) as on the wire."""

    time_ms: int                        # the newest instant among the streams
    times_ms: dict[int, int]            # per stream id
    euler_rad: np.ndarray               # roll, pitch, yaw (ZYX), body FRD -> NED
    rates_frd_rad_s: np.ndarray
    pos_ned_m: np.ndarray               # hull centre
    vel_ned_m_s: np.ndarray             # hull centre
    hip_rad: np.ndarray
    hip_rate_rad_s: np.ndarray
    thrust_cmd_n: np.ndarray            # as the FC reports them (NaN: it cannot tell)
    thrust_limit_n: np.ndarray
    esc: EscSample | None = None        # the newest ESC telemetry (None: the FC sends none)


class TelemetryAssembler:
    def __init__(self):
        self.counters = TelemetryCounters()
        self._samples: dict[int, Sample] = {}
        self._esc: EscSample | None = None
        self._esc_received_s: float | None = None
        self._first: tuple[float, float] | None = None     # the first sample's (FC instant, arrival), s
        self._newest_ms: int | None = None                 # the newest instant among the streams' samples

    def add(self, msg, now_s: float) -> bool:
        """Take one message; True when it is a telemetry sample and was accepted."""
        msg_id = msg.get_msgId()
        read = _READERS.get(msg_id)
        if read is None:
            return msg_id == ESC_TELEMETRY and self._add_esc(msg, now_s)
        values = read(msg)
        if values is None:
            self.counters.nonfinite += 1
            return False
        t_ms = int(msg.time_boot_ms)
        newest = self._samples.get(msg_id)
        if newest is not None and t_ms <= newest.time_ms:
            self.counters.stale += 1
            return False
        self._samples[msg_id] = Sample(t_ms, now_s, values)
        if self._newest_ms is None or t_ms > self._newest_ms:
            self._newest_ms = t_ms
        if self._first is None:
            self._first = (t_ms / 1000.0, now_s)
        self.counters.accepted += 1
        return True

    def _add_esc(self, msg, now_s: float) -> bool:
        fc_ms = self._newest_ms
        if fc_ms is None or self._esc is not None and fc_ms <= round(self._esc.time_s * 1000.0):
            self.counters.stale += 1          # no FC instant to stamp it with, or none newer than the last
            return False
        self._esc = EscSample(time_s=fc_ms / 1000.0, rpm=_array(msg.rpm),
                              current_a=_array([a / 100.0 for a in msg.current]),
                              voltage_v=_array([v / 100.0 if v > 0 else math.nan for v in msg.voltage]))
        self._esc_received_s = now_s
        self.counters.accepted += 1
        return True

    def clear(self) -> None:
        """Forget every stream (the FC rebooted: its clock started over)."""
        self._samples.clear()
        self._esc = self._esc_received_s = self._first = self._newest_ms = None

    def stale(self, limit_s: float) -> tuple[int, ...]:
        """The needed streams (named by the first message of NEEDED, and ESC_TELEMETRY) that are
        more than limit_s behind the newest of any on the FC's clock and on ours; one never
        received counts from the first sample of any."""
        if self._first is None:
            return ()
        newest_fc_s = self._newest_ms / 1000.0
        if self._fresh_on_fc_clock(newest_fc_s, limit_s):
            return ()
        newest_s = max(x.received_s for x in self._samples.values())
        out = []
        for ids in NEEDED:
            got = [self._samples[i] for i in ids if i in self._samples]
            fc_s, ours_s = (max(x.time_ms for x in got) / 1000.0, max(x.received_s for x in got)) if got else self._first
            if newest_fc_s - fc_s > limit_s and newest_s - ours_s > limit_s:
                out.append(ids[0])
        if self._esc is not None and newest_fc_s - self._esc.time_s > limit_s and \
                newest_s - self._esc_received_s > limit_s:
            out.append(ESC_TELEMETRY)
        return tuple(out)

    def _fresh_on_fc_clock(self, newest_fc_s: float, limit_s: float) -> bool:
        """Every needed stream (and the ESC telemetry, once some came) within limit_s of the
        newest instant on the FC's clock: none is stale, whatever our clock says (as `stale` finds
        with fewer steps: the oldest stream's newest instant decides). It names NEEDED's streams
        by hand: a test leaves out each of NEEDED in turn and expects it found."""
        s = self._samples
        att, quat, pos, joints, thr = s.get(ATTITUDE), s.get(ATTITUDE_QUATERNION), s.get(LOCAL_POSITION), \
            s.get(JOINT_STATE), s.get(THRUSTER_STATUS)
        if pos is None or joints is None or thr is None or att is None and quat is None:
            return False
        att_ms = quat.time_ms if att is None else att.time_ms if quat is None else max(att.time_ms, quat.time_ms)
        oldest_ms = min(att_ms, pos.time_ms, joints.time_ms, thr.time_ms)
        return newest_fc_s - oldest_ms / 1000.0 <= limit_s and \
            (self._esc is None or newest_fc_s - self._esc.time_s <= limit_s)

    def last_received_s(self) -> float | None:
        return max((s.received_s for s in self._samples.values()), default=None)

    def snapshot(self) -> VehicleSnapshot | None:
        """None until position, joints, thrusters and an attitude (either message) have come."""
        s = self._samples
        att, quat = s.get(ATTITUDE), s.get(ATTITUDE_QUATERNION)
        if att is None and quat is None or any(i not in s for i in (LOCAL_POSITION, JOINT_STATE, THRUSTER_STATUS)):
            return None
        if att is not None and (quat is None or att.time_ms >= quat.time_ms):
            euler, rates = att.values
            euler = _array(euler)
        else:
            quat_wxyz, rates = quat.values
            euler = euler_from_quat_wxyz(quat_wxyz)
        (pos, vel), (hip, hip_rate), (cmd, limit) = s[LOCAL_POSITION].values, s[JOINT_STATE].values, \
            s[THRUSTER_STATUS].values
        return VehicleSnapshot(self._newest_ms, {i: sample.time_ms for i, sample in s.items()}, euler, _array(rates),
                               _array(pos), _array(vel), _array(hip), _array(hip_rate), _array(cmd), _array(limit),
                               self._esc)


def _array(values: tuple[float, ...]) -> np.ndarray:
    return np.array(values, dtype=float)


def rom_state(snap: VehicleSnapshot, com: ComOffset) -> np.ndarray:
    """The NMPC's state (20) from a snapshot: centre of mass position and velocity (NED), on
    floats (the rotations too: numpy's matrix product, through OpenBLAS, fuses its multiplies
    and adds and rounds the last bit otherwise, at a few times the cost); an angle that is not
    finite gives NaN, as numpy's cosine does."""
    euler, rates = snap.euler_rad.tolist(), snap.rates_frd_rad_s.tolist()
    hip, hip_rate = snap.hip_rad.tolist(), snap.hip_rate_rad_s.tolist()
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = rotation_rows(*(f(a) if math.isfinite(a) else math.nan
                                                               for a in euler for f in (math.cos, math.sin)))
    (r0, r1, r2), (d0, d1, d2) = com.offset_and_rate(hip, hip_rate)
    w0, w1, w2 = rates
    m0, m1, m2 = w1 * r2 - w2 * r1 + d0, w2 * r0 - w0 * r2 + d1, w0 * r1 - w1 * r0 + d2     # the offset's motion
    (p0, p1, p2), (v0, v1, v2) = snap.pos_ned_m.tolist(), snap.vel_ned_m_s.tolist()
    return np.array([p0 + (a0 * r0 + a1 * r1 + a2 * r2), p1 + (b0 * r0 + b1 * r1 + b2 * r2),
                     p2 + (c0 * r0 + c1 * r1 + c2 * r2), *euler, *hip,
                     v0 + (a0 * m0 + a1 * m1 + a2 * m2), v1 + (b0 * m0 + b1 * m1 + b2 * m2),
                     v2 + (c0 * m0 + c1 * m1 + c2 * m2), *rates, *hip_rate])         # rom_layout's order
