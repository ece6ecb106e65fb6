"""The mission in time: where the centre of mass should be at each instant.

The mission (m4.mission.Mission) becomes a plan: a time-ordered list of pieces, each
giving position and velocity (local NED, centre of mass) as a function of time.

- A leg to a waypoint is a straight line flown with a trapezoidal speed profile: accelerate
  at accel_max_m_s2 up to the leg's speed, cruise, decelerate to stop on the waypoint (a
  short leg peaks lower). Velocity is continuous everywhere, so the NMPC never sees a step.
- At each waypoint the plan stays hold_s, then the next leg starts; after the last one it
  holds for ever.
- A fault with on_fault = "hold" replaces the rest of the plan by a brake from the measured
  position along the reference velocity at accel_max_m_s2 (no instant stop) and a hold where
  the brake ends. "continue" changes nothing. A fault during the landing changes nothing.
- From land.at_s (without one: when the last waypoint's hold ends, as first planned) the plan
  brakes (when it is moving) and descends at descent_speed_m_s to the ground, where the centre
  of mass sits ground_com_height_m above z = 0; from there it sinks on at LANDING_SINK_M_S
  until the touchdown (the companion's thrust cut ends it): a robot that tracks the plan a few
  centimetres high (a disturbance estimate's bias, a controller that closes the last gap
  slowly) still meets the ground, at a touchdown speed of about the sink's, instead of
  hovering just above it.
- `item` says which waypoint (or the landing) the plan is on: the progress a mission from a
  ground station reports (m4.mission_items).
- `land_from`: the flight controller's failsafe is landing when the companion takes over (a
  restart, a return after a loss): from then the plan descends from where the robot is, at
  the mission's descent speed (the FC's own 0.5 m/s without a [mission.land]), whatever it
  planned before, its own landing included.

`progress` is what a restarted companion needs to make the same plan again: where and when it
started and the last change (fault hold or landing). The companion sends it with its fault
status, the flight controller keeps it (M4_FAULT_STATUS), and `restore` applies it.

The companion's NMPC reference (`companion.core.reference`) and the simulator's metrics both
read this plan.
"""

from __future__ import annotations

import bisect
import enum
import math
from dataclasses import dataclass

import numpy as np

from m4.airframe import Airframe
from m4.mission import Mission

DEFAULT_ACCEL_MAX_M_S2 = 2.0    # the reference's acceleration limit unless the companion's config says otherwise
FC_LAND_SPEED_M_S = 0.5         # the flight controller's failsafe descent (mavlink_defs/README.md, Failsafe)
LANDING_SINK_M_S = 0.1          # the landing's descent below the ground's height, until the touchdown


class PlanState(enum.IntEnum):
    """How the plan stands (the wire's M4_MISSION_STATE: same numbers)."""
    NONE = 0              # no plan: the flight has not started
    AS_PLANNED = 1        # the mission as planned from its start
    FAULT_HOLD = 2        # a fault turned the rest into a brake and a hold from the change
    LANDING = 3           # landing from the change, with the flight controller's failsafe


@dataclass(frozen=True)
class PlanProgress:
    """What makes a plan again: its start and its last change (times on the mission's clock)."""
    state: PlanState
    start_time_s: float
    start_ned_m: tuple[float, float, float]
    change_time_s: float = 0.0                              # FAULT_HOLD, LANDING
    change_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class MissionProgress:
    """A plan and the mission's clock at one instant: where a restarted companion resumes."""
    time_s: float
    plan: PlanProgress


def ground_com_height_m(af: Airframe) -> float:
    """Height of the centre of mass above flat ground when the robot stands on it in the
    nominal flight posture.

    The lowest points of the robot in flight configuration are the hull's bottom face (half
    the hull height below the hull centre) and the wheels' lower faces (the wheels lie flat
    around the vertical thrust axis: half the wheel width below the hubs, which are level
    with the hips); the centre of mass sits com_offset_frd_m below the hull centre.
    """
    hip_z = np.array(af.hip_frd_m)[:, 2]
    lowest_frd_m = max(af.body_box_size_m[2] / 2, float(np.max(hip_z)) + af.wheel_width_m / 2)
    com_z = float(af.com_offset_frd_m(np.full(len(hip_z), af.nominal_hip_rad))[2])
    return lowest_frd_m - com_z


class _Hold:
    def __init__(self, t0_s: float, p_ned_m: np.ndarray):
        self.t0_s, self.end_s, self._p = t0_s, math.inf, np.array(p_ned_m, dtype=float)

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        return self._p.copy(), np.zeros(3)


