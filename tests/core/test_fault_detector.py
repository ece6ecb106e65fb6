import math

import numpy as np
import pytest

from m4.airframe import ROTOR_COUNT, load_airframe
from companion.core import rom
from companion.core.fault_detector import FaultDetector, FaultDetectorConfig, FaultState
from companion.core.thrust_loss_baseline import ThrustLossCheck

AF = load_airframe()
HOVER_N = AF.hover_thrust_per_rotor_n
DT = 0.1
STEP = rom.build_rom(AF, DT, 4).step


def hover_frames(n, thrust_n=None):
    """n frames of a robot hovering on exact thrusts (stays put), with the thrusts commanded."""
    x = rom.hover_state(AF)
    u = rom.hover_input(AF)
    for k in range(n):
        yield k * DT, x, u[rom.THRUST]
        x = np.array(STEP(x, u, np.zeros(rom.ND))).ravel()


def test_exact_hover_stays_healthy_with_the_limits_as_bounds():
    det = FaultDetector(AF)
    for t, x, cmd in hover_frames(30):
        status = det.update(t, x, cmd)
    assert status.state is FaultState.HEALTHY and status.rotor is None and status.message == ""
    assert np.allclose(status.thrust_max_estimate_n, AF.thrust_max_n)
    assert np.abs(status.deficit_n).max() < 0.05


def test_delivered_thrust_telemetry_confirms_the_rotor_and_its_ceiling_directly():
    det = FaultDetector(AF)
    cmd = np.full(ROTOR_COUNT, HOVER_N)
    x = rom.hover_state(AF)
    statuses = []
    for k in range(10):
        delivered = cmd.copy()
        if k >= 3:
            delivered[1] = 6.0      # rotor 2 gives 6 N whatever it is asked
        statuses.append(det.update(k * DT, x, cmd, thrust_delivered_n=delivered))
    # at 10 Hz one frame spans more than direct_confirm_s: the first frame short of thrust confirms
    assert [s.state for s in statuses[2:5]] == [FaultState.HEALTHY, FaultState.CONFIRMED, FaultState.CONFIRMED]
    final = statuses[-1]
    assert final.rotor == 2 and final.message == "thrust loss rotor 2"
    assert final.detected_at_s == pytest.approx(3 * DT)
    # an instant drop is faster than the motor lag the ceiling is extrapolated with: a little low, never high
    assert 6.0 - 0.05 * HOVER_N <= final.thrust_max_estimate_n[1] <= 6.0
    assert np.allclose(np.delete(final.thrust_max_estimate_n, 1), AF.thrust_max_n)


def test_deficits_on_two_rotors_are_not_a_single_rotor_fault():
    det = FaultDetector(AF)
    cmd = np.full(ROTOR_COUNT, HOVER_N)
    delivered = cmd - np.array([5.0, 0.0, 5.0, 0.0])
    for k in range(10):
        status = det.update(k * DT, rom.hover_state(AF), cmd, thrust_delivered_n=delivered)
    assert status.state is FaultState.HEALTHY


def test_unknown_delivered_thrust_falls_back_on_the_model_residual():
    det = FaultDetector(AF)
    x = rom.hover_state(AF)
    u = rom.hover_input(AF)
    lost = u.copy()
    lost[3] = 0.0                          # rotor 4 off; we keep commanding hover thrust
    nan = np.full(ROTOR_COUNT, math.nan)
    for k in range(6):
        status = det.update(k * DT, x, u[rom.THRUST], thrust_delivered_n=nan)
        x = np.array(STEP(x, lost if k >= 2 else u, np.zeros(rom.ND))).ravel()
    assert status.state is FaultState.CONFIRMED and status.rotor == 4
    # the ROM has no motor lag but the detector's model does: the first interval reads low
    assert status.thrust_max_estimate_n[3] < 0.1 * HOVER_N


