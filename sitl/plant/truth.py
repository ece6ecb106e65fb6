"""The plant's true state sampled on the simulated clock, saved as .npz for the flight metrics.

`m4-sitl serve --truth-log PATH` attaches a TruthRecorder to the vehicle: it samples the
plant every `period_ms` of simulated time (and at t = 0) with the wall clock beside it, and
writes the arrays on close. `load_truth` reads them back as a Truth of numpy arrays; every
array's first axis is the sample. Memory is bounded: a ring buffer keeps the last
`MAX_SAMPLES` samples (10 minutes at 100 Hz) and `dropped` counts what it let go.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import MISSING, dataclass, fields
from pathlib import Path

import numpy as np

from sitl.plant.mujoco_plant import Plant
from sitl.plant.state import PlantState

DEFAULT_PERIOD_MS = 10
MAX_SAMPLES = 60_000


@dataclass(frozen=True)
class Truth:
    time_s: np.ndarray             # (n,) simulated
    wall_s: np.ndarray             # (n,) monotonic wall clock of the SITL process
    pos_ned_m: np.ndarray          # (n, 3) hull centre
    com_ned_m: np.ndarray          # (n, 3) centre of mass of the whole robot
    vel_ned_m_s: np.ndarray        # (n, 3) hull centre
    euler_rad: np.ndarray          # (n, 3) roll, pitch, yaw (ZYX)
    rates_frd_rad_s: np.ndarray    # (n, 3)
    hip_rad: np.ndarray            # (n, 4)
    thrust_cmd_n: np.ndarray       # (n, 4)
    thrust_n: np.ndarray           # (n, 4) delivered
    thrust_limit_n: np.ndarray     # (n, 4)
    on_ground: np.ndarray          # (n,) bool: any contact with the floor
    # Every rotor's truth (None in a truth log written before the plant had them):
    rotor_speed_rad_s: np.ndarray | None = None   # (n, 4)
    esc_current_a: np.ndarray | None = None       # (n, 4) drawn from the pack
    fault_kind: np.ndarray | None = None          # (n, 4) int: m4.fault_kind.FaultKind, -1 healthy
    battery_voltage_v: np.ndarray | None = None   # (n,)
    wind_ned_m_s: np.ndarray | None = None        # (n, 3) the air's velocity at the robot; None: still air (no [wind])


_FROM_STATE = tuple(f.name for f in fields(Truth) if f.name not in ("time_s", "wall_s"))   # PlantState's names
_OPTIONAL = frozenset(f.name for f in fields(Truth) if f.default is not MISSING)


class TruthRecorder:
    def __init__(self, period_ms: int = DEFAULT_PERIOD_MS, max_samples: int = MAX_SAMPLES):
        self.period_ms = period_ms
        self.dropped = 0
        self._next_ms = 0
        # (time_s, wall_s, the plant's state) a sample: the states are read-only (Plant.state), so
        # they are kept whole and taken apart into columns once, by truth(), not in the loop
        self._samples: deque[tuple[float, float, PlantState]] = deque(maxlen=max_samples)

    def observe(self, now_ms: int, plant: Plant) -> None:
        """Called at every simulated instant; samples when the next grid point is reached."""
        if now_ms < self._next_ms:
            return
        self._next_ms = (now_ms // self.period_ms + 1) * self.period_ms
        samples = self._samples
        self.dropped += len(samples) == samples.maxlen
        samples.append((now_ms / 1000.0, time.monotonic(), plant.state()))

    def truth(self) -> Truth:
        samples = self._samples
        rows = {"time_s": [t for t, _, _ in samples], "wall_s": [wall for _, wall, _ in samples]}
        for name in _FROM_STATE:
            values = [getattr(s, name) for _, _, s in samples]
            present = next((v for v in values if v is not None), None)
            if present is None:            # a still-air plant has no wind: that array is left out
                rows[name] = []
            else:                          # the air came later (Plant.blow): still air at the samples before
                rows[name] = [np.zeros_like(present) if v is None else v for v in values]
        return Truth(**{name: np.array(values) for name, values in rows.items() if values or name not in _OPTIONAL})

    def save(self, path: str | Path) -> None:
        t = self.truth()
        np.savez_compressed(Path(path), **{f.name: getattr(t, f.name) for f in fields(Truth)
                                           if getattr(t, f.name) is not None})


def load_truth(path: str | Path) -> Truth:
    with np.load(Path(path)) as data:
        return Truth(**{f.name: data[f.name] for f in fields(Truth) if f.name in data or f.default is MISSING})


def truth_differences(before: Truth, after: Truth) -> dict[str, float | None]:
    """The arrays of two truths that are not the same to the bit (NaN equal to NaN; the wall
    clock aside), each with its largest difference (None: one lacks it or their shapes differ)."""
    found: dict[str, float | None] = {}
    for f in fields(Truth):
        a, b = getattr(before, f.name), getattr(after, f.name)
        if f.name == "wall_s" or (a is None and b is None):
            continue
        if a is None or b is None or a.shape != b.shape:
            found[f.name] = None
        elif not np.array_equal(a, b, equal_nan=True):
            found[f.name] = float(np.nanmax(np.abs(a.astype(float) - b.astype(float))))
    return found