class _Move:
    """Straight line p0 -> p1 from rest to rest: trapezoidal speed (triangular when short)."""

    def __init__(self, t0_s: float, p0: np.ndarray, p1: np.ndarray, speed_m_s: float, accel_m_s2: float):
        self._p0 = np.array(p0, dtype=float)
        delta = np.asarray(p1, dtype=float) - self._p0
        self._length = float(np.linalg.norm(delta))
        self._dir = delta / self._length if self._length > 0 else np.zeros(3)
        self._a = accel_m_s2
        self._v = min(speed_m_s, math.sqrt(accel_m_s2 * self._length))
        self._t_acc = self._v / accel_m_s2
        t_cruise = (self._length - self._v * self._t_acc) / self._v if self._v > 0 else 0.0
        self.t0_s = t0_s
        self.end_s = t0_s + 2 * self._t_acc + t_cruise

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        tau = min(max(t_s - self.t0_s, 0.0), self.end_s - self.t0_s)
        to_go = self.end_s - self.t0_s - tau
        if tau < self._t_acc:
            s, v = 0.5 * self._a * tau**2, self._a * tau
        elif to_go < self._t_acc:
            s, v = self._length - 0.5 * self._a * to_go**2, self._a * to_go
        else:
            s, v = 0.5 * self._a * self._t_acc**2 + self._v * (tau - self._t_acc), self._v
        return self._p0 + s * self._dir, v * self._dir


class _Sink:
    """Down from rest at p0 towards and into the ground: speeds up at accel_m_s2 to speed_m_s,
    then on at that speed for ever."""

    def __init__(self, t0_s: float, p0: np.ndarray, speed_m_s: float, accel_m_s2: float):
        self._p0, self._v, self._a = np.array(p0, dtype=float), speed_m_s, accel_m_s2
        self._t_acc = speed_m_s / accel_m_s2
        self.t0_s, self.end_s = t0_s, math.inf

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        tau = max(t_s - self.t0_s, 0.0)
        if tau < self._t_acc:
            s, v = 0.5 * self._a * tau**2, self._a * tau
        else:
            s, v = self._v * (tau - 0.5 * self._t_acc), self._v
        return self._p0 + np.array([0.0, 0.0, s]), np.array([0.0, 0.0, v])


class _Brake:
    """Constant deceleration along the initial velocity down to rest."""

    def __init__(self, t0_s: float, p0: np.ndarray, v0: np.ndarray, accel_m_s2: float):
        self._p0, self._speed = np.array(p0, dtype=float), float(np.linalg.norm(v0))
        self._dir = np.asarray(v0, dtype=float) / self._speed if self._speed > 0 else np.zeros(3)
        self._a = accel_m_s2
        self.t0_s, self.end_s = t0_s, t0_s + self._speed / accel_m_s2

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        tau = min(max(t_s - self.t0_s, 0.0), self.end_s - self.t0_s)
        s = self._speed * tau - 0.5 * self._a * tau**2
        return self._p0 + s * self._dir, (self._speed - self._a * tau) * self._dir


class _Plan:
    """Pieces in time order; at time t the last piece that started at or before t applies."""

    def __init__(self, pieces: list):
        self.pieces = pieces
        self._starts = [p.t0_s for p in pieces]

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        i = max(bisect.bisect_right(self._starts, t_s) - 1, 0)
        return self.pieces[i].state(t_s)

    def replaced_from(self, t_s: float, pieces: list) -> _Plan:
        return _Plan([p for p in self.pieces if p.t0_s < t_s] + pieces)


def stopping(t_s: float, p_ned_m, v_ned_m_s, accel_m_s2: float) -> _Plan:
    """From t_s a brake from p_ned_m along v_ned_m_s at accel_m_s2, then a hold where it ends:
    a fault's hold, and the companion's hold when the flight controller's mode is HOLD."""
    brake = _Brake(t_s, p_ned_m, v_ned_m_s, accel_m_s2)
    return _Plan([brake, _Hold(brake.end_s, brake.state(brake.end_s)[0])])