def test_a_gap_in_telemetry_restarts_the_evidence_instead_of_reading_it_as_a_fault():
    det = FaultDetector(AF)
    x0 = rom.hover_state(AF)
    det.update(0.0, x0, np.full(ROTOR_COUNT, HOVER_N))
    far = x0.copy()
    far[rom.RATES] = (3.0, -3.0, 0.0)       # what 2 s of an unobserved tumble could look like
    for k in range(2):
        status = det.update(2.0 + k * 1.0, far, np.full(ROTOR_COUNT, HOVER_N))
    assert status.state is FaultState.HEALTHY


@pytest.mark.parametrize("field, value", [("window_s", 0.0), ("deficit_min_n", -1.0), ("estimate_gain", 1.5),
                                          ("rates_noise_rad_s", math.nan)])
def test_bad_detector_settings_are_rejected_by_name(field, value):
    with pytest.raises(ValueError, match=field):
        FaultDetector(AF, FaultDetectorConfig(**{field: value}))


def test_baseline_fires_after_a_second_of_saturated_level_descent_without_naming_a_rotor():
    check = ThrustLossCheck(AF)
    x = rom.hover_state(AF)
    x[rom.V] = (0.0, 0.0, 0.4)              # sinking
    cmd = np.array([28.0, 20.0, 20.0, 0.0])  # one rotor at the top of its range
    statuses = [check.update(k * DT, x, cmd) for k in range(12)]
    assert statuses[9].state is FaultState.SUSPECT
    assert statuses[10].state is FaultState.CONFIRMED and statuses[10].detected_at_s == pytest.approx(1.0)
    assert statuses[10].rotor is None
    assert np.allclose(statuses[10].thrust_max_estimate_n, AF.thrust_max_n)


def test_baseline_restarts_its_timer_whenever_the_robot_stops_sinking():
    check = ThrustLossCheck(AF)
    x = rom.hover_state(AF)
    cmd = np.array([28.0, 20.0, 20.0, 0.0])
    for k in range(30):
        x[rom.V] = (0.0, 0.0, 0.4 if k % 8 else -0.1)
        status = check.update(k * DT, x, cmd)
    assert status.state is not FaultState.CONFIRMED


def test_a_frame_with_nan_is_skipped_without_poisoning_later_detection():
    det = FaultDetector(AF)
    frames = list(hover_frames(12))
    for t, x, cmd in frames[:4]:
        det.update(t, x, cmd)
    broken = frames[4][1].copy()
    broken[rom.V] = math.nan
    assert det.update(frames[4][0], broken, frames[4][2]).state is FaultState.HEALTHY
    for t, x, cmd in frames[5:]:
        status = det.update(t, x, cmd)
    assert status.state is FaultState.HEALTHY and np.all(np.isfinite(status.deficit_n))
    assert np.abs(status.deficit_n).max() < 0.05


def test_unknown_limits_from_the_flight_controller_fall_back_on_the_airframe():
    det = FaultDetector(AF)
    status = det.update(0.0, rom.hover_state(AF), np.full(ROTOR_COUNT, HOVER_N),
                        thrust_limit_n=[math.nan, 20.0, math.nan, 25.0])
    assert np.allclose(status.thrust_max_estimate_n, [AF.thrust_max_n, 20.0, AF.thrust_max_n, 25.0])


def lagged_frames(commands_n, ceiling_fn, dt_s=0.02):
    """Frames dt_s apart; over the interval that ends at frame k the motors follow commands_n[k]
    (4,) with the airframe's first-order lag towards min(command, ceiling_fn(k)). Yields
    (t, command in force over the interval, delivered thrust at t)."""
    decay = math.exp(-dt_s / AF.motor_time_constant_s)
    thrust = np.array(commands_n[0], dtype=float)
    for k, cmd in enumerate(commands_n):
        target = np.minimum(cmd, ceiling_fn(k))
        thrust = target + (thrust - target) * decay
        yield k * dt_s, cmd, thrust.copy()


