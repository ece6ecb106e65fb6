"""The metrics a tlog alone gives (metrics.json of `m4-companion plot`): what the flight
controller measured and what the companion did, no simulator truth.

One vocabulary with `m4-sitl fly` (sitl.flights.metrics): a key both write means the same
thing, measured from the same instant. Positions are the hull's (the IMU's,
LOCAL_POSITION_NED) unless the companion's log holds its centre of mass and reference
(NAMED_VALUE_FLOAT com_*, ref_*). Definitions as sitl.flights.metrics (analysis.measures):
- faults: those the log carries (the FC's announcements, accepted commands) and those given,
  each with its detection as analysis.detection defines it (detected_at_s, detected_rotor,
  latency_s), judged against the ceiling the fault's kind and loss state for the airframe's
  hover thrust;
- measured_from: where "after the fault" starts, {"what", "at_s"}: the first fault; without
  one, the companion's first confirmation ("first confirmation": the earliest instant the log
  shows a fault); without either, the log's start;
- altitude_loss_m: largest drop after it below the reference altitude (the companion's, when
  logged; else the altitude there);
- max_tilt_deg_after_fault, tilt_recovered_s (within 10 deg to the end), yaw_rate_final_rad_s
  (mean over the last second), time_to_yaw_saturation_s (from the first total rotor loss, else
  from measured_from);
- max_thrust_n: the largest thrust the FC sent an ESC after it (M4_THRUSTER_STATUS: no FC
  measures delivered thrust; fly's is the simulator's true thrust);
- nmpc: rate_hz (of the setpoints), solve_ms_median, solve_ms_p99, solve_failures (null
  when the log has no NMPC decisions: not the companion's own log);
- position_rmse_m of the centre of mass against the reference, when both are logged.
A tlog's own: confirmations (each fault the companion confirmed: at_s, rotor, kind),
first_confirmation_s, max_thrust_commanded_n (M4_SETPOINT), setpoints, step_latency_ms
(median, p99, max), critical_messages.
"""

from __future__ import annotations

import numpy as np

from analysis import detection
from analysis.detection import Fault, stated_ceiling_n
from analysis.measures import tilt_deg, tilt_recovered_s, time_to_yaw_saturation, yaw_rate_final
from analysis.tlog_reader import FlightRecord, Series
from m4.airframe import Airframe
from m4.mavlink import mavlink


def detections(record: FlightRecord, faults: list[Fault], hover_thrust_per_rotor_n: float) -> list[dict]:
    """Each fault and its detection (analysis.detection), against the ceiling its kind and loss state."""
    fs = record.fault_state
    ceilings_n = [stated_ceiling_n(f, hover_thrust_per_rotor_n) for f in faults]
    return detection.detections(faults, ceilings_n, hover_thrust_per_rotor_n, fs.time_s, fs.values[:, 0],
                                fs.values[:, 1], fs.values[:, 2:6])


def _stats(series: Series | None) -> dict | None:
    if series is None or not len(series):
        return None
    v = series.values[:, 0]
    return {"median": float(np.median(v)), "p99": float(np.percentile(v, 99)), "max": float(np.max(v))}


def _after(series: Series, from_s: float) -> np.ndarray:
    return series.values[series.time_s >= from_s]


