"""What a flight leaves behind, read back into arrays: the tlog, the feed and the truth.

- `read_fault_status`: the companion's M4_FAULT_STATUS messages from the tlog (both directions
  are in it; the flight controller's own streams are not needed here, the truth log has the
  real state).
- `read_feed`: the companion's Zenoh feed as recorded by `sitl.flights.feed_recorder` (one JSON object
  a line: {"key": ..., "payload": {...}}); the NMPC diagnostics as arrays; the setpoint lead
  the companion measured.
- `load_truth` (sitl.plant.truth): the plant's true state.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m4.airframe import ROTOR_COUNT
from m4.mavlink import COMPANION_COMPONENT_ID, mavutil


@dataclass(frozen=True)
class FaultStatusLog:
    """The companion's M4_FAULT_STATUS messages, in order."""

    time_s: np.ndarray                 # (n,) the telemetry instant each answers
    rotor: np.ndarray                  # (n,) 0 none, 1..4
    state: np.ndarray                  # (n,) 0 healthy, 1 suspect, 2 confirmed
    thrust_max_estimate_n: np.ndarray  # (n, 4)
    detected_s: np.ndarray             # (n,) detected_time_boot_ms in seconds (NaN while healthy)
    kind: np.ndarray                   # (n,) M4_FAULT_KIND: 0 unknown, 1 motor, 2 propeller, 3 damage, 4 degraded

    @classmethod
    def empty(cls) -> FaultStatusLog:
        return cls(np.zeros(0), np.zeros(0, int), np.zeros(0, int), np.zeros((0, ROTOR_COUNT)), np.zeros(0),
                   np.zeros(0, int))


@dataclass(frozen=True)
class NmpcLog:
    time_s: np.ndarray                 # (n,) telemetry instant of each solve
    solve_ms: np.ndarray               # (n,)
    ok: np.ndarray                     # (n,) bool

    @classmethod
    def empty(cls) -> NmpcLog:
        return cls(np.zeros(0), np.zeros(0), np.zeros(0, bool))


def read_fault_status(path: str | Path) -> FaultStatusLog:
    """The companion's M4_FAULT_STATUS messages in a flight's tlog."""
    log = mavutil.mavlink_connection(str(path))
    msgs = []
    try:
        while (msg := log.recv_match(type="M4_FAULT_STATUS", blocking=False)):
            if msg.get_srcComponent() == COMPANION_COMPONENT_ID:
                msgs.append(msg)
    finally:
        log.close()
    if not msgs:
        return FaultStatusLog.empty()
    return FaultStatusLog(
        time_s=np.array([m.time_boot_ms for m in msgs]) / 1000.0,
        rotor=np.array([m.rotor for m in msgs]),
        state=np.array([m.state for m in msgs]),
        thrust_max_estimate_n=np.array([m.thrust_max_estimate_n for m in msgs], dtype=float),
        detected_s=np.array([m.detected_time_boot_ms / 1000.0 if m.state else np.nan for m in msgs]),
        kind=np.array([m.kind for m in msgs]),
    )


def read_feed(path: str | Path) -> dict[str, list[dict]]:
    """The recorded feed's payloads by topic (the last chunk of the key), in arrival order.
    A missing file is an empty feed; a line cut short (the recorder stopped mid-write) is skipped."""
    topics: dict[str, list[dict]] = {}
    path = Path(path)
    if not path.exists():
        return topics
    for line in path.read_text().splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        topics.setdefault(entry["key"].rsplit("/", 1)[-1], []).append(entry["payload"])
    return topics


def nmpc_log(feed: dict[str, list[dict]]) -> NmpcLog:
    rows = [p for p in feed.get("nmpc", []) if p.get("t_s") is not None and p.get("solve_ms") is not None]
    if not rows:
        return NmpcLog.empty()
    return NmpcLog(time_s=np.array([p["t_s"] for p in rows], dtype=float),
                   solve_ms=np.array([p["solve_ms"] for p in rows], dtype=float),
                   ok=np.array([bool(p["ok"]) for p in rows], dtype=bool))


def setpoint_lead_ms(feed: dict[str, list[dict]]) -> float | None:
    """The median of the setpoint leads the companion published on its link topic (None: none)."""
    leads = [p["setpoint_lead_ms"] for p in feed.get("link", []) if p.get("setpoint_lead_ms") is not None]
    return float(np.median(leads)) if leads else None
