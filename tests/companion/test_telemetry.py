"""The telemetry assembler: ordering per stream, NaN, clearing after a reboot, and the centre of mass in the ROM state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from m4.airframe import load_airframe
from m4.attitude import euler_from_quat_wxyz
from companion.core import rom
from companion.core.com_offset import ComOffset
from m4.mavlink import mavlink
from companion.telemetry import ATTITUDE, ESC_TELEMETRY, JOINT_STATE, LOCAL_POSITION, NEEDED, TelemetryAssembler, \
    rom_state

AF = load_airframe()
COM = ComOffset(AF)
NAN4 = [math.nan] * 4


def attitude(t_ms, roll=0.0, pitch=0.0, yaw=0.0, rates=(0.0, 0.0, 0.0)):
    return mavlink.MAVLink_attitude_message(t_ms, roll, pitch, yaw, *rates)


def position(t_ms, ned=(0.0, 0.0, -2.0), vel=(0.0, 0.0, 0.0)):
    return mavlink.MAVLink_local_position_ned_message(t_ms, *ned, *vel)


def joints(t_ms, hip=None, rate=(0.0,) * 4):
    return mavlink.MAVLink_m4_joint_state_message(t_ms, list(hip or [AF.nominal_hip_rad] * 4), list(rate))


def thrusters(t_ms, limit=NAN4):
    hover = [AF.hover_thrust_per_rotor_n] * 4
    return mavlink.MAVLink_m4_thruster_status_message(t_ms, hover, list(limit))


def frame(t_ms, **kw):
    return [attitude(t_ms), position(t_ms, **kw), joints(t_ms), thrusters(t_ms)]


def feed(asm, msgs, now_s=0.0):
    return [asm.add(m, now_s) for m in msgs]


def test_no_snapshot_until_attitude_position_joints_and_thrusters_have_come():
    asm = TelemetryAssembler()
    feed(asm, frame(0)[:3])
    assert asm.snapshot() is None
    feed(asm, [thrusters(0)])
    assert asm.snapshot() is not None


def test_duplicates_and_older_stamps_are_dropped_and_counted():
    asm = TelemetryAssembler()
    feed(asm, frame(100, ned=(1.0, 2.0, -3.0)))
    accepted = feed(asm, [position(100, ned=(9.0, 9.0, -9.0)), position(60, ned=(8.0, 8.0, -8.0))], now_s=0.01)
    assert accepted == [False, False]
    assert asm.counters.stale == 2
    assert np.allclose(asm.snapshot().pos_ned_m, [1.0, 2.0, -3.0])


def test_each_stream_keeps_its_own_newest_sample_out_of_order_arrivals_included():
    asm = TelemetryAssembler()
    feed(asm, frame(100))
    feed(asm, [attitude(140, roll=0.1), attitude(120, roll=0.2), position(120, ned=(1.0, 0.0, -2.0))])
    snap = asm.snapshot()
    assert snap.euler_rad[0] == pytest.approx(0.1)
    assert snap.times_ms[ATTITUDE] == 140 and snap.times_ms[LOCAL_POSITION] == 120
    assert snap.time_ms == 140


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_fields_are_rejected_and_counted(bad):
    asm = TelemetryAssembler()
    feed(asm, frame(0))
    assert not asm.add(position(20, ned=(bad, 0.0, -2.0)), 0.0)
    assert not asm.add(attitude(20, pitch=bad), 0.0)
    assert not asm.add(joints(20, rate=(0.0, bad, 0.0, 0.0)), 0.0)
    assert asm.counters.nonfinite == 3
    assert np.all(np.isfinite(rom_state(asm.snapshot(), COM)))


def test_a_quaternion_that_is_not_a_unit_one_is_rejected():
    asm = TelemetryAssembler()
    bad = mavlink.MAVLink_attitude_quaternion_message(0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, [0.0] * 4)
    assert not asm.add(bad, 0.0)
    assert asm.counters.nonfinite == 1


def test_thruster_nan_means_unknown_and_is_kept():
    asm = TelemetryAssembler()
    feed(asm, frame(0))
    assert np.all(np.isnan(asm.snapshot().thrust_limit_n))


def test_time_going_backwards_is_dropped_until_cleared():
    asm = TelemetryAssembler()
    feed(asm, frame(5000), now_s=10.0)
    assert feed(asm, frame(20), now_s=11.0) == [False] * 4
    assert asm.counters.stale == 4 and asm.snapshot().time_ms == 5000
    asm.clear()                                 # the FC rebooted (the link says so)
    assert asm.snapshot() is None               # the old boot's position, joints and thrusters are gone
    feed(asm, frame(40), now_s=11.02)
    assert asm.snapshot().time_ms == 40


def test_quaternion_gives_the_same_euler_angles_as_the_rotation():
    euler = np.array([0.3, -0.4, 2.5])
    rot = rom.rotation_ned_from_frd(euler)
    w = math.sqrt(1.0 + np.trace(rot)) / 2.0
    q = [w, (rot[2, 1] - rot[1, 2]) / (4 * w), (rot[0, 2] - rot[2, 0]) / (4 * w), (rot[1, 0] - rot[0, 1]) / (4 * w)]
    assert np.allclose(euler_from_quat_wxyz(q), euler)


def test_attitude_from_the_quaternion_when_attitude_is_missing():
    asm = TelemetryAssembler()
    half = math.radians(30.0) / 2
    q = mavlink.MAVLink_attitude_quaternion_message(0, math.cos(half), math.sin(half), 0.0, 0.0, 0.1, 0.0, 0.0,
                                                    [0.0] * 4)
    feed(asm, [q, *frame(0)[1:]])
    assert np.allclose(asm.snapshot().euler_rad, [math.radians(30.0), 0.0, 0.0])


def test_rom_position_is_the_centre_of_mass_rotated_into_ned():
    hip = np.radians([80.0, 10.0, 60.0, 30.0])
    euler = np.array([0.2, -0.1, 1.0])
    asm = TelemetryAssembler()
    feed(asm, [attitude(0, *euler), position(0, ned=(1.0, 2.0, -3.0)), joints(0, hip=list(hip)), thrusters(0)])
    x = rom_state(asm.snapshot(), COM)
    r_ned = rom.rotation_ned_from_frd(euler) @ AF.com_offset_frd_m(hip)
    assert np.linalg.norm(r_ned) > 0.005                       # the offset is not negligible here
    assert np.allclose(x[rom.P], np.array([1.0, 2.0, -3.0]) + r_ned)
    assert np.allclose(x[rom.HIP], hip) and np.allclose(x[rom.EULER], euler)


def test_rom_velocity_adds_omega_cross_r_and_the_legs_motion():
    hip = np.radians([80.0, 10.0, 60.0, 30.0])
    rates = np.array([0.0, 0.0, 5.0])
    hip_rate = np.array([1.0, -2.0, 0.5, 0.0])
    asm = TelemetryAssembler()
    feed(asm, [attitude(0, rates=tuple(rates)), position(0), joints(0, hip=list(hip), rate=tuple(hip_rate)),
               thrusters(0)])
    x = rom_state(asm.snapshot(), COM)
    r = AF.com_offset_frd_m(hip)
    dt = 1e-6
    r_dot = (AF.com_offset_frd_m(hip + hip_rate * dt) - AF.com_offset_frd_m(hip - hip_rate * dt)) / (2 * dt)
    assert np.allclose(AF.com_offset_rate_frd_m_s(hip, hip_rate), r_dot, atol=1e-8)
    assert np.allclose(x[rom.V], np.cross(rates, r) + r_dot)


def esc(rpm=(5522,) * 4, current_ca=(2250,) * 4, voltage_cv=(1480,) * 4):
    return mavlink.MAVLink_esc_telemetry_1_to_4_message([30] * 4, list(voltage_cv), list(current_ca), [0] * 4,
                                                         list(rpm), [1] * 4)


def test_esc_telemetry_is_stamped_with_the_fcs_clock_and_converted_to_si_units():
    asm = TelemetryAssembler()
    assert asm.add(esc(), 0.0) is False             # nothing yet says what time it is on the FC
    feed(asm, frame(40))
    assert asm.snapshot().esc is None                # an FC without ESC telemetry
    assert asm.add(esc(rpm=(5522, 5500, 0, 7000), voltage_cv=(1480, 1480, 1480, 0)), 0.0)
    e = asm.snapshot().esc
    assert e.time_s == pytest.approx(0.04)
    assert list(e.rpm) == [5522, 5500, 0, 7000]
    assert e.current_a == pytest.approx([22.5] * 4)
    assert e.voltage_v[:3] == pytest.approx([14.8] * 3) and math.isnan(e.voltage_v[3])   # 0: not reported


def test_a_second_esc_frame_before_the_fcs_clock_moves_is_dropped_as_stale():
    asm = TelemetryAssembler()
    feed(asm, frame(40))
    assert feed(asm, [esc(rpm=(1,) * 4), esc(rpm=(2,) * 4)]) == [True, False]
    feed(asm, frame(60) + [esc(rpm=(3,) * 4)])
    assert asm.snapshot().esc.rpm[0] == 3 and asm.snapshot().esc.time_s == pytest.approx(0.06)
    assert asm.counters.stale == 1
    asm.clear()
    assert asm.snapshot() is None and asm.add(esc(), 0.0) is False


# -- freshness --------------------------------------------------------------------------------------
LIMIT_S = 0.1


def fly_frames(asm, t0_ms, frames, without=(), now0_s=None):
    """Frames every 20 ms (FC clock and ours alike), leaving out the messages of types `without`."""
    for k in range(frames):
        t_ms = t0_ms + 20 * k
        feed(asm, [m for m in frame(t_ms) if not isinstance(m, without)],
             (t_ms if now0_s is None else 1000 * now0_s + 20 * k) / 1000.0)


@pytest.mark.parametrize("ids", NEEDED, ids=lambda ids: mavlink.mavlink_map[ids[0]].__name__)
def test_every_needed_stream_stopped_or_never_come_is_stale_whichever_it_is(ids):
    """`stale` first checks on the FC's clock alone whether every stream is fresh, naming NEEDED's
    streams by hand: each of NEEDED, left out, must still be found."""
    types = tuple(mavlink.mavlink_map[i] for i in ids)
    stopped = TelemetryAssembler()
    fly_frames(stopped, 0, 10)
    fly_frames(stopped, 200, 6, without=types)
    never = TelemetryAssembler()
    fly_frames(never, 0, 16, without=types)
    assert stopped.stale(LIMIT_S) == never.stale(LIMIT_S) == (ids[0],)

def test_a_stream_that_stops_while_the_others_come_is_stale_until_it_comes_again():
    asm = TelemetryAssembler()
    fly_frames(asm, 0, 10)
    assert asm.stale(LIMIT_S) == ()
    fly_frames(asm, 200, 4, without=mavlink.MAVLink_local_position_ned_message)
    assert asm.stale(LIMIT_S) == ()                   # 80 ms without: not yet
    fly_frames(asm, 280, 2, without=mavlink.MAVLink_local_position_ned_message)
    assert asm.stale(LIMIT_S) == (LOCAL_POSITION,)    # 120 ms
    fly_frames(asm, 320, 1)
    assert asm.stale(LIMIT_S) == ()


def test_a_gap_in_every_stream_ages_none_of_them():
    """The link's silence is the link's timeout's business, not a stale stream."""
    asm = TelemetryAssembler()
    fly_frames(asm, 0, 10)
    fly_frames(asm, 2000, 1)
    assert asm.stale(LIMIT_S) == ()


