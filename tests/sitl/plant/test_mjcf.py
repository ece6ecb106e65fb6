"""The generated MuJoCo model against the airframe file, and the scene stepping cleanly."""

import mujoco
import numpy as np
import pytest

from m4.airframe import ROTOR_COUNT, load_airframe
from sitl.plant import mjcf

AF = load_airframe()
FLIP = np.array([1.0, -1.0, -1.0])      # FRD <-> FLU, written out here on purpose


@pytest.fixture(scope="module")
def hover():
    model = mujoco.MjModel.from_xml_path(str(mjcf.MODEL_DIR / mjcf.SCENE_FILE))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("hover").id)
    mujoco.mj_forward(model, data)
    return model, data


def test_committed_model_files_equal_a_fresh_generation():
    assert (mjcf.MODEL_DIR / mjcf.ROBOT_FILE).read_text() == mjcf.robot_xml(AF)
    assert (mjcf.MODEL_DIR / mjcf.SCENE_FILE).read_text() == mjcf.scene_xml(AF)
    assert (mjcf.MODEL_DIR / mjcf.README_FILE).read_text() == mjcf.readme_md(AF)


def test_masses_are_the_airframe_lumps_and_add_up_to_the_total(hover):
    model, _ = hover
    assert model.body_subtreemass[model.body("hull").id] == pytest.approx(AF.total_mass_kg)
    assert AF.total_mass_kg == pytest.approx(6.0)
    assert model.body("hull").mass[0] == pytest.approx(AF.body_mass_kg)
    for n in range(1, ROTOR_COUNT + 1):
        assert model.body(f"hip{n}").mass[0] == pytest.approx(AF.leg_hip_block_mass_kg)
        assert model.body(f"leg{n}").mass[0] == pytest.approx(AF.leg_link_mass_kg)
        assert model.body(f"wheel{n}").mass[0] == pytest.approx(AF.leg_wheel_mass_kg)


def test_hull_inertia_is_the_airframe_one_about_the_hull_centre(hover):
    model, _ = hover
    hull = model.body("hull")
    assert hull.inertia == pytest.approx(AF.body_inertia_diag_kg_m2)
    assert hull.ipos == pytest.approx(np.zeros(3))
    assert hull.iquat == pytest.approx([1.0, 0.0, 0.0, 0.0])


def test_thrusters_sit_at_the_airframe_positions_in_the_hover_posture(hover):
    _, data = hover
    hull = data.body("hull")
    expected = AF.thruster_positions_frd_m(np.full(ROTOR_COUNT, AF.nominal_hip_rad))
    for i in range(ROTOR_COUNT):
        site = data.site(f"thrust{i + 1}")
        rel_flu = hull.xmat.reshape(3, 3).T @ (site.xpos - hull.xpos)
        assert FLIP * rel_flu == pytest.approx(expected[i], abs=1e-12)
        # Thrust axis of each site along body up.
        assert site.xmat.reshape(3, 3)[:, 2] == pytest.approx([0.0, 0.0, 1.0], abs=1e-12)


def test_lumps_sit_at_the_hip_mid_leg_and_leg_end(hover):
    _, data = hover
    q = np.full(ROTOR_COUNT, AF.nominal_hip_rad)
    ends = AF.thruster_positions_frd_m(q)
    hull = data.body("hull").xpos
    for i in range(ROTOR_COUNT):
        hip = np.array(AF.hip_frd_m[i])
        n = i + 1
        assert FLIP * (data.body(f"hip{n}").xipos - hull) == pytest.approx(hip, abs=1e-12)
        assert FLIP * (data.body(f"leg{n}").xipos - hull) == pytest.approx((hip + ends[i]) / 2, abs=1e-12)
        assert FLIP * (data.body(f"wheel{n}").xipos - hull) == pytest.approx(ends[i], abs=1e-12)


def test_thrust_actuators_have_the_rotor_lag_and_its_square_and_the_reaction_moment_sign(hover):
    model, _ = hover
    for i in range(ROTOR_COUNT):
        for name, tau in (("thrust", AF.motor_time_constant_s), ("thrustsq", AF.motor_time_constant_s / 2)):
            act = model.actuator(f"{name}{i + 1}")
            assert act.dynprm[0] == pytest.approx(tau)
            assert not model.actuator_ctrllimited[act.id]      # the rotor model (sitl/plant/thrusters.py) limits
            # Force along site +z (up); moment spin k_m T about FRD z, i.e. -spin k_m T about FLU z.
            assert act.gear == pytest.approx([0, 0, 1, 0, 0, -AF.spin_sign[i] * AF.moment_coefficient_m])


def test_hover_keyframe_holds_the_hover_thrust_and_nominal_posture(hover):
    _, data = hover
    for i in range(ROTOR_COUNT):
        assert data.actuator(f"thrust{i + 1}").ctrl[0] == pytest.approx(AF.hover_thrust_per_rotor_n)
        assert data.joint(f"sagittal{i + 1}").qpos[0] == pytest.approx(AF.nominal_hip_rad)
        assert data.joint(f"frontal{i + 1}").qpos[0] == 0.0


def test_scene_steps_with_random_inputs_without_any_mujoco_warning():
    model = mujoco.MjModel.from_xml_path(str(mjcf.MODEL_DIR / mjcf.SCENE_FILE))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("hover").id)
    rng = np.random.default_rng(7)
    lo, hi = model.actuator_ctrlrange.T
    limited = model.actuator_ctrllimited.astype(bool)
    for _ in range(100):
        data.ctrl[limited] = rng.uniform(lo[limited], hi[limited])
        mujoco.mj_step(model, data, nstep=20)
    assert all(w.number == 0 for w in data.warning), [w.number for w in data.warning]
    assert np.all(np.isfinite(data.qpos))


def test_sagittal_servo_gains_give_the_airframe_time_constant_on_the_leg_inertia(hover):
    model, _ = hover
    length = AF.leg_length_m
    inertia = (AF.leg_wheel_mass_kg * (length**2 + AF.wheel_radius_m**2 / 2)
               + AF.leg_link_mass_kg * ((length / 2) ** 2 + (3 * AF.link_radius_m**2 + length**2) / 12))
    omega = 1.0 / AF.servo_time_constant_s
    for n in range(1, ROTOR_COUNT + 1):
        assert model.actuator(f"hip{n}").gainprm[0] == pytest.approx(inertia * omega**2)
        assert model.actuator(f"hiprate{n}").gainprm[0] == pytest.approx(2 * inertia * omega)