def test_delivered_thrust_far_below_the_lagged_command_two_frames_running_confirms_at_once():
    """50 Hz telemetry, rotor 3 stops right after frame 4: its delivered thrust decays with the motor
    lag, two frames with a deficit of more than deficit_min_n confirm (0.04 s, not confirm_s),
    and the ceiling handed over is the level the lag heads to (0 N), not the thrust still delivered."""
    det = FaultDetector(AF)
    cmd = np.full(ROTOR_COUNT, HOVER_N)
    ceiling = lambda k: np.array([AF.thrust_max_n, AF.thrust_max_n, 0.0 if k >= 5 else AF.thrust_max_n,
                                  AF.thrust_max_n])
    statuses = [det.update(t, rom.hover_state(AF), c, thrust_delivered_n=d)
                for t, c, d in lagged_frames([cmd] * 12, ceiling)]
    confirmed = next(s for s in statuses if s.state is FaultState.CONFIRMED)
    assert confirmed.rotor == 3
    assert confirmed.detected_at_s == pytest.approx(6 * 0.02)      # deficits at frames 5 and 6
    assert confirmed.detected_at_s - 4 * 0.02 < FaultDetectorConfig().confirm_s
    assert confirmed.thrust_max_estimate_n[2] == pytest.approx(AF.thrust_min_n, abs=0.05)
    assert statuses[5].state is FaultState.SUSPECT


def test_a_fast_command_step_the_motor_lag_delays_raises_no_alarm():
    """Rotor 1 commanded from hover to the maximum in one frame, and back: the delivered thrust
    trails the command by far more than deficit_min_n for a few frames, but not the command
    passed through the motor lag."""
    det = FaultDetector(AF)
    hover = np.full(ROTOR_COUNT, HOVER_N)
    step = hover.copy()
    step[0] = AF.thrust_max_n
    commands = [hover] * 5 + [step] * 10 + [hover] * 10
    limits = lambda k: np.full(ROTOR_COUNT, AF.thrust_max_n)
    frames = list(lagged_frames(commands, limits))
    raw_deficits = [c[0] - d[0] for _, c, d in frames]
    assert max(raw_deficits) > 2 * FaultDetectorConfig().deficit_min_n      # the raw command would alarm
    for t, c, d in frames:
        status = det.update(t, rom.hover_state(AF), c, thrust_delivered_n=d)
        assert status.state is FaultState.HEALTHY, t


def test_a_partial_loss_is_confirmed_from_delivered_thrust_with_its_ceiling():
    det = FaultDetector(AF)
    cmd = np.full(ROTOR_COUNT, HOVER_N)
    ceiling = lambda k: np.array([AF.thrust_max_n, 0.5 * HOVER_N if k >= 5 else AF.thrust_max_n,
                                  AF.thrust_max_n, AF.thrust_max_n])
    statuses = [det.update(t, rom.hover_state(AF), c, thrust_delivered_n=d)
                for t, c, d in lagged_frames([cmd] * 15, ceiling)]
    confirmed = next(s for s in statuses if s.state is FaultState.CONFIRMED)
    assert confirmed.rotor == 2 and confirmed.detected_at_s <= 9 * 0.02 + 1e-9
    assert confirmed.thrust_max_estimate_n[1] == pytest.approx(0.5 * HOVER_N, abs=0.05)


def test_one_frame_of_low_delivered_thrust_at_50_hz_is_only_a_suspicion():
    """A single 50 Hz frame (shorter than direct_confirm_s) reporting rotor 1 far short of its
    command, then normal thrust again: suspect for that frame, healthy after, never confirmed."""
    det = FaultDetector(AF)
    cmd = np.full(ROTOR_COUNT, HOVER_N)
    states = []
    for k in range(10):
        delivered = cmd.copy()
        if k == 4:
            delivered[0] = 0.0
        states.append(det.update(k * 0.02, rom.hover_state(AF), cmd, thrust_delivered_n=delivered).state)
    assert states[4] is FaultState.SUSPECT
    assert FaultState.CONFIRMED not in states and states[-1] is FaultState.HEALTHY