def test_the_attitude_is_stale_only_when_neither_attitude_message_comes():
    asm = TelemetryAssembler()
    quat = mavlink.MAVLink_attitude_quaternion_message
    for k in range(10):
        feed(asm, frame(20 * k)[1:] + [quat(20 * k, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, [0.0] * 4)], 0.02 * k)
    assert asm.stale(LIMIT_S) == ()                   # ATTITUDE stopped at once, ATTITUDE_QUATERNION came
    fly_frames(asm, 200, 10, without=mavlink.MAVLink_attitude_message)
    assert asm.stale(LIMIT_S) == (ATTITUDE,)


def test_a_stream_that_never_came_is_stale_from_the_first_arrival_of_any():
    asm = TelemetryAssembler()
    fly_frames(asm, 0, 5, without=mavlink.MAVLink_m4_joint_state_message)
    assert asm.stale(LIMIT_S) == ()
    fly_frames(asm, 100, 2, without=mavlink.MAVLink_m4_joint_state_message)        # 120 ms since the first
    assert asm.stale(LIMIT_S) == (JOINT_STATE,)
    asm.clear()
    assert asm.stale(LIMIT_S) == ()


def test_esc_telemetry_is_needed_once_it_came_and_stale_when_it_stops():
    asm = TelemetryAssembler()
    fly_frames(asm, 0, 10)
    assert asm.stale(LIMIT_S) == ()                   # an FC without ESC telemetry
    feed(asm, [esc()], 0.18)
    fly_frames(asm, 200, 4)
    assert asm.stale(LIMIT_S) == ()
    fly_frames(asm, 280, 2)
    assert asm.stale(LIMIT_S) == (ESC_TELEMETRY,)


