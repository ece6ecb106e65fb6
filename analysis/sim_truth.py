"""The air a simulated flight met, from the simulator's truth beside its log.

`m4-sitl fly --out DIR` writes DIR/truth.npz (sitl.plant.truth) beside DIR/flight.tlog and
DIR/companion-log/flight-*.tlog; with [wind] it holds `wind_ned_m_s`, the air's velocity at
the robot, at the simulator's instants `time_s` (the flight controller's clock). No robot
measures it: the figures label it as the simulator's truth. Read with numpy alone (no MuJoCo).
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from analysis.tlog_reader import Series

TRUTH_FILE = "truth.npz"


def truth_beside(tlog: Path) -> Path | None:
    """The truth.npz in the tlog's folder, or in the one above (the companion's log folder)."""
    for folder in (tlog.parent, tlog.parent.parent):
        if (folder / TRUTH_FILE).is_file():
            return folder / TRUTH_FILE
    return None


def air_velocity(truth_npz: Path) -> Series | None:
    """The air's velocity at the robot, NED m/s (None: the flight was in still air). A file numpy
    cannot read as the simulator's truth raises ValueError naming it."""
    try:
        with np.load(truth_npz) as data:
            if "wind_ned_m_s" not in data.files:
                return None
            return Series(np.asarray(data["time_s"], dtype=float), np.asarray(data["wind_ned_m_s"], dtype=float))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as e:
        raise ValueError(f"{truth_npz}: not the simulator's truth ({e})") from None
