"""A flight's tlog read back into arrays on the flight controller's clock.

What the FC measured (LOCAL_POSITION_NED, ATTITUDE, M4_JOINT_STATE, M4_THRUSTER_STATUS,
ESC_TELEMETRY_1_TO_4: component 1), what the companion commanded and decided (M4_SETPOINT,
M4_FAULT_STATUS and the NAMED_VALUE_FLOAT of its flight log: component 191), STATUSTEXT from
either, and the faults applied:
- announced by the FC (its STATUSTEXT "rotor 4 motor stop injected", m4.fault_text: the
  simulated FC says it for a command's fault and a scenario's alike, so the companion's own
  log carries them), at the instant of the FC's next stamped message (it says it just
  before the frame of the instant it applies the fault);
- else injected by a command the log holds (MAV_CMD_INJECT_FAILURE: a motor stop;
  MAV_CMD_M4_ROTOR_LOSS with its kind; once the FC accepted them): a ground station's command
  is in the FC's tlog, not in the companion's.
A restore ends the fault open on its rotor (until_s). Times are the FC's time_boot_ms in
seconds; a message without one (STATUSTEXT, ESC_TELEMETRY_1_TO_4, a command) takes the newest
FC instant logged before it. Repeats of an instant (a lockstep frame sent again) are dropped.
Bytes that make no whole record (a file cut short, or garbled) are counted, not read.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from analysis.detection import Fault
from m4.fault_kind import FaultKind, rotor_loss_kind
from m4.fault_text import read_fault_text
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, mavlink, mavutil
from m4.mavlink.tlog import TLOG_TIME

m = mavlink
SAME_FAULT_S = 0.1                # a command and the FC's announcement of it, this close: one fault
CENTIAMPERE_A = 0.01


@dataclass(frozen=True)
class Series:
    time_s: np.ndarray             # (n,)
    values: np.ndarray             # (n, k)

    @classmethod
    def of(cls, rows: list[tuple[float, list[float]]], width: int) -> Series:
        if not rows:
            return cls(np.zeros(0), np.zeros((0, width)))
        t = np.array([r[0] for r in rows])
        v = np.array([r[1] for r in rows], dtype=float).reshape(len(rows), width)
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        keep = np.concatenate(([True], np.diff(t) > 0))
        return cls(t[keep], v[keep])

    def __len__(self) -> int:
        return len(self.time_s)


@dataclass(frozen=True)
class FlightRecord:
    position_ned_m: Series         # LOCAL_POSITION_NED x, y, z (the hull, as the FC measures it)
    velocity_ned_m_s: Series
    euler_rad: Series              # ATTITUDE roll, pitch, yaw
    rates_frd_rad_s: Series
    hip_rad: Series                # M4_JOINT_STATE (measured)
    thrust_cmd_n: Series           # M4_THRUSTER_STATUS: what the FC sent its ESCs (clamped, or its failsafe's)
    thrust_limit_n: Series
    esc_rpm: Series                # ESC_TELEMETRY_1_TO_4: each ESC's measured speed
    esc_current_a: Series
    setpoint_thrust_n: Series      # M4_SETPOINT (commanded by the companion)
    setpoint_hip_rad: Series
    fault_state: Series            # M4_FAULT_STATUS: state, rotor, thrust_max_estimate_n[4], kind (M4_FAULT_KIND)
    named: dict[str, Series] = field(default_factory=dict)     # the companion's NAMED_VALUE_FLOAT
    statustext: list[tuple[float, int, int, str]] = field(default_factory=list)   # (t, component, severity, text)
    injected: list[Fault] = field(default_factory=list)
    unread_bytes: int = 0          # not in a whole record (a file cut short, or garbled)

    @property
    def duration_s(self) -> float:
        return float(self.position_ned_m.time_s[-1]) if len(self.position_ned_m) else 0.0

    def confirmations(self) -> list[tuple[float, int, str]]:
        """(instant, rotor, kind) of each fault the companion confirmed: its M4_FAULT_STATUS
        turning CONFIRMED, or naming another rotor while confirmed."""
        fs, out, named = self.fault_state, [], None
        for t_s, state, rotor, kind in zip(fs.time_s, *fs.values[:, [0, 1, 6]].astype(int).T):
            confirmed = rotor if state == m.M4_FAULT_STATE_CONFIRMED else None
            if confirmed is not None and confirmed != named:
                out.append((float(t_s), int(rotor), FaultKind(kind).label if kind in set(FaultKind) else "unknown"))
            named = confirmed
        return out


_INJECT = (m.MAV_CMD_INJECT_FAILURE, m.MAV_CMD_M4_ROTOR_LOSS)


def _commanded_fault(cmd, t_s: float) -> Fault | None:
    if cmd.command == m.MAV_CMD_M4_ROTOR_LOSS:
        kind = rotor_loss_kind(cmd.param3)
        return Fault(t_s, int(cmd.param1), float(cmd.param2), "unknown" if kind is None else kind.label)
    if cmd.param1 == m.FAILURE_UNIT_SYSTEM_MOTOR and cmd.param2 in (m.FAILURE_TYPE_OFF, m.FAILURE_TYPE_OK):
        return Fault(t_s, int(cmd.param3), 1.0 if cmd.param2 == m.FAILURE_TYPE_OFF else 0.0, "motor")
    return None


def _announced_fault(text: str, t_s: float) -> Fault | None:
    said = read_fault_text(text)
    return None if said is None else Fault(t_s, said.rotor, said.loss, said.kind.label)


def applied_faults(announced: list[Fault], commanded: list[Fault]) -> list[Fault]:
    """The faults in time order: every one the FC announced, and a command's it did not (none
    of its announcements on that rotor within SAME_FAULT_S); each restore closes the faults
    open on its rotor (until_s) instead of counting as one."""
    events = sorted([*announced, *(c for c in commanded if not any(
        a.rotor == c.rotor and abs(a.at_s - c.at_s) <= SAME_FAULT_S for a in announced))], key=lambda f: f.at_s)
    faults: list[Fault] = []
    for event in events:
        if event.loss > 0.0:
            faults.append(event)
            continue
        faults = [replace(f, until_s=event.at_s) if f.until_s is None and event.rotor in (0, f.rotor) else f
                  for f in faults]
    return faults


def read_tlog(path: str | Path) -> FlightRecord:
    """Every series of the flight in the tlog at `path` (OSError when it cannot be read)."""
    rows: dict[str, list] = {k: [] for k in ("pos", "vel", "att", "rates", "hip", "thrust", "limit", "sp_thrust",
                                             "sp_hip", "fault", "rpm", "current")}
    named: dict[str, list] = {}
    texts, announced, unstamped, commanded, pending = [], [], [], [], {}
    now_s, whole_bytes = 0.0, 0
    conn = mavutil.mavlink_connection(str(path), dialect="m4")
    try:
        while (msg := conn.recv_match()) is not None:
            kind, comp = msg.get_type(), msg.get_srcComponent()
            if kind == "BAD_DATA":
                continue
            whole_bytes += TLOG_TIME.size + len(msg.get_msgbuf())
            t = getattr(msg, "time_boot_ms", None)
            t_s = now_s if t is None else t / 1000.0
            if comp == FC_COMPONENT_ID and t is not None:
                now_s = max(now_s, t_s)
                announced += [replace(fault, at_s=t_s) for fault in unstamped]
                unstamped.clear()
            if kind == "LOCAL_POSITION_NED" and comp == FC_COMPONENT_ID:
                rows["pos"].append((t_s, [msg.x, msg.y, msg.z]))
                rows["vel"].append((t_s, [msg.vx, msg.vy, msg.vz]))
            elif kind == "ATTITUDE" and comp == FC_COMPONENT_ID:
                rows["att"].append((t_s, [msg.roll, msg.pitch, msg.yaw]))
                rows["rates"].append((t_s, [msg.rollspeed, msg.pitchspeed, msg.yawspeed]))
            elif kind == "M4_JOINT_STATE" and comp == FC_COMPONENT_ID:
                rows["hip"].append((t_s, list(msg.hip_angle_rad)))
            elif kind == "M4_THRUSTER_STATUS" and comp == FC_COMPONENT_ID:
                rows["thrust"].append((t_s, list(msg.thrust_cmd_n)))
                rows["limit"].append((t_s, list(msg.thrust_limit_n)))
            elif kind == "ESC_TELEMETRY_1_TO_4" and comp == FC_COMPONENT_ID:
                rows["rpm"].append((t_s, list(msg.rpm)))
                rows["current"].append((t_s, [CENTIAMPERE_A * c for c in msg.current]))
            elif kind == "M4_SETPOINT" and comp == COMPANION_COMPONENT_ID:
                rows["sp_thrust"].append((t_s, list(msg.thrust_n)))
                rows["sp_hip"].append((t_s, list(msg.hip_angle_rad)))
            elif kind == "M4_FAULT_STATUS" and comp == COMPANION_COMPONENT_ID:
                rows["fault"].append((t_s, [msg.state, msg.rotor, *msg.thrust_max_estimate_n, msg.kind]))
            elif kind == "NAMED_VALUE_FLOAT" and comp == COMPANION_COMPONENT_ID:
                named.setdefault(msg.name, []).append((t_s, [msg.value]))
            elif kind == "STATUSTEXT":
                texts.append((t_s, comp, msg.severity, msg.text))
                if comp == FC_COMPONENT_ID and (fault := _announced_fault(msg.text, t_s)) is not None:
                    unstamped.append(fault)          # the FC says it before the frame of the instant it applies it
            elif kind in ("COMMAND_LONG", "COMMAND_INT") and msg.command in _INJECT and msg.target_component in (
                    0, FC_COMPONENT_ID):
                pending[msg.command] = (msg, t_s)
            elif kind == "COMMAND_ACK" and msg.command in pending and msg.result == m.MAV_RESULT_ACCEPTED:
                fault = _commanded_fault(*pending.pop(msg.command))
                if fault is not None:
                    commanded.append(fault)
        announced += unstamped
        size = conn.f.seek(0, os.SEEK_END)
    finally:
        conn.close()
    return FlightRecord(
        position_ned_m=Series.of(rows["pos"], 3), velocity_ned_m_s=Series.of(rows["vel"], 3),
        euler_rad=Series.of(rows["att"], 3), rates_frd_rad_s=Series.of(rows["rates"], 3),
        hip_rad=Series.of(rows["hip"], 4), thrust_cmd_n=Series.of(rows["thrust"], 4),
        thrust_limit_n=Series.of(rows["limit"], 4), esc_rpm=Series.of(rows["rpm"], 4),
        esc_current_a=Series.of(rows["current"], 4), setpoint_thrust_n=Series.of(rows["sp_thrust"], 4),
        setpoint_hip_rad=Series.of(rows["sp_hip"], 4), fault_state=Series.of(rows["fault"], 7),
        named={name: Series.of(r, 1) for name, r in named.items()}, statustext=texts,
        injected=applied_faults(announced, commanded), unread_bytes=size - whole_bytes)
