"""The MJCF of the M4 in flight mode, generated from the airframe (the one source of numbers).

Layout as in mujoco_menagerie: `m4.xml` (the robot: default classes, bodies, actuators, a
`hover` keyframe) and `scene.xml` (floor, light, sky) that includes it. Regenerate the
committed files with `python -m sitl.plant.mjcf`; a test checks they equal a fresh generation.

Frames: MuJoCo's world is z-up. The model uses world = NWU (x north, y west, z up) and body
= FLU (x forward, y left, z up), so NED = diag(1, -1, -1) world and FRD = diag(1, -1, -1)
body; `sitl.plant.frames` converts, and the plant's API speaks NED/FRD only.

Per leg (rotor i = 1..4): body `hip{i}` at the hip with the frontal joint (hinge about body
x, 0 = flight configuration, every thrust axis along body z) and the hip block; body
`leg{i}` with the sagittal joint (0 = folded along the body, q = 90 deg out sideways) and
the link at mid-leg; body `wheel{i}` at the leg end with the wheel + thruster lump and the
site `thrust{i}`. Actuators: `thrust{i}` + `thrustsq{i}` (together the rotor's thrust
along the hub axis with its reaction moment spin k_m T; see _actuators), `hip{i}` +
`hiprate{i}` (the sagittal servo: both take the reference rate; `hip{i}` integrates it into
the reference angle and pulls the joint to it, `hiprate{i}` damps the joint towards the
reference rate), `frontal{i}` (stiff hold of the flight configuration).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe, load_airframe
from sitl.plant.frames import FLIP

PHYSICS_DT_S = 0.001
MODEL_DIR = Path(__file__).resolve().parent / "models" / "m4"
ROBOT_FILE = "m4.xml"
SCENE_FILE = "scene.xml"
README_FILE = "README.md"
HOVER_HEIGHT_M = 2.0            # the keyframe's height above the floor


@dataclass(frozen=True)
class Lump:
    """A leg lump: mass, position in its leg frame (FLU, leg along +-x at q = 0), own inertia."""

    mass_kg: float
    pos_m: tuple[float, float, float]
    inertia_diag_kg_m2: tuple[float, float, float]


def leg_lumps(af: Airframe, sx: float) -> tuple[Lump, Lump, Lump]:
    """Hip block (cube at the hip), link (rod from hip to hub), wheel + thruster (disk at the hub)."""
    (m_h, f_h), (m_l, f_l), (m_w, f_w) = af.leg_lumps
    a, r, length = af.hip_block_size_m, af.link_radius_m, af.leg_length_m
    rw, w = af.wheel_radius_m, af.wheel_width_m
    rod_perp = m_l * (3 * r**2 + length**2) / 12
    disk_diam = m_w * (3 * rw**2 + w**2) / 12
    return (Lump(m_h, (sx * f_h * length, 0.0, 0.0), (m_h * a**2 / 6,) * 3),
            Lump(m_l, (sx * f_l * length, 0.0, 0.0), (m_l * r**2 / 2, rod_perp, rod_perp)),
            Lump(m_w, (sx * f_w * length, 0.0, 0.0), (disk_diam, disk_diam, m_w * rw**2 / 2)))


def sagittal_inertia_kg_m2(af: Airframe) -> float:
    """Inertia the sagittal servo moves: link and wheel about the hip's vertical axis (the same
    in every posture)."""
    return sum(lump.inertia_diag_kg_m2[2] + lump.mass_kg * (lump.pos_m[0] ** 2 + lump.pos_m[1] ** 2)
               for lump in leg_lumps(af, 1.0)[1:])


def servo_gains(inertia_kg_m2: float, time_constant_s: float) -> tuple[float, float]:
    """(kp, kv) of a critically damped position servo with natural frequency 1 / time constant."""
    omega = 1.0 / time_constant_s
    return inertia_kg_m2 * omega**2, 2.0 * inertia_kg_m2 * omega


def sagittal_axis_flu(sx: float, sy: float) -> tuple[float, float, float]:
    """Hinge axis (FLU) whose positive angle q turns the leg from (sx, 0) towards (0, sy) in FRD."""
    return (0.0, 0.0, -sx * sy)


def _fmt(*values: float) -> str:
    return " ".join(f"{float(v) + 0.0:.10g}" for v in values)


def _sub(parent: ET.Element, tag: str, **attrs) -> ET.Element:
    return ET.SubElement(parent, tag, {k.rstrip("_"): v for k, v in attrs.items()})


def _defaults(root: ET.Element, af: Airframe) -> None:
    top = _sub(_sub(root, "default"), "default", class_="m4")
    _sub(top, "geom", rgba="0.25 0.27 0.3 1")
    _sub(top, "site", group="5")
    visual = _sub(top, "default", class_="visual")
    _sub(visual, "geom", contype="0", conaffinity="0", group="2")
    collision = _sub(top, "default", class_="collision")
    _sub(collision, "geom", contype="1", conaffinity="0", group="3")
    sagittal = _sub(top, "default", class_="sagittal")
    # No hard stops: the servo's reference stays in [hip_min, hip_max] and the joint follows it
    # within the servo's small overshoot, which a stop would turn into an impact.
    _sub(sagittal, "joint", limited="false")
    frontal = _sub(top, "default", class_="frontal")
    _sub(frontal, "joint", axis="1 0 0")
    thruster = _sub(top, "default", class_="thruster")
    _sub(thruster, "general", dyntype="filterexact")


def _leg(hull: ET.Element, af: Airframe, i: int) -> None:
    n = i + 1
    sx, sy = af.leg_direction_signs[i]
    hip_block, link, wheel = leg_lumps(af, sx)
    hip = _sub(hull, "body", name=f"hip{n}", pos=_fmt(*(FLIP * af.hip_frd_m[i])))
    _sub(hip, "joint", name=f"frontal{n}", class_="frontal")
    _sub(hip, "inertial", pos=_fmt(*hip_block.pos_m), mass=_fmt(hip_block.mass_kg),
         diaginertia=_fmt(*hip_block.inertia_diag_kg_m2))
    _sub(hip, "geom", class_="visual", type="box", size=_fmt(*(af.hip_block_size_m / 2,) * 3))
    leg = _sub(hip, "body", name=f"leg{n}")
    _sub(leg, "joint", name=f"sagittal{n}", class_="sagittal", axis=_fmt(*sagittal_axis_flu(sx, sy)))
    _sub(leg, "inertial", pos=_fmt(*link.pos_m), mass=_fmt(link.mass_kg), diaginertia=_fmt(*link.inertia_diag_kg_m2))
    _sub(leg, "geom", class_="visual", type="capsule", size=_fmt(af.link_radius_m),
         fromto=_fmt(0.0, 0.0, 0.0, *wheel.pos_m))
    hub = _sub(leg, "body", name=f"wheel{n}", pos=_fmt(*wheel.pos_m))
    _sub(hub, "inertial", pos="0 0 0", mass=_fmt(wheel.mass_kg), diaginertia=_fmt(*wheel.inertia_diag_kg_m2))
    _sub(hub, "geom", name=f"wheel{n}", class_="collision", type="cylinder",
         size=_fmt(af.wheel_radius_m, af.wheel_width_m / 2))
    _sub(hub, "geom", class_="visual", type="cylinder", size=_fmt(af.wheel_radius_m, af.wheel_width_m / 2),
         rgba="0.8 0.3 0.1 0.6" if af.spin_sign[i] > 0 else "0.1 0.4 0.8 0.6")
    _sub(hub, "site", name=f"thrust{n}", pos="0 0 0")


def _actuators(root: ET.Element, af: Airframe) -> None:
    act = _sub(root, "actuator")
    # Rotor i's thrust is the sum of `thrust{i}` and `thrustsq{i}`: force along the hub axis
    # (+z of the site, up), reaction moment spin k_m T about FRD z (-spin k_m T about FLU z).
    # With rotor speed w = w_s + d exp(-t / tau) the thrust k_t w^2 is k_t w_s^2 +
    # 2 k_t w_s d exp(-t / tau) + k_t d^2 exp(-2 t / tau): two first-order filters, of time
    # constants tau and tau / 2, whose states the plant (sitl/plant/thrusters.py) sets at every update.
    for name, tau in (("thrust", af.motor_time_constant_s), ("thrustsq", af.motor_time_constant_s / 2)):
        for i in range(ROTOR_COUNT):
            _sub(act, "general", name=f"{name}{i + 1}", class_="thruster", site=f"thrust{i + 1}",
                 dynprm=_fmt(tau), gear=_fmt(0, 0, 1, 0, 0, -af.spin_sign[i] * af.moment_coefficient_m))
    kp, kv = servo_gains(sagittal_inertia_kg_m2(af), af.servo_time_constant_s)
    for i in range(ROTOR_COUNT):
        # ctrl: reference rate; act: reference angle (integrated natively, kept in the joint range).
        _sub(act, "intvelocity", name=f"hip{i + 1}", class_="m4", joint=f"sagittal{i + 1}", kp=_fmt(kp),
             ctrlrange=_fmt(-af.hip_rate_max_rad_s, af.hip_rate_max_rad_s),
             actrange=_fmt(af.hip_min_rad, af.hip_max_rad))
    for i in range(ROTOR_COUNT):
        _sub(act, "velocity", name=f"hiprate{i + 1}", class_="m4", joint=f"sagittal{i + 1}", kv=_fmt(kv),
             ctrlrange=_fmt(-af.hip_rate_max_rad_s, af.hip_rate_max_rad_s))
    _frontal_holds(act, af)


def _frontal_holds(act: ET.Element, af: Airframe) -> None:
    """Stiff, overdamped position servos on the frontal joints (target 0: flight configuration).
    Stiffness kp from the airframe, damping kv = kp x time constant; with MuJoCo's implicit
    treatment of kv the step stays stable for any kp as long as the time constant exceeds a
    quarter of the physics step."""
    kp = af.frontal_servo_stiffness_n_m_per_rad
    kv = kp * af.frontal_servo_time_constant_s
    for i in range(ROTOR_COUNT):
        _sub(act, "position", name=f"frontal{i + 1}", class_="m4", joint=f"frontal{i + 1}", kp=_fmt(kp), kv=_fmt(kv))


def _hover_key(root: ET.Element, af: Airframe) -> None:
    hover = af.hover_thrust_per_rotor_n
    qpos = [0.0, 0.0, HOVER_HEIGHT_M, 1.0, 0.0, 0.0, 0.0]
    for _ in range(ROTOR_COUNT):
        qpos += [0.0, af.nominal_hip_rad]
    ctrl = [hover] * ROTOR_COUNT + [0.0] * (4 * ROTOR_COUNT)
    _sub(_sub(root, "keyframe"), "key", name="hover", qpos=_fmt(*qpos), ctrl=_fmt(*ctrl),
         act=_fmt(*[hover] * ROTOR_COUNT, *[0.0] * ROTOR_COUNT, *[af.nominal_hip_rad] * ROTOR_COUNT))


def robot_xml(af: Airframe) -> str:
    """The robot file (m4.xml) for an airframe."""
    root = ET.Element("mujoco", model=af.name)
    _sub(root, "compiler", angle="radian", autolimits="true")
    _sub(root, "option", timestep=_fmt(PHYSICS_DT_S), gravity=_fmt(0, 0, -af.gravity_m_s2),
         integrator="implicitfast", jacobian="dense")
    _defaults(root, af)
    world = _sub(root, "worldbody")
    hull = _sub(world, "body", name="hull", pos=_fmt(0, 0, HOVER_HEIGHT_M), childclass="m4")
    _sub(hull, "freejoint", name="root")
    _sub(hull, "inertial", pos="0 0 0", mass=_fmt(af.body_mass_kg), diaginertia=_fmt(*af.body_inertia_diag_kg_m2))
    _sub(hull, "geom", name="hull", class_="collision", type="box", size=_fmt(*(np.array(af.body_box_size_m) / 2)))
    _sub(hull, "geom", class_="visual", type="box", size=_fmt(*(np.array(af.body_box_size_m) / 2)))
    _sub(hull, "site", name="imu", pos="0 0 0")
    for i in range(ROTOR_COUNT):
        _leg(hull, af, i)
    _actuators(root, af)
    _hover_key(root, af)
    return _to_text(root)


def scene_xml(af: Airframe) -> str:
    """The scene file: floor at z = 0 (NED down = 0), light, sky; includes the robot file."""
    root = ET.Element("mujoco", model=f"{af.name} scene")
    _sub(root, "include", file=ROBOT_FILE)
    _sub(root, "statistic", center="0 0 1", extent="1.5")
    visual = _sub(root, "visual")
    _sub(visual, "headlight", diffuse="0.6 0.6 0.6", ambient="0.3 0.3 0.3", specular="0 0 0")
    _sub(visual, "global", azimuth="-120", elevation="-20")
    asset = _sub(root, "asset")
    _sub(asset, "texture", type="skybox", builtin="gradient", rgb1="0.3 0.5 0.7", rgb2="0 0 0",
         width="512", height="3072")
    _sub(asset, "texture", type="2d", name="groundplane", builtin="checker", mark="edge", rgb1="0.2 0.3 0.4",
         rgb2="0.1 0.2 0.3", markrgb="0.8 0.8 0.8", width="300", height="300")
    _sub(asset, "material", name="groundplane", texture="groundplane", texuniform="true", texrepeat="5 5",
         reflectance="0.2")
    world = _sub(root, "worldbody")
    _sub(world, "light", pos="0 0 5", dir="0 0 -1", directional="true")
    _sub(world, "geom", name="floor", size="0 0 0.05", type="plane", material="groundplane")
    return _to_text(root)


def readme_md(af: Airframe) -> str:
    """The model folder's README, with the airframe's numbers it was generated from."""
    deg = math.degrees
    hubs = af.thruster_positions_frd_m(np.full(ROTOR_COUNT, af.nominal_hip_rad))
    rotors = "\n".join(f"| {i + 1} | {af.rotor_names[i]} | {'ccw' if af.spin_sign[i] > 0 else 'cw'} | "
                        f"({hubs[i, 0]:+.3f}, {hubs[i, 1]:+.3f}, {hubs[i, 2]:+.3f}) |" for i in range(ROTOR_COUNT))
    return f"""# M4 in flight mode (MuJoCo)