def _reference_altitude(record: FlightRecord, from_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(times, reference altitude below which a drop counts), NED down positive."""
    ref = record.named.get("ref_d")
    if ref is not None and len(ref):
        return ref.time_s, ref.values[:, 0]
    pos = record.position_ned_m
    k = min(int(np.searchsorted(pos.time_s, from_s)), len(pos) - 1)
    return pos.time_s, np.full(len(pos), pos.values[k, 2])


def _position_rmse(record: FlightRecord) -> float | None:
    parts = [record.named.get(f"{kind}_{axis}") for kind in ("com", "ref") for axis in "ned"]
    if any(p is None or not len(p) for p in parts):
        return None
    n = min(len(p) for p in parts)
    com = np.column_stack([p.values[:n, 0] for p in parts[:3]])
    ref = np.column_stack([p.values[:n, 0] for p in parts[3:]])
    return float(np.sqrt(np.mean(np.sum((com - ref) ** 2, axis=1))))


def measured_from(record: FlightRecord, faults: list[Fault]) -> dict:
    """Where "after the fault" starts: {"what": "fault" | "first confirmation" | "start of the log", "at_s"}."""
    if faults:
        return {"what": "fault", "at_s": faults[0].at_s}
    status = record.fault_state
    confirmed_s = detection.first_confirmation_s(status.time_s, status.values[:, 0])
    if confirmed_s is not None:
        return {"what": "first confirmation", "at_s": confirmed_s}
    return {"what": "start of the log", "at_s": float(record.position_ned_m.time_s[0])}


def _nmpc(record: FlightRecord) -> dict:
    """fly's nmpc summary from the companion's logged decisions (null values without them)."""
    solve, ok, setpoints = record.named.get("nmpc_ms"), record.named.get("nmpc_ok"), record.setpoint_thrust_n
    span_s = float(setpoints.time_s[-1] - setpoints.time_s[0]) if len(setpoints) > 1 else 0.0
    stats = _stats(solve)
    return {"rate_hz": (len(setpoints) - 1) / span_s if span_s > 0 else None,
            "solve_ms_median": None if stats is None else stats["median"],
            "solve_ms_p99": None if stats is None else stats["p99"],
            "solve_failures": None if ok is None else int(np.count_nonzero(ok.values[:, 0] == 0))}


def telemetry_metrics(record: FlightRecord, faults: list[Fault], af: Airframe) -> dict:
    """Every metric a tlog gives (see the module's docstring) of a flight of the airframe `af`."""
    pos, att, rates, status = record.position_ned_m, record.euler_rad, record.rates_frd_rad_s, record.fault_state
    if not len(pos) or not len(att):
        raise ValueError("no LOCAL_POSITION_NED or ATTITUDE from the flight controller in this tlog")
    origin = measured_from(record, faults)
    start_s = origin["at_s"]
    spin_s = next((f.at_s for f in faults if f.loss >= 1.0), start_s)
    ref_t, ref_d = _reference_altitude(record, start_s)
    after = pos.time_s >= start_s
    drop = pos.values[after, 2] - np.interp(pos.time_s[after], ref_t, ref_d)
    tilt = tilt_deg(att.values)
    yaw_rate = rates.values[:, 2]
    final = yaw_rate_final(rates.time_s, yaw_rate, float(rates.time_s[-1]))
    return {
        "duration_s": record.duration_s,
        "faults": detections(record, faults, af.hover_thrust_per_rotor_n),
        "measured_from": origin,
        "altitude_loss_m": float(max(np.max(drop, initial=0.0), 0.0)),
        "max_tilt_deg_after_fault": float(np.max(tilt[att.time_s >= start_s], initial=0.0)),
        "tilt_recovered_s": tilt_recovered_s(att.time_s, tilt, start_s, len(att) - 1),
        "position_rmse_m": _position_rmse(record),
        "yaw_rate_final_rad_s": final,
        "time_to_yaw_saturation_s": time_to_yaw_saturation(rates.time_s, yaw_rate, spin_s, final),
        "max_thrust_n": float(np.nanmax(_after(record.thrust_cmd_n, start_s), initial=0.0)),
        "nmpc": _nmpc(record),
        "confirmations": [{"at_s": t_s, "rotor": rotor, "kind": kind} for t_s, rotor, kind in record.confirmations()],
        "first_confirmation_s": detection.first_confirmation_s(status.time_s, status.values[:, 0]),
        "max_thrust_commanded_n": float(np.max(_after(record.setpoint_thrust_n, start_s), initial=0.0)),
        "setpoints": len(record.setpoint_thrust_n),
        "step_latency_ms": _stats(record.named.get("step_ms")),
        "critical_messages": [text for _, _, severity, text in record.statustext
                              if severity <= mavlink.MAV_SEVERITY_CRITICAL],
    }
