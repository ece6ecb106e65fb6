"""The flight's figures (PNG, matplotlib's Agg backend: no display needed), like the paper's.

- trajectory.png: position of the centre of mass against the reference, roll and pitch, and
  yaw on a panel of its own (after a rotor loss it spins through thousands of degrees, which
  would flatten roll and pitch into a line);
- velocities_rates.png: body-frame velocities and angular rates;
- actuators.png: delivered thrust per rotor with its limit, and hip angles;
- snapshots.png: drawings of the robot from above and from the side at a few instants;
- model_matching.png (sitl.model_matching): the reduced-order model's open-loop prediction
  against the plant after rotor 4 stops.
Every time plot marks each fault (dashed) and its detection (dotted).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from m4.attitude import rotation_ned_from_frd
from sitl.model_matching import FAILED_ROTOR, MatchResult
from sitl.truth import Truth

ROTOR_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red")
SNAPSHOT_OFFSETS_S = (-0.5, 0.0, 0.3, 0.6, 1.0, 2.0)     # around the first fault
DPI = 110


def _mark_faults(ax, faults: list[dict]) -> None:
    for f in faults:
        ax.axvline(f["at_s"], color="crimson", ls="--", lw=1.0)
        if f.get("detected_at_s") is not None:
            ax.axvline(f["detected_at_s"], color="crimson", ls=":", lw=1.0)


def _finish(fig, axes, faults: list[dict], path: Path, title: str) -> Path:
    for ax in axes:
        _mark_faults(ax, faults)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title + "   (-- fault, ·· detected)")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def trajectory_figure(path: Path, title: str, truth: Truth, ref_ned_m: np.ndarray, faults: list[dict]) -> Path:
    t = truth.time_s
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True, height_ratios=(3, 3, 2))
    for i, (name, sign) in enumerate((("north", 1), ("east", 1), ("altitude", -1))):
        line, = axes[0].plot(t, sign * truth.com_ned_m[:, i], label=f"{name}")
        axes[0].plot(t, sign * ref_ned_m[:, i], ls="--", color=line.get_color(), lw=1, label=f"{name} ref")
    axes[0].set_ylabel("centre of mass (m)")
    axes[0].legend(ncol=3, fontsize=8)
    for i, name in enumerate(("roll", "pitch")):
        axes[1].plot(t, np.degrees(truth.euler_rad[:, i]), label=name)
    axes[1].set_ylabel("roll, pitch (deg)")
    axes[1].legend(fontsize=8)
    axes[2].plot(t, np.degrees(np.unwrap(truth.euler_rad[:, 2])), color="tab:green", label="yaw")
    axes[2].set_ylabel("yaw (deg, unwrapped)")
    axes[2].legend(fontsize=8)
    return _finish(fig, axes, faults, path, title)


def body_velocities(truth: Truth) -> np.ndarray:
    """(n, 3) velocity of the hull in the body frame FRD."""
    return np.array([rotation_ned_from_frd(e).T @ v for e, v in zip(truth.euler_rad, truth.vel_ned_m_s)])


def velocities_rates_figure(path: Path, title: str, truth: Truth, faults: list[dict]) -> Path:
    t = truth.time_s
    fig, axes = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    vel_frd_m_s = body_velocities(truth)
    for i, name in enumerate(("u (forward)", "v (right)", "w (down)")):
        axes[0].plot(t, vel_frd_m_s[:, i], label=name)
    axes[0].set_ylabel("body velocity (m/s)")
    axes[0].legend(fontsize=8)
    for i, name in enumerate(("p (roll)", "q (pitch)", "r (yaw)")):
        axes[1].plot(t, truth.rates_frd_rad_s[:, i], label=name)
    axes[1].set_ylabel("body rates (rad/s)")
    axes[1].legend(fontsize=8)
    return _finish(fig, axes, faults, path, title)


def actuators_figure(path: Path, title: str, truth: Truth, faults: list[dict]) -> Path:
    t = truth.time_s
    fig, axes = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for i in range(ROTOR_COUNT):
        c = ROTOR_COLOURS[i]
        axes[0].plot(t, truth.thrust_n[:, i], color=c, label=f"rotor {i + 1}")
        axes[0].plot(t, truth.thrust_limit_n[:, i], color=c, ls=":", lw=1)
        axes[1].plot(t, np.degrees(truth.hip_rad[:, i]), color=c, label=f"hip {i + 1}")
    axes[0].set_ylabel("delivered thrust (N)\n(dotted: limit)")
    axes[0].legend(ncol=4, fontsize=8)
    axes[1].set_ylabel("hip angle (deg)")
    axes[1].legend(ncol=4, fontsize=8)
    return _finish(fig, axes, faults, path, title)


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


def flight_figures(out_dir: Path, title: str, af: Airframe, truth: Truth, ref_ned_m: np.ndarray,
                   faults: list[dict]) -> list[Path]:
    out_dir = Path(out_dir)
    fault_s = faults[0]["at_s"] if faults else None
    return [trajectory_figure(out_dir / "trajectory.png", title, truth, ref_ned_m, faults),
            velocities_rates_figure(out_dir / "velocities_rates.png", title, truth, faults),
            actuators_figure(out_dir / "actuators.png", title, truth, faults),
            snapshots_figure(out_dir / "snapshots.png", title, af, truth, fault_s, {f["rotor"] for f in faults
                                                                                     if f["loss"] >= 1.0})]