class MissionPlan:
    """The plan of a mission flown from start_ned_m (centre of mass) at t0_s, every speed
    change at accel_max_m_s2."""

    def __init__(self, mission: Mission, start_ned_m, af: Airframe,
                 accel_max_m_s2: float = DEFAULT_ACCEL_MAX_M_S2, t0_s: float = 0.0):
        self._mission, self._a = mission, accel_max_m_s2
        self.ground_com_z_ned_m = -ground_com_height_m(af)
        self._waypoint_done_s: list[float] = []     # when each waypoint's hold ends, as planned
        self._base = _Plan(self._mission_pieces(np.asarray(start_ned_m, dtype=float), t0_s))
        planned_end_s = self._waypoint_done_s[-1] if self._waypoint_done_s else t0_s
        self.land_at_s = None if mission.land is None else (
            planned_end_s if mission.land.at_s is None else mission.land.at_s)   # None: no landing
        self._plan = self._with_landing(self._base)
        self.fault_hold_s: float | None = None      # when a fault turned the plan into a hold
        self.landing_from_s: float | None = None    # when the plan joined the FC's landing
        self.progress = PlanProgress(PlanState.AS_PLANNED, t0_s, _ned(start_ned_m))

    def _mission_pieces(self, start: np.ndarray, t_s: float) -> list:
        pieces: list = []
        here = start
        for wp in self._mission.waypoints:
            move = _Move(t_s, here, np.array(wp.ned_m), wp.speed_m_s, self._a)
            here = np.array(wp.ned_m, dtype=float)
            pieces += [move, _Hold(move.end_s, here)]
            t_s = move.end_s + wp.hold_s
            self._waypoint_done_s.append(t_s)
        pieces.append(_Hold(t_s, here))
        return pieces

    def _stop(self, t_s: float, p_ned_m, v_ned_m_s) -> list:
        return stopping(t_s, p_ned_m, v_ned_m_s, self._a).pieces

    def _with_landing(self, base: _Plan) -> _Plan:
        land, at_s = self._mission.land, self.land_at_s
        if land is None:
            return base
        stop = self._stop(at_s, *base.state(at_s))
        above = stop[-1].state(stop[-1].t0_s)[0]
        ground = np.array([above[0], above[1], max(above[2], self.ground_com_z_ned_m)])
        descent = _Move(stop[-1].t0_s, above, ground, land.descent_speed_m_s, self._a)
        return base.replaced_from(at_s, stop[:-1] + [descent, self._sink(descent.end_s, ground)])

    def _sink(self, t_s: float, ground_ned_m: np.ndarray) -> _Sink:
        return _Sink(t_s, ground_ned_m, LANDING_SINK_M_S, self._a)

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(p_ned_m (3,), v_ned_m_s (3,)) of the reference at t_s."""
        return self._plan.state(t_s)

    def fault_detected(self, t_s: float, position_ned_m) -> None:
        """A fault was confirmed at t_s with the centre of mass at position_ned_m (the first
        call counts; later ones, and any during the landing, change nothing)."""
        if self._mission.on_fault != "hold" or self.landing_started(t_s) or self.fault_hold_s is not None:
            return
        self.fault_hold_s = t_s
        _, v_ned_m_s = self._base.state(t_s)
        self._base = self._base.replaced_from(t_s, self._stop(t_s, np.asarray(position_ned_m, dtype=float), v_ned_m_s))
        self._plan = self._with_landing(self._base)
        self._changed(PlanState.FAULT_HOLD, t_s, position_ned_m)

    def land_from(self, t_s: float, position_ned_m) -> None:
        """From t_s the plan descends from position_ned_m to the ground: the flight controller's
        failsafe was landing, the robot is where its landing brought it (lower than our own
        landing's plan, if we were landing before)."""
        land = self._mission.land
        above = np.asarray(position_ned_m, dtype=float)
        ground = np.array([above[0], above[1], max(above[2], self.ground_com_z_ned_m)])
        descent = _Move(t_s, above, ground, FC_LAND_SPEED_M_S if land is None else land.descent_speed_m_s, self._a)
        self._plan = self._plan.replaced_from(t_s, [descent, self._sink(descent.end_s, ground)])
        self.landing_from_s = t_s
        self._changed(PlanState.LANDING, t_s, position_ned_m)

    def restore(self, progress: PlanProgress) -> None:
        """The change a plan made from the same start had (a restarted companion's)."""
        if progress.state is PlanState.FAULT_HOLD:
            self.fault_detected(progress.change_time_s, progress.change_ned_m)
        elif progress.state is PlanState.LANDING:
            self.land_from(progress.change_time_s, progress.change_ned_m)

    def _changed(self, state: PlanState, t_s: float, position_ned_m) -> None:
        self.progress = PlanProgress(state, self.progress.start_time_s, self.progress.start_ned_m, t_s,
                                     _ned(position_ned_m))

    def landing_started(self, t_s: float) -> bool:
        if self.landing_from_s is not None and t_s >= self.landing_from_s:
            return True
        return self.land_at_s is not None and t_s >= self.land_at_s

    def item(self, t_s: float) -> int:
        """The mission's item flown at t_s: the index of the waypoint it flies to or holds at,
        len(waypoints) once every waypoint's hold is over or the landing started (the landing,
        if there is one). After a fault hold it stays the one the fault met."""
        if self.landing_started(t_s):
            return len(self._mission.waypoints)
        if self.fault_hold_s is not None:
            t_s = min(t_s, self.fault_hold_s)
        return bisect.bisect_right(self._waypoint_done_s, t_s)


def _ned(values) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in np.asarray(values, dtype=float).reshape(3))
    return x, y, z
