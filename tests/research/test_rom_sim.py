"""The ROM closed-loop harness: faults, caps, delays and mismatch do what they say."""

import numpy as np
import pytest

from m4.airframe import load_airframe
from companion.core import rom
from companion.core.nmpc import Nmpc
from research.rom_sim import (
    PlantMismatch,
    RotorFault,
    SimConfig,
    hold_reference,
    simulate,
    thrust_limits,
)

AF = load_airframe()


def test_a_fault_lowers_one_rotor_to_its_share_of_hover_thrust_from_its_time_on():
    sim = SimConfig(duration_s=1.0, faults=(RotorFault(at_s=0.5, index=2, loss=0.66),), thrust_cap_n=24.0)
    assert thrust_limits(AF, sim, 0.4) == pytest.approx([24.0] * 4)
    after = thrust_limits(AF, sim, 0.5)
    assert after[2] == pytest.approx(0.34 * AF.hover_thrust_per_rotor_n)
    assert thrust_limits(AF, sim, 0.6, delay_s=0.2)[2] == pytest.approx(24.0)


def test_mismatch_scales_the_mass_and_inertia_of_the_plant():
    heavy = PlantMismatch(mass_scale=1.1, inertia_scale=0.9).airframe(AF)
    assert heavy.total_mass_kg == pytest.approx(1.1 * AF.total_mass_kg)
    assert heavy.body_inertia_diag_kg_m2[0] == pytest.approx(AF.body_inertia_diag_kg_m2[0] * 1.1 * 0.9)


def test_the_plant_delivers_no_thrust_from_a_dead_rotor_even_before_the_controller_knows():
    nmpc = Nmpc(AF)
    x0 = rom.hover_state(AF)
    sim = SimConfig(duration_s=0.6, control_period_s=0.1, faults=(RotorFault(0.2, 0, 1.0),), known_delay_s=0.2)
    log = simulate(nmpc, x0, hold_reference(x0, nmpc.config.horizon), sim)
    unaware = (log.t_s >= 0.2) & (log.t_s < 0.4)
    assert np.all(log.thrust_max_known_n[unaware, 0] == AF.thrust_max_n)
    assert np.all(log.u[unaware, 0] > 1.0)                     # it still commands the dead rotor
    assert np.all(log.thrust_delivered_n[log.t_s >= 0.2, 0] == 0.0)
    assert log.x.shape == (7, rom.NX) and log.u.shape == (6, rom.NU)
