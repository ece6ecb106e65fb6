"""Model matching (the paper's first experiment): the reduced-order model against the plant.

Both start hovering at rest at the nominal posture; at t = 0 rotor 4 is commanded off and the
other three keep the hover thrust, hips held (open loop). The ROM models the airframe given
the rotors' thrusts, so it is fed the thrust the plant's rotors deliver (rotor 4 spins down
through its motor lag; that lag is the actuator's, which the NMPC does not model either). The
ROM predicts the centre of mass and the attitude; the errors against the plant's truth
(distance, and the angle of the rotation between the two attitudes) are summarised as RMS and
max over growing horizons. Open loop the robot tumbles within the second, so what the ROM
leaves out (the legs' own inertia, the servos giving a little under load, the legs' reaction
on the body) grows with the tumble. `python -m sitl.flights.model_matching` prints them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe, load_airframe
from companion.core import rom
from sitl.plant.mujoco_plant import Plant

FAILED_ROTOR = 4
START_NED_M = (0.0, 0.0, -10.0)           # high enough that neither model meets the floor in 1 s
SUMMARY_HORIZONS_S = (0.1, 0.3, 0.5, 1.0)  # 0.5 s: the NMPC's horizon (5 x 0.1 s)


@dataclass(frozen=True)
class MatchResult:
    time_s: np.ndarray             # (n,) sample times
    rom_com_ned_m: np.ndarray      # (n, 3)
    plant_com_ned_m: np.ndarray    # (n, 3)
    rom_euler_rad: np.ndarray      # (n, 3) roll, pitch, yaw (ZYX)
    plant_euler_rad: np.ndarray    # (n, 3)

    @property
    def position_error_m(self) -> np.ndarray:
        return np.linalg.norm(self.rom_com_ned_m - self.plant_com_ned_m, axis=1)

    @property
    def attitude_error_rad(self) -> np.ndarray:
        """Angle of the rotation between the two attitudes (well defined through any tumble)."""
        out = []
        for a, b in zip(self.rom_euler_rad, self.plant_euler_rad):
            r = rom.rotation_ned_from_frd(a).T @ rom.rotation_ned_from_frd(b)
            out.append(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)))
        return np.array(out)

    def errors_until(self, t_s: float) -> dict[str, float]:
        """RMS and max of the position (m) and attitude (deg) errors over [0, t_s]."""
        keep = self.time_s <= t_s + 1e-9
        pos, ang = self.position_error_m[keep], np.degrees(self.attitude_error_rad[keep])
        return {"pos_rms_m": _rms(pos), "pos_max_m": float(pos.max()),
                "att_rms_deg": _rms(ang), "att_max_deg": float(ang.max())}

    def summary(self) -> str:
        lines = [f"ROM vs plant, rotor {FAILED_ROTOR} off at t = 0, hover thrust on the others, "
                 + "hips held (open loop, the ROM fed the delivered thrusts):"]
        for t in SUMMARY_HORIZONS_S:
            e = self.errors_until(t)
            lines.append(f"  over {t:.2f} s: centre of mass error RMS {e['pos_rms_m']:.3f} m, max "
                         f"{e['pos_max_m']:.3f} m; attitude error RMS {e['att_rms_deg']:.1f} deg, max "
                         f"{e['att_max_deg']:.1f} deg")
        return "\n".join(lines)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def compare(af: Airframe, duration_s: float = 1.0, sample_s: float = 0.01) -> MatchResult:
    plant = Plant(af, start_ned_m=START_NED_M)
    thrust = np.full(ROTOR_COUNT, af.hover_thrust_per_rotor_n)
    thrust[FAILED_ROTOR - 1] = 0.0
    hips = np.full(ROTOR_COUNT, af.nominal_hip_rad)
    plant.command(thrust, hips)

    step = rom.build_rom(af, sample_s).step
    start = plant.state()
    x = rom.hover_state(af, p_ned_m=start.com_ned_m, yaw_rad=start.euler_rad[2])
    u = rom.hover_input(af)
    d = np.zeros(rom.ND)

    n = round(duration_s / sample_s)
    times, rom_com, plant_com, rom_euler, plant_euler = [], [], [], [], []
    for k in range(n + 1):
        s = plant.state()
        times.append(s.time_s)
        rom_com.append(x[rom.P].copy())
        rom_euler.append(x[rom.EULER].copy())
        plant_com.append(s.com_ned_m)
        plant_euler.append(s.euler_rad)
        if k < n:
            plant.step(sample_s)
            u[rom.THRUST] = (s.thrust_n + plant.state().thrust_n) / 2     # delivered over the interval
            x = np.asarray(step(x, u, d)).ravel()
    return MatchResult(np.array(times), np.array(rom_com), np.array(plant_com),
                       np.array(rom_euler), np.array(plant_euler))


if __name__ == "__main__":
    print(compare(load_airframe()).summary())
