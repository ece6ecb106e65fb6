"""The paper's model-matching result: the ROM's prediction against the plant after rotor 4 stops."""

import numpy as np

from m4.airframe import load_airframe
from sitl.flights.model_matching import compare


def test_rom_predicts_the_plant_after_a_rotor_loss_within_sane_bounds():
    result = compare(load_airframe(), duration_s=1.0)
    print()
    print(result.summary())
    short, horizon, full = result.errors_until(0.3), result.errors_until(0.5), result.errors_until(1.0)
    # Both tumble the same way: with rotor 4 (rear right) gone the right rear corner drops; in
    # FRD right side down is +roll and tail down (nose up) is +pitch.
    assert result.plant_euler_rad[20, 0] > 0.1 and result.rom_euler_rad[20, 0] > 0.1
    assert result.plant_euler_rad[20, 1] > 0.1 and result.rom_euler_rad[20, 1] > 0.1
    # Close over the first 0.3 s and over the NMPC's 0.5 s horizon; the tumble amplifies what
    # the ROM leaves out by 1 s.
    assert short["pos_rms_m"] < 0.005 and short["att_rms_deg"] < 2.5
    assert horizon["pos_rms_m"] < 0.01 and horizon["att_rms_deg"] < 8.0
    assert full["pos_max_m"] < 0.1
    # The models do differ (the legs' own inertia and reaction, servo compliance).
    assert short["att_max_deg"] > 0.5
    assert np.all(np.isfinite(result.position_error_m))
