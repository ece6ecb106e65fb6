"""A simulated flight's figures (PNG, matplotlib's Agg backend: no display needed), like the paper's.

- trajectory, velocities_rates, actuators, yaw_rate: drawn from the flight's tlog by the same
  code as `m4-companion plot` (analysis.figures), the companion's own log when it wrote one
  (it holds the reference), else the SITL's flight.tlog; the faults marked where the scenario
  put them, their detection where sitl.flights.metrics found it;
- snapshots.png: drawings of the robot from above and from the side at a few instants (the
  simulator's truth);
- wind.png (analysis.figures): the companion's disturbance estimate; when the scenario has
  [wind], above it the air's velocity at the robot (truth) and below it the robot's speed over
  the ground and through the air;
- model_matching.png (sitl.flights.model_matching): the reduced-order model's open-loop prediction
  against the plant after rotor 4 stops.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from analysis.figures import ROTOR_COLOURS, draw
from analysis.tlog_reader import Series, read_tlog
from m4.airframe import ROTOR_COUNT, Airframe
from m4.attitude import rotation_ned_from_frd
from sitl.flights.flight_run import FlightFiles
from sitl.flights.model_matching import FAILED_ROTOR, MatchResult
from sitl.plant.truth import Truth

SNAPSHOT_OFFSETS_S = (-0.5, 0.0, 0.3, 0.6, 1.0, 2.0)     # around the first fault
DPI = 110


def snapshot_instants(truth: Truth, fault_s: float | None) -> list[int]:
    """Sample indices of the drawings: around the first fault, or spread over the flight."""
    t = truth.time_s
    times = [fault_s + dt for dt in SNAPSHOT_OFFSETS_S] if fault_s is not None else np.linspace(t[0], t[-1], 6)
    return sorted({int(np.clip(np.searchsorted(t, s), 0, len(t) - 1)) for s in times})


def _robot_lines(af: Airframe, pos_ned_m, euler_rad, hip_rad) -> tuple[np.ndarray, np.ndarray]:
    """Hull outline (5, 3) and thruster hubs (4, 3), local NED."""
    r = rotation_ned_from_frd(euler_rad)
    lx, ly, _ = np.array(af.body_box_size_m) / 2
    hull = np.array([[lx, ly, 0], [lx, -ly, 0], [-lx, -ly, 0], [-lx, ly, 0], [lx, ly, 0]])
    hubs = af.thruster_positions_frd_m(hip_rad)
    return pos_ned_m + hull @ r.T, pos_ned_m + hubs @ r.T


def snapshots_figure(path: Path, title: str, af: Airframe, truth: Truth, fault_s: float | None,
                     failed_rotors: set[int]) -> Path:
    picks = snapshot_instants(truth, fault_s)
    fig, axes = plt.subplots(2, len(picks), figsize=(2.6 * len(picks), 5.6), squeeze=False)
    hips = np.array(af.hip_frd_m)
    span = af.leg_length_m + np.linalg.norm(af.body_box_size_m[:2]) / 2 + 0.05
    for col, k in enumerate(picks):
        p, e, q = truth.pos_ned_m[k], truth.euler_rad[k], truth.hip_rad[k]
        hull, hubs = _robot_lines(af, p, e, q)
        hip_world = p + hips @ rotation_ned_from_frd(e).T
        failed = {i - 1 for i in failed_rotors} if fault_s is not None and truth.time_s[k] >= fault_s else set()
        for row, (h, v, hlabel, vlabel) in enumerate(((1, 0, "east (m)", "north (m)"),
                                                      (0, 2, "north (m)", "altitude (m)"))):
            ax = axes[row, col]
            sign = -1 if v == 2 else 1
            ax.plot(hull[:, h], sign * hull[:, v], color="k", lw=1.5)
            for i in range(ROTOR_COUNT):
                ax.plot([hip_world[i, h], hubs[i, h]], [sign * hip_world[i, v], sign * hubs[i, v]],
                        color=ROTOR_COLOURS[i], lw=2)
                ax.add_patch(plt.Circle((hubs[i, h], sign * hubs[i, v]), af.wheel_radius_m * 0.6,
                                        fill=i in failed, color="crimson" if i in failed else ROTOR_COLOURS[i],
                                        alpha=0.6))
            ax.set_xlim(p[h] - span, p[h] + span)
            ax.set_ylim(sign * p[v] - span, sign * p[v] + span)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
            ax.set_xlabel(hlabel, fontsize=8)
            if col == 0:
                ax.set_ylabel(("from above\n" if row == 0 else "from the side\n") + vlabel, fontsize=8)
        axes[0, col].set_title(f"t = {truth.time_s[k]:.2f} s", fontsize=9)
    fig.suptitle(title + "   (filled red: failed rotor)")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def model_matching_figure(path: Path, result: MatchResult) -> Path:
    t = result.time_s
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for i, name in enumerate(("north", "east", "down")):
        line, = axes[0].plot(t, result.plant_com_ned_m[:, i], label=f"{name} plant")
        axes[0].plot(t, result.rom_com_ned_m[:, i], ls="--", color=line.get_color(), label=f"{name} ROM")
    axes[0].set_ylabel("centre of mass NED (m)")
    axes[0].legend(ncol=3, fontsize=8)
    for i, name in enumerate(("roll", "pitch", "yaw")):
        line, = axes[1].plot(t, np.degrees(np.unwrap(result.plant_euler_rad[:, i])), label=f"{name} plant")
        axes[1].plot(t, np.degrees(np.unwrap(result.rom_euler_rad[:, i])), ls="--", color=line.get_color(),
                     label=f"{name} ROM")
    axes[1].set_ylabel("Euler angles (deg, unwrapped)")
    axes[1].legend(ncol=3, fontsize=8)
    axes[2].plot(t, result.position_error_m * 100, label="position error (cm)")
    axes[2].plot(t, np.degrees(result.attitude_error_rad), label="attitude error (deg)")
    axes[2].set_ylabel("error")
    axes[2].legend(fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel(f"time since rotor {FAILED_ROTOR} stopped (s)")
    e = result.errors_until(0.5)
    fig.suptitle(f"Model matching, open loop: over 0.5 s RMS {e['pos_rms_m'] * 100:.1f} cm, "
                 f"{e['att_rms_deg']:.1f} deg")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def flight_tlog(files: FlightFiles) -> Path:
    """The tlog the figures are drawn from: the companion's newest flight log, else the SITL's."""
    logs = sorted(files.companion_tlogs.glob("flight-*.tlog")) if files.companion_tlogs.is_dir() else []
    return logs[-1] if logs else files.tlog


def flight_figures(files: FlightFiles, title: str, af: Airframe, truth: Truth, faults: list[dict]) -> list[Path]:
    """Every figure of a flown flight into its folder; `faults`: metrics.json's."""
    fault_s = faults[0]["at_s"] if faults else None
    air = None if truth.wind_ned_m_s is None else Series(truth.time_s, truth.wind_ned_m_s)
    paths = draw(read_tlog(flight_tlog(files)), files.out_dir, title, faults, air=air)
    paths.append(snapshots_figure(files.out_dir / "snapshots.png", title, af, truth, fault_s,
                                  {f["rotor"] for f in faults if f["loss"] >= 1.0}))
    return paths
