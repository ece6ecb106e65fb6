"""Measures of a flight's attitude and spin from arrays: the same definitions for the
simulator's truth (sitl.flights.metrics) and for any tlog (analysis.flight_metrics)."""

from __future__ import annotations

import numpy as np

TILT_RECOVERED_DEG = 10.0
YAW_FINAL_WINDOW_S = 1.0
YAW_SATURATION_FRACTION = 0.9
YAW_SPIN_MIN_RAD_S = 1.0


def tilt_deg(euler_rad: np.ndarray) -> np.ndarray:
    """Angle between body z and the vertical for ZYX Euler angles (n, 3)."""
    e = np.asarray(euler_rad, dtype=float).reshape(-1, 3)
    return np.degrees(np.arccos(np.clip(np.cos(e[:, 0]) * np.cos(e[:, 1]), -1.0, 1.0)))


def tilt_recovered_s(time_s: np.ndarray, tilt: np.ndarray, from_s: float, airborne_end: int) -> float | None:
    """Time after from_s from which the tilt stays within TILT_RECOVERED_DEG to airborne_end (None: never)."""
    span = np.arange(int(np.searchsorted(time_s, from_s)), airborne_end + 1)
    if span.size == 0 or tilt[span[-1]] > TILT_RECOVERED_DEG:
        return None
    above = span[tilt[span] > TILT_RECOVERED_DEG]
    return 0.0 if above.size == 0 else float(time_s[above[-1] + 1] - from_s)


def yaw_rate_final(time_s: np.ndarray, yaw_rate: np.ndarray, until_s: float) -> float:
    """Mean yaw rate over the YAW_FINAL_WINDOW_S before until_s."""
    keep = (time_s <= until_s) & (time_s > until_s - YAW_FINAL_WINDOW_S)
    return float(np.mean(yaw_rate[keep])) if np.any(keep) else 0.0


def time_to_yaw_saturation(time_s: np.ndarray, yaw_rate: np.ndarray, from_s: float, final: float) -> float | None:
    """From from_s until |yaw rate| first reaches YAW_SATURATION_FRACTION of `final` (None: no spin)."""
    if abs(final) < YAW_SPIN_MIN_RAD_S:
        return None
    hits = np.flatnonzero((time_s >= from_s) & (np.abs(yaw_rate) >= YAW_SATURATION_FRACTION * abs(final)))
    return float(time_s[hits[0]] - from_s) if hits.size else None


def rounded(value):
    """A metrics.json value with its floats to 4 decimals (a latency of 0.04 s, not 0.040000000000000036)."""
    if isinstance(value, float):
        return round(value, 4)
    if isinstance(value, dict):
        return {k: rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [rounded(v) for v in value]
    return value
