"""The simulator's own figures from synthetic truth: snapshot instants (the tlog figures: tests/analysis)."""

from __future__ import annotations

import numpy as np

from m4.airframe import load_airframe
from sitl.flights import figures
from sitl.plant.truth import Truth

AF = load_airframe()


def _truth(n=300, dt=0.01, yaw_rad=0.0, vel_ned=(0.0, 0.0, 0.0)) -> Truth:
    t = np.arange(n) * dt
    pos = np.tile([0.0, 0.0, -2.0], (n, 1))
    return Truth(time_s=t, wall_s=t, pos_ned_m=pos, com_ned_m=pos.copy(), vel_ned_m_s=np.tile(vel_ned, (n, 1)),
                 euler_rad=np.tile([0.0, 0.0, yaw_rad], (n, 1)), rates_frd_rad_s=np.zeros((n, 3)),
                 hip_rad=np.full((n, 4), AF.nominal_hip_rad), thrust_cmd_n=np.full((n, 4), 14.7),
                 thrust_n=np.full((n, 4), 14.7), thrust_limit_n=np.full((n, 4), AF.thrust_max_n),
                 on_ground=np.zeros(n, bool))


def test_snapshots_are_taken_around_the_first_fault_or_across_the_flight():
    truth = _truth()
    picks = figures.snapshot_instants(truth, fault_s=1.0)
    assert truth.time_s[picks[0]] == 0.5 and truth.time_s[picks[1]] == 1.0 and truth.time_s[picks[-1]] == 2.99
    spread = figures.snapshot_instants(truth, fault_s=None)
    assert spread[0] == 0 and spread[-1] == len(truth.time_s) - 1 and len(spread) == 6