Generated by `python -m sitl.plant.mjcf` from the airframe file `m4/airframes/m4_reference.toml`
(airframe "{af.name}"); do not edit by hand: change the airframe and regenerate. A test checks
that these files equal a fresh generation.

- `{ROBOT_FILE}`: the robot (default classes, bodies, actuators, keyframe `hover`).
- `{SCENE_FILE}`: floor (at z = 0), light and sky; includes `{ROBOT_FILE}`.

View it: `python -m mujoco.viewer --mjcf sitl/plant/models/m4/{SCENE_FILE}`.

## Frames
World NWU (x north, y west, z up), body FLU. The project speaks NED / FRD; `sitl/plant/frames.py`
converts (both flips are diag(1, -1, -1)). Rotor numbering, spin and hub positions below are in
FRD, as in the airframe file.

## Structure
- `hull`: free body, {af.body_mass_kg:g} kg, inertia diag{tuple(af.body_inertia_diag_kg_m2)} kg m^2,
  box {' x '.join(f'{v:g}' for v in af.body_box_size_m)} m; site `imu` at its centre.
- Per leg i: `hip{{i}}` (frontal joint `frontal{{i}}`, hip block {af.leg_hip_block_mass_kg:g} kg) ->
  `leg{{i}}` (sagittal joint `sagittal{{i}}`, link {af.leg_link_mass_kg:g} kg at mid-leg) -> `wheel{{i}}`
  (wheel + thruster {af.leg_wheel_mass_kg:g} kg at {af.leg_length_m:g} m, site `thrust{{i}}`). Total
  {af.total_mass_kg:g} kg.
