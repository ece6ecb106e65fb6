"""The simulated flight controller's parameters (component 1), as a ground station sees them.

Failsafe timeouts, the two fast loops, the FC's own ESC check for a lost rotor and the
telemetry rates; the names follow ArduPilot's (FS_ for failsafes, SR_ for stream rates, M4_
for what is the M4's own). Every one but FS_LAND_SPEED may change in flight: each getter and
setter reaches the object that uses the value at its next tick. The table, the units and the
ranges: docs/parameters.md.
"""

from __future__ import annotations

from collections.abc import Callable

from m4.mavlink import mavlink
from m4.params import Param, ParamTable
from m4.params import ParamType as T
from sitl.fc.failsafe import LAND_SPEED_M_S

m = mavlink
STREAM_RATE_MAX_HZ = 500.0           # 2 ms: the FC's clock counts whole milliseconds
# Stream rate parameters: name, message (the FC's streams but HEARTBEAT, which stays at 1 Hz).
STREAMS = (
    ("SR_CURRENT_MODE", m.MAVLINK_MSG_ID_CURRENT_MODE),
    ("SR_SYS_STATUS", m.MAVLINK_MSG_ID_SYS_STATUS),
    ("SR_EXT_SYS_STATE", m.MAVLINK_MSG_ID_EXTENDED_SYS_STATE),
    ("SR_GLOBAL_POS", m.MAVLINK_MSG_ID_GLOBAL_POSITION_INT),
    ("SR_ACTUATOR", m.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS),
    ("SR_ATTITUDE", m.MAVLINK_MSG_ID_ATTITUDE),
    ("SR_ATTITUDE_Q", m.MAVLINK_MSG_ID_ATTITUDE_QUATERNION),
    ("SR_LOCAL_POS", m.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    ("SR_JOINT_STATE", m.MAVLINK_MSG_ID_M4_JOINT_STATE),
    ("SR_THRUSTER", m.MAVLINK_MSG_ID_M4_THRUSTER_STATUS),
)
ESC_STREAM = ("SR_ESC_TELEM", m.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4)


def _switch(obj, attr: str) -> dict:
    return dict(get=lambda: float(getattr(obj, attr)), set=lambda v: setattr(obj, attr, bool(v)))


def _scaled(obj, attr: str, per_unit: float) -> dict:
    """A value kept in other units (ms for s): the attribute holds value x per_unit, rounded."""
    return dict(get=lambda: getattr(obj, attr) / per_unit, set=lambda v: setattr(obj, attr, round(v * per_unit)))


def _stream(fc, msg_id: int, now_ms: Callable[[], int]) -> dict:
    """A stream's rate in Hz (0: stopped), as MAV_CMD_SET_MESSAGE_INTERVAL sets it: read on the
    companion's link, set on every link (the command sets the sender's link alone)."""
    def get() -> float:
        interval = fc.schedule.interval_ms(msg_id)
        return 0.0 if interval is None else 1000.0 / interval

    def set_(hz: float) -> None:
        for schedule in fc.schedules:
            schedule.set_interval_us(msg_id, 1e6 / hz if hz > 0 else -1, now_ms())
    return dict(get=get, set=set_)


def fc_params(fc, now_ms: Callable[[], int]) -> ParamTable:
    """The parameters of FlightController `fc` (sitl/fc/flight_controller.py); now_ms: its clock."""
    watch, af = fc.rotor_watch, fc.airframe
    params = [
        Param("FS_SP_TIMEOUT", T.REAL32, 0.1, 1.0, "s", "setpoints stale (HOLD) this long after the instant they "
              "answer, at the least (3 periods if longer)", **_scaled(fc, "stale_min_ms", 1000.0)),
        Param("FS_LAND_DELAY", T.REAL32, 0.0, 30.0, "s", "HOLD this long before the failsafe lands",
              get=lambda: fc.failsafe.land_after_s, set=lambda v: setattr(fc.failsafe, "land_after_s", v)),
        Param("FS_LAND_SPEED", T.REAL32, LAND_SPEED_M_S, LAND_SPEED_M_S, "m/s", "the failsafe's descent speed",
              get=lambda: LAND_SPEED_M_S, read_only_why="the companion's landing joins the FC's at this speed "
                                             "(m4/mission_plan.py FC_LAND_SPEED_M_S)"),
        Param("M4_RATE_FB_ENA", T.INT8, 0, 1, "", "fly M4_SETPOINT's rate feedback (0: its thrust_n alone)",
              **_switch(fc, "rate_feedback_enabled")),
        Param("M4_SF_COVER_ENA", T.INT8, 0, 1, "", "fly M4_SETPOINT's shortfall cover",
              **_switch(fc, "shortfall_cover_enabled")),
        Param("M4_ESC_CHK", T.INT8, 0, 1, "", "the FC's own lost-rotor check on its ESCs' speed",
              **_switch(watch, "enabled")),
        Param("M4_ESC_CHK_THR", T.REAL32, 0.5, af.thrust_max_n, "N", "checked only above this command",
              get=lambda: watch.min_command_n, set=lambda v: setattr(watch, "min_command_n", v)),
        Param("M4_ESC_CHK_FRAC", T.REAL32, 0.1, 0.9, "", "lost below this share of the commanded speed",
              get=lambda: watch.slow_fraction, set=lambda v: setattr(watch, "slow_fraction", v)),
        Param("M4_ESC_CHK_TIME", T.REAL32, 0.02, 1.0, "s", "lost after this long slow",
              **_scaled(watch, "confirm_ms", 1000.0)),
    ]
    streams = STREAMS + ((ESC_STREAM,) if fc.esc is not None else ())
    params += [Param(name, T.REAL32, 0.0, STREAM_RATE_MAX_HZ, "Hz", f"{m.mavlink_map[msg_id].msgname} rate "
                     "(0: stopped)", **_stream(fc, msg_id, now_ms)) for name, msg_id in streams]
    return ParamTable(params)
