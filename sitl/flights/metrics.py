"""The metrics of one flight (metrics.json), from its records: pure functions of arrays.

Definitions (times in the scenario's clock, positions of the centre of mass, NED):
- airborne window: from t = 0 to the first ground contact after the landing started (the
  touchdown), or to the end of the record when there is none.
- crashed: a ground contact before the landing started (any contact when the mission has
  no landing), or the robot upside down (tilt > 90 deg) while airborne.
- reference: the companion's mission reference (companion.core.reference) rebuilt offline
  from the true start position, with the hold placed where the companion confirmed the
  first fault (when the mission holds on a fault).
- altitude_loss_m: largest drop of the centre of mass below the reference's altitude over
  the airborne window after the first fault (the whole window when nothing fails).
- max_tilt_deg_after_fault: largest angle between body z and the vertical over the same span.
- tilt_recovered_s: time after the first fault from which the tilt stays within
  analysis.measures.TILT_RECOVERED_DEG to the end of the airborne window (None: it never does).
- yaw_rate_final_rad_s: mean body yaw rate over the last YAW_FINAL_WINDOW_S before the
  landing starts (or the end of the airborne window); time_to_yaw_saturation_s: from the
  first total rotor loss (else the first fault) until |yaw rate| first reaches
  YAW_SATURATION_FRACTION of its final value
  (None when the final rate is below YAW_SPIN_MIN_RAD_S: the robot does not spin).
- faults[i].detected_at_s, detected_rotor, latency_s: analysis.detection's rule (the tlog's
  metrics use it too): the first instant in [at_s, the next later fault's at_s) at which the
  companion's fault status is confirmed with a thrust estimate on the named rotor that reflects this fault:
  at most the ceiling the fault leaves the rotor (its kind and loss, sitl.plant.thrusters.fault_ceiling_n:
  0 for a stopped motor or a lost propeller, (1 - loss) x hover thrust for a degraded motor,
  about (1 - loss) x the rotor's limit for a damaged propeller) + DETECTION_MARGIN x hover
  thrust. The detection campaign takes its detections from here.
- realtime_factor: simulated seconds per wall second of the plant process, from its first
  answered control instant to the end.
- link (added by sitl.flights.fly): the companion's link as flown: delay_ms each way, loss, mode
  ("lockstep": emulated in simulated time by the SITL; "proxy": sitl/links/netem_proxy.py in real time;
  "none") and setpoint_lead_ms, the median lead the companion measured (None: unmeasured).
"""

from __future__ import annotations

import numpy as np

from analysis import detection
from analysis.measures import rounded, tilt_deg, tilt_recovered_s, time_to_yaw_saturation, yaw_rate_final
from m4.airframe import Airframe
from m4.mission_plan import MissionPlan
from m4.scenario import Scenario
from sitl.flights.records import FaultStatusLog, NmpcLog
from sitl.plant.thrusters import fault_ceiling_n
from sitl.plant.truth import Truth

TILT_UPSIDE_DOWN_DEG = 90.0
COMPLETE_TOLERANCE_S = 0.05
AT_REST_SPEED_M_S = 0.2
TOUCHDOWN_WINDOW_S = 0.2
# Survival: what every built-in scenario must achieve.
ALTITUDE_LOSS_MAX_M = 0.5
TOUCHDOWN_SPEED_MAX_M_S = 1.0


def touchdown_index(time_s: np.ndarray, on_ground: np.ndarray, land_s: float | None) -> int | None:
    """First contact at or after the start of the landing (None: no landing or no contact)."""
    if land_s is None:
        return None
    hits = np.flatnonzero(on_ground & (time_s >= land_s))
    return int(hits[0]) if hits.size else None


def crashed(time_s: np.ndarray, on_ground: np.ndarray, tilt: np.ndarray, land_s: float | None,
            airborne_end: int) -> bool:
    early = on_ground if land_s is None else on_ground & (time_s < land_s)
    return bool(np.any(early) or np.any(tilt[:airborne_end + 1] > TILT_UPSIDE_DOWN_DEG))