- Sagittal angle: 0 = leg folded along the body, {deg(af.hip_max_rad):g} deg = straight out sideways;
  servo range {deg(af.hip_min_rad):g}..{deg(af.hip_max_rad):g} deg, nominal {deg(af.nominal_hip_rad):g} deg.
  Frontal joints: 0 = flight configuration, held by stiff servos (`frontal{{i}}`).

| rotor | position | spin | hub at the nominal posture, FRD (m) |
|---|---|---|---|
{rotors}

## Actuators
- `thrust1..4` + `thrustsq1..4`: rotor i's thrust T is the sum of the two, along the hub axis
  (site +z), with the reaction moment k_m T, k_m = {af.moment_coefficient_m:g} m (+ about FRD z for
  ccw rotors). The rotor speed follows its target with a first-order lag of
  {af.motor_time_constant_s * 1e3:g} ms, so T = k_t w^2 is a constant plus two decays (time constants
  {af.motor_time_constant_s * 1e3:g} and {af.motor_time_constant_s * 0.5e3:g} ms, `filterexact`) whose
  states the plant sets from its rotor model (`sitl/plant/thrusters.py`).
- `hip1..4` + `hiprate1..4`: the sagittal servo (time constant {af.servo_time_constant_s * 1e3:g} ms);
  both take the reference rate, `hip{{i}}` integrates it into the reference angle.
  The plant (`sitl/plant/mujoco_plant.py`) shapes the reference by the rate ({af.hip_rate_max_rad_s:g} rad/s) and
  acceleration ({af.hip_accel_max_rad_s2:g} rad/s^2) limits.
- `frontal1..4`: hold the frontal joints at 0.

Drag on the hull, faults and the scenario's [plant] mismatch are applied by the plant, not here.
"""


def _to_text(root: ET.Element) -> str:
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode") + "\n"


def compile_model(af: Airframe) -> mujoco.MjModel:
    """The scene compiled in memory (no files), for the plant."""
    return mujoco.MjModel.from_xml_string(scene_xml(af), {ROBOT_FILE: robot_xml(af).encode()})


def write_model(af: Airframe | None = None, out_dir: Path = MODEL_DIR) -> list[Path]:
    """Write m4.xml, scene.xml and README.md for an airframe (the reference one by default)."""
    af = af or load_airframe()
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / ROBOT_FILE, out_dir / SCENE_FILE, out_dir / README_FILE]
    for path, text in zip(paths, (robot_xml(af), scene_xml(af), readme_md(af))):
        path.write_text(text)
    return paths


if __name__ == "__main__":
    for p in write_model():
        print(f"wrote {p}")
