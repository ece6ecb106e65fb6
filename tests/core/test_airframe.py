import math

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.toml_fields import ConfigError


def test_reference_airframe_has_the_design_numbers():
    af = load_airframe()
    assert af.total_mass_kg == pytest.approx(6.0)
    assert af.hover_thrust_per_rotor_n == pytest.approx(6.0 * 9.81 / 4)
    assert af.rotor_names == ("front-right", "rear-left", "front-left", "rear-right")
    assert af.spin_sign == (1, 1, -1, -1)
    assert af.same_side_pairs == ((0, 3), (1, 2))


def test_thrusters_fold_forward_and_backward_at_zero_and_point_sideways_at_ninety():
    af = load_airframe()
    folded = af.thruster_positions_frd_m(np.zeros(4))
    assert folded[0, :2] == pytest.approx([0.15 + 0.22, 0.10])      # front-right points forward
    assert folded[1, :2] == pytest.approx([-0.15 - 0.22, -0.10])    # rear-left points backward
    out = af.thruster_positions_frd_m(np.full(4, math.pi / 2))
    assert out[2, :2] == pytest.approx([0.15, -0.10 - 0.22])        # front-left points left
    assert out[3, :2] == pytest.approx([-0.15, 0.10 + 0.22])        # rear-right points right


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_a_hip_angle_that_is_not_finite_has_no_thruster_position():
    af = load_airframe()
    hub = af.thruster_positions_frd_m([math.inf, -math.inf, math.nan, af.nominal_hip_rad])
    assert np.all(np.isnan(hub[:3, :2])) and np.all(np.isfinite(hub[3]))
    assert np.all(np.isnan(af.com_offset_rate_frd_m_s([math.inf, 0.0, 0.0, 0.0], np.ones(4))[:2]))


def test_symmetric_posture_keeps_the_centre_of_mass_at_the_hull_centre():
    af = load_airframe()
    assert af.com_offset_frd_m(np.full(4, 0.6)) == pytest.approx(np.zeros(3), abs=1e-12)


def _write_airframe(tmp_path, old, new):
    from importlib import resources
    text = (resources.files("m4.airframes") / "m4_reference.toml").read_text()
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.parametrize("old,new,message", [
    ("length_m = 0.22", "length_m = -0.22", "[leg] length_m must be > 0"),
    ("mass_kg = 4.4", "mass_kg = \"heavy\"", "[body] mass_kg must be a number"),
    ("moment_coefficient_m = 0.02", "moment_coefficient_m = 0.02\nmoment_coef = 1", "unknown key(s) moment_coef"),
    ('spin = ["ccw", "ccw", "cw", "cw"]', 'spin = ["ccw", "ccw", "cw"]', "spin must be a list of 4 strings"),
])
def test_bad_airframe_files_are_rejected_naming_the_key(tmp_path, old, new, message):
    with pytest.raises(ConfigError) as err:
        load_airframe(_write_airframe(tmp_path, old, new))
    assert message in str(err.value)


def test_missing_airframe_file_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        load_airframe(tmp_path / "nope.toml")