def touchdown_speed_m_s(time_s: np.ndarray, vel_ned_m_s: np.ndarray, touchdown: int | None) -> float | None:
    """Fastest descent (m/s, >= 0) over the TOUCHDOWN_WINDOW_S before the first contact of the
    landing: one sample of a spinning robot's hull can be caught bobbing up."""
    if touchdown is None:
        return None
    start = int(np.searchsorted(time_s, time_s[touchdown] - TOUCHDOWN_WINDOW_S))
    return float(max(np.max(vel_ned_m_s[start:touchdown + 1, 2]), 0.0))


def reference_positions(scenario: Scenario, af: Airframe, time_s: np.ndarray, com_ned_m: np.ndarray,
                        hold_detected_s: float | None) -> np.ndarray:
    """(n, 3) the mission reference at each sample."""
    ref = MissionPlan(scenario.mission, com_ned_m[0], af, t0_s=float(time_s[0]))
    if hold_detected_s is not None:
        k = int(np.searchsorted(time_s, hold_detected_s))
        ref.fault_detected(hold_detected_s, com_ned_m[min(k, len(time_s) - 1)])
    return np.array([ref.state(t)[0] for t in time_s])


def altitude_loss_m(time_s: np.ndarray, com_z_ned_m: np.ndarray, ref_z_ned_m: np.ndarray, from_s: float,
                    airborne_end: int) -> float:
    span = slice(int(np.searchsorted(time_s, from_s)), airborne_end + 1)
    drop = com_z_ned_m[span] - ref_z_ned_m[span]            # NED: positive is below the reference
    return float(max(np.max(drop, initial=0.0), 0.0))


def detection_faults(scenario: Scenario) -> list[detection.Fault]:
    """The scenario's faults as analysis.detection (and a tlog's metrics) take them."""
    return [detection.Fault(f.at_s, f.rotor, f.loss, f.kind.label, f.until_s) for f in scenario.faults]


def detections(scenario: Scenario, status: FaultStatusLog, af: Airframe) -> list[dict]:
    """The scenario's faults and their detections (analysis.detection), each judged against the
    ceiling the plant's motor model says the fault leaves its rotor."""
    faults = detection_faults(scenario)
    ceilings_n = [fault_ceiling_n(af, f.loss, f.kind, scenario.plant.thrust_max_n) for f in scenario.faults]
    return detection.detections(faults, ceilings_n, af.hover_thrust_per_rotor_n, status.time_s, status.state,
                                status.rotor, status.thrust_max_estimate_n)


def nmpc_summary(nmpc: NmpcLog) -> dict:
    n = len(nmpc.time_s)
    if n == 0:
        return {"rate_hz": None, "solve_ms_median": None, "solve_ms_p99": None, "solve_failures": None}
    span = nmpc.time_s[-1] - nmpc.time_s[0]
    return {"rate_hz": float((n - 1) / span) if span > 0 else None,
            "solve_ms_median": float(np.median(nmpc.solve_ms)),
            "solve_ms_p99": float(np.percentile(nmpc.solve_ms, 99)),
            "solve_failures": int(np.count_nonzero(~nmpc.ok))}


def realtime_factor(time_s: np.ndarray, wall_s: np.ndarray) -> float | None:
    if len(time_s) < 3 or wall_s[-1] <= wall_s[1]:
        return None
    return float((time_s[-1] - time_s[1]) / (wall_s[-1] - wall_s[1]))


def reference_track(scenario: Scenario, af: Airframe, truth: Truth, status: FaultStatusLog) -> np.ndarray:
    """(n, 3) the mission reference at each truth sample, the hold where the companion confirmed the fault."""
    hold_s = detection.first_confirmation_s(status.time_s, status.state) if scenario.faults else None
    return reference_positions(scenario, af, truth.time_s, truth.com_ned_m, hold_s)