def test_a_wait_of_the_fc_in_lockstep_ages_nothing_on_its_clock():
    """The FC waited 0.5 s (our clock) for our answer to frame 180, then sent ATTITUDE at 190."""
    asm = TelemetryAssembler()
    fly_frames(asm, 0, 10)
    feed(asm, [attitude(190)], 0.68)
    assert asm.stale(LIMIT_S) == ()


def test_a_sample_stamped_far_ahead_makes_no_other_stream_stale():
    asm = TelemetryAssembler()
    fly_frames(asm, 0, 10)
    feed(asm, [position(4_000_000)], 0.19)
    fly_frames(asm, 200, 10, without=mavlink.MAVLink_local_position_ned_message)
    assert asm.stale(LIMIT_S) == ()


def test_rom_state_is_the_airframes_arrays_to_the_last_bits():
    """On floats, where numpy fuses the rotation's multiplies and adds: the position and the
    velocity an ulp or so apart (half a spacing of |value| + 1 at worst over these cases, one
    over 3000 others), the entries passed through untouched exactly equal."""
    rng = np.random.default_rng(21)
    for _ in range(300):
        euler, rates, hip, hip_rate = rng.uniform(-1.5, 1.5, 3), rng.normal(0, 2, 3), rng.uniform(0, 1.6, 4), \
            rng.normal(0, 2, 4)
        pos, vel = rng.normal(0, 5, 3), rng.normal(0, 2, 3)
        asm = TelemetryAssembler()
        feed(asm, [attitude(0, *euler, rates=tuple(rates)), position(0, ned=tuple(pos), vel=tuple(vel)),
                   joints(0, hip=list(hip), rate=tuple(hip_rate)), thrusters(0)])
        snap = asm.snapshot()
        rot, r = rom.rotation_ned_from_frd(snap.euler_rad), AF.com_offset_frd_m(snap.hip_rad)
        moving = np.cross(snap.rates_frd_rad_s, r) + AF.com_offset_rate_frd_m_s(snap.hip_rad, snap.hip_rate_rad_s)
        expected = np.concatenate([snap.pos_ned_m + rot @ r, snap.euler_rad, snap.hip_rad,
                                   snap.vel_ned_m_s + rot @ moving, snap.rates_frd_rad_s, snap.hip_rate_rad_s])
        x = rom_state(snap, COM)
        assert np.all(np.abs(x - expected) <= 2 * np.spacing(np.abs(expected) + 1))
        for untouched in (rom.EULER, rom.HIP, rom.RATES, rom.HIP_RATE):
            assert x[untouched].tolist() == expected[untouched].tolist()


def test_an_angle_that_is_not_finite_gives_a_state_of_nan_not_an_error():
    """A snapshot built by hand (the controller's tests do) may hold one; the controller makes
    a safe setpoint of the NaN."""
    asm = TelemetryAssembler()
    feed(asm, frame(0))
    snap = asm.snapshot()
    snap.euler_rad[0] = math.inf
    x = rom_state(snap, COM)
    assert np.isnan(x[rom.P]).all() and np.isnan(x[rom.V]).all() and x[rom.EULER][0] == math.inf
