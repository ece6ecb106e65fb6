"""Real-time factor of the plant alone: `python -m benchmarks.plant`.

1 kHz physics, a command every 20 ms (the control rate of the MAVLink setpoints) and a state
read after each. Two loads: hips held (hover), and hips always moving (the four legs swept
in phase, which keeps the servo reference shaping busy and, with the centre of mass staying
centred and the legs' yaw reactions cancelling, keeps the open-loop robot hovering instead of
tumbling onto the floor). Target: >= 50x real time on one core.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from m4.airframe import ROTOR_COUNT, load_airframe
from m4.arguments import positive_number
from sitl.plant.mujoco_plant import Plant

COMMAND_PERIOD_S = 0.02
TARGET_FACTOR = 50.0
SWEEP_HZ = 0.5


def real_time_factor(sim_s: float, move_hips: bool) -> float:
    af = load_airframe()
    plant = Plant(af, start_ned_m=(0.0, 0.0, -10.0))
    thrust = np.full(ROTOR_COUNT, plant.hover_thrust_n)
    centre = af.nominal_hip_rad
    amplitude = 0.5 * min(af.hip_max_rad - centre, centre - af.hip_min_rad)
    n = round(sim_s / COMMAND_PERIOD_S)
    start = time.perf_counter()
    for k in range(n):
        arg = np.full(ROTOR_COUNT, 2 * np.pi * SWEEP_HZ * k * COMMAND_PERIOD_S)
        hips = centre + amplitude * np.sin(arg) if move_hips else np.full(ROTOR_COUNT, centre)
        rates = amplitude * 2 * np.pi * SWEEP_HZ * np.cos(arg) if move_hips else None
        plant.command(thrust, hips, rates)
        plant.step(COMMAND_PERIOD_S)
        state = plant.state()
    if state.on_ground:
        raise RuntimeError("the benchmark's robot reached the floor: the load is not the flight it means to time")
    return n * COMMAND_PERIOD_S / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.plant", description=__doc__.splitlines()[0])
    parser.add_argument("--sim-s", type=positive_number, default=20.0, help="simulated seconds per load (default 20)")
    args = parser.parse_args(argv)
    for label, move in (("hips held", False), ("hips sweeping", True)):
        factor = real_time_factor(args.sim_s, move)
        verdict = "ok" if factor >= TARGET_FACTOR else f"BELOW the {TARGET_FACTOR:.0f}x target"
        print(f"plant at 1 kHz, commands every {COMMAND_PERIOD_S * 1e3:.0f} ms, {label}: "
              f"{factor:.0f}x real time ({verdict})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