def flight_metrics(scenario: Scenario, controller: str, af: Airframe, truth: Truth, ref_ned_m: np.ndarray,
                   status: FaultStatusLog, nmpc: NmpcLog) -> dict:
    """Every key of metrics.json (docs/interfaces.md) and the survival checks; ref_ned_m: reference_track()."""
    t, com, ref = truth.time_s, truth.com_ned_m, ref_ned_m
    tilt = tilt_deg(truth.euler_rad)
    land_s = scenario.mission.land.at_s if scenario.mission.land is not None else None
    touchdown = touchdown_index(t, truth.on_ground, land_s)
    end = touchdown if touchdown is not None else len(t) - 1
    fault_s = scenario.faults[0].at_s if scenario.faults else float(t[0])
    spin_s = next((f.at_s for f in scenario.faults if f.loss >= 1.0), fault_s)
    yaw_until = min(land_s, float(t[end])) if land_s is not None else float(t[end])
    yaw_final = yaw_rate_final(t, truth.rates_frd_rad_s[:, 2], yaw_until)
    after = slice(int(np.searchsorted(t, fault_s)), end + 1)
    airborne = slice(0, end + 1)
    at_rest = bool(truth.on_ground[-1] and np.linalg.norm(truth.vel_ned_m_s[-1]) < AT_REST_SPEED_M_S)
    m = {
        "scenario": scenario.name,
        "controller": controller,
        "completed": bool(t[-1] >= scenario.duration_s - COMPLETE_TOLERANCE_S),
        "crashed": crashed(t, truth.on_ground, tilt, land_s, end),
        "duration_s": float(t[-1]),
        "faults": detections(scenario, status, af),
        "altitude_loss_m": altitude_loss_m(t, com[:, 2], ref[:, 2], fault_s, end),
        "max_tilt_deg_after_fault": float(np.max(tilt[after])),
        "tilt_recovered_s": tilt_recovered_s(t, tilt, fault_s, end),
        "position_rmse_m": float(np.sqrt(np.mean(np.sum((com[airborne] - ref[airborne]) ** 2, axis=1)))),
        "yaw_rate_final_rad_s": yaw_final,
        "time_to_yaw_saturation_s": time_to_yaw_saturation(t, truth.rates_frd_rad_s[:, 2], spin_s, yaw_final),
        "max_thrust_n": float(np.max(truth.thrust_n[after])),
        "landed": touchdown is not None and at_rest,
        "touchdown_speed_m_s": touchdown_speed_m_s(t, truth.vel_ned_m_s, touchdown),
        "nmpc": nmpc_summary(nmpc),
        "realtime_factor": realtime_factor(t, truth.wall_s),
        "wind": wind_summary(scenario, truth),
    }
    m["checks"] = survival_checks(m, land_s is not None)
    m["survived"] = all(m["checks"].values())
    return rounded(m)


def wind_summary(scenario: Scenario, truth: Truth) -> dict | None:
    """The scenario's [wind] and the air the robot met (truth); None in still air."""
    w = scenario.wind
    if w is None:
        return None
    air = truth.wind_ned_m_s
    return {"mean_ned_m_s": list(w.mean_ned_m_s), "turbulence": w.turbulence, "gusts": len(w.gusts),
            "air_std_ned_m_s": air.std(axis=0).tolist(),
            "air_speed_max_m_s": float(np.max(np.linalg.norm(air, axis=1)))}


def survival_checks(m: dict, lands: bool) -> dict[str, bool]:
    checks = {
        "completed": m["completed"],
        "no_ground_contact_before_landing": not m["crashed"],
        "altitude_loss_within_0.5_m": m["altitude_loss_m"] <= ALTITUDE_LOSS_MAX_M,
        "tilt_back_within_10_deg": m["tilt_recovered_s"] is not None,
    }
    if lands:
        checks["soft_landing"] = bool(m["landed"] and m["touchdown_speed_m_s"] is not None
                                      and m["touchdown_speed_m_s"] <= TOUCHDOWN_SPEED_MAX_M_S)
    return checks
