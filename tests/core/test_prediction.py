"""Prediction through the setpoints in flight: which command acts when, and the state it leads to."""

from __future__ import annotations

import itertools
import math

import casadi as ca
import numpy as np
import pytest

from companion.core import rom
from companion.core.prediction import HISTORY_S, CommandHistory, Predictor, SentCommand
from companion.core.rate_feedback import RateFeedbackDesign
from m4.airframe import load_airframe
from m4.setpoint import RateFeedback, ShortfallCover

AF = load_airframe()
PERIOD = 0.02
F = rom.build_rom(AF, PERIOD).f
NO_FAULT = np.full(4, AF.thrust_max_n)


def command(time_s: float, thrust_n) -> SentCommand:
    return SentCommand(time_s, rom.hover_state(AF), np.r_[np.broadcast_to(thrust_n, 4), np.zeros(4)])


def test_the_command_in_force_is_the_newest_one_that_has_reached_the_fc():
    history = CommandHistory()
    for k in range(5):
        history.add(command(k * PERIOD, 10.0 + k))
    assert history.in_force(0.08, 0.0).time_s == pytest.approx(0.08)
    assert history.in_force(0.08, 0.05).time_s == pytest.approx(0.02)      # 0.02 + 0.05 <= 0.08 < 0.04 + 0.05
    assert history.in_force(0.04, 0.05) is None                              # none of ours arrived yet
    flown = history.in_flight(0.08, 0.13, 0.05)                             # in force at 0.08, then two take over
    assert [start for start, _ in flown] == pytest.approx([0.08, 0.09, 0.11])
    assert [c.time_s for _, c in flown] == pytest.approx([0.02, 0.04, 0.06])
    assert history.in_flight(0.04, 0.1, 0.05) == []


def test_commands_older_than_the_history_are_forgotten():
    history = CommandHistory()
    for k in range(100):
        history.add(command(k * PERIOD, 10.0))
    newest = 99 * PERIOD
    assert history.newest.time_s == pytest.approx(newest)
    assert history.in_force(newest - HISTORY_S - PERIOD, 0.0) is None
    assert history.in_force(newest - HISTORY_S + PERIOD, 0.0) is not None


def test_without_lead_the_measured_state_is_planned_from():
    history = CommandHistory()
    history.add(command(0.0, 20.0))
    x = rom.hover_state(AF)
    assert np.array_equal(Predictor(AF, F, 0.02).predict(x, 0.02, 0.0, history, np.zeros(rom.ND), NO_FAULT), x)


def test_the_state_is_flown_forward_with_the_commands_in_flight():
    """Lead 0.05 s at 0.1 s with every motor already at the commanded thrust: the ROM flown
    0.05 s, moving on at 1 m/s."""
    history = CommandHistory()
    thrust = AF.hover_thrust_per_rotor_n + 2.0
    for k in range(5):
        history.add(command(k * PERIOD, thrust))
    x = rom.hover_state(AF)
    x[rom.V] = (1.0, 0.0, 0.0)
    predicted = Predictor(AF, F, 0.02).predict(x, 0.1, 0.05, history, np.zeros(rom.ND), NO_FAULT, np.full(4, thrust))
    step = rom.build_rom(AF, 0.05, substeps=8).step
    expected = np.asarray(step(x, np.r_[np.full(4, thrust), np.zeros(4)], np.zeros(rom.ND))).ravel()
    assert np.allclose(predicted[rom.P], expected[rom.P], atol=1e-6)
    assert np.allclose(predicted[rom.V], expected[rom.V], atol=1e-5)
    assert predicted[rom.P][0] == pytest.approx(x[rom.P][0] + 0.05, abs=1e-3)
    assert np.array_equal(predicted[rom.HIP], x[rom.HIP])                      # hips: the goal, not predicted


def test_the_motors_follow_a_new_command_with_their_lag():
    """From hover, every rotor commanded 3 N more at 0.05 s, acting from 0.15 s with a lead of
    0.1 s: the climb rate at 0.1 + lead is that of a first-order thrust step, not of an instant one."""
    hover = AF.hover_thrust_per_rotor_n
    history = CommandHistory()
    history.add(command(0.0, hover))
    history.add(command(0.05, hover + 3.0))
    lead, tau, mass = 0.1, AF.motor_time_constant_s, AF.total_mass_kg
    predicted = Predictor(AF, F, 0.02).predict(rom.hover_state(AF), 0.1, lead, history, np.zeros(rom.ND), NO_FAULT,
                                         np.full(4, hover))
    acting_s = 0.05                                     # from 0.15 s to 0.2 s
    climb_m_s = 4 * 3.0 / mass * (acting_s - tau * (1.0 - np.exp(-acting_s / tau)))
    assert -predicted[rom.V][2] == pytest.approx(climb_m_s, rel=0.02)
    assert -predicted[rom.V][2] < 0.6 * 4 * 3.0 / mass * acting_s


def test_a_lost_rotor_flies_the_prediction_at_its_estimated_ceiling_not_at_its_command():
    history = CommandHistory()
    for k in range(6):
        history.add(command(k * PERIOD, AF.hover_thrust_per_rotor_n))
    x = rom.hover_state(AF)
    lost = Predictor(AF, F, 0.02).predict(x, 0.1, 0.06, history, np.zeros(rom.ND), [30.0, 30.0, 30.0, 0.0])
    healthy = Predictor(AF, F, 0.02).predict(x, 0.1, 0.06, history, np.zeros(rom.ND), NO_FAULT)
    assert np.allclose(healthy[rom.RATES], 0.0, atol=1e-6)
    assert np.linalg.norm(lost[rom.RATES][:2]) > 0.5                  # it starts to roll and pitch


def test_the_fcs_rate_feedback_is_predicted_as_the_fc_closes_it():
    """A roll rate the plan does not want (planned 0): the FC's feedback brakes it, and the
    prediction through the commands in flight brakes it as well; without feedback it keeps on."""
    x = rom.hover_state(AF)
    x[rom.RATES] = [2.0, 0.0, 0.0]
    gain = RateFeedbackDesign(AF, 20.0).gain(x[rom.HIP], NO_FAULT)
    braking = RateFeedback(np.zeros(3), np.zeros(3), gain)
    hover = AF.hover_thrust_per_rotor_n
    rates = {}
    for name, feedback in (("with", braking), ("without", None)):
        history = CommandHistory()
        for k in range(6):
            history.add(SentCommand(k * PERIOD, x, np.r_[np.full(4, hover), np.zeros(4)], feedback))
        predicted = Predictor(AF, F, PERIOD).predict(x, 0.1, 0.06, history, np.zeros(rom.ND), NO_FAULT,
                                                     np.full(4, hover))
        rates[name] = predicted[rom.RATES][0]
    assert rates["without"] == pytest.approx(2.0, abs=0.05)
    assert 0.0 < rates["with"] < 0.6 * rates["without"]


def test_the_fcs_cover_for_a_rotor_asked_beyond_its_bound_is_predicted():
    """Commands sent before the loss was known ask rotor 4 for hover thrust; it gives nothing.
    With the cover sent along, the FC moves the others to keep sum and torque, and the
    prediction keeps the robot level; without it, the robot starts to roll and pitch."""
    x = rom.hover_state(AF)
    hover = AF.hover_thrust_per_rotor_n
    lost = [AF.thrust_max_n] * 3 + [AF.thrust_min_n]
    rates = {}
    for name, cover in (("with", RateFeedbackDesign(AF, 0.0, shortfall_cover=True).cover(x[rom.HIP], False)),
                        ("without", None)):
        history = CommandHistory()
        for k in range(6):
            history.add(SentCommand(k * PERIOD, x, np.r_[np.full(4, hover), np.zeros(4)], None, cover))
        predicted = Predictor(AF, F, PERIOD).predict(x, 0.1, 0.06, history, np.zeros(rom.ND), lost,
                                                     np.full(4, hover))
        rates[name] = np.linalg.norm(predicted[rom.RATES][:2])
    assert rates["without"] > 0.5
    assert rates["with"] < 0.05


def loop_prediction(x, time_s, lead_s, commands, d, bound_n, thrust_now_n=None):
    """The prediction as a Python loop over its pieces (the route before it was compiled, main
    061eb30): each piece's command from m4.setpoint's own RateFeedback and ShortfallCover,
    one RK4 flow (two substeps) a piece, the motors' lag between."""
    def in_force(t_s):
        return [c for c in commands if c.time_s + lead_s <= t_s + 1e-6][-1]

    sym = [ca.SX.sym(name, n) for name, n in (("x", rom.NX), ("u", rom.NU), ("d", rom.ND), ("dt", 1))]
    flow = ca.Function("flow", sym, [rom.rk4(F, *sym[:3], sym[3], 2)])
    end_s, tau = time_s + lead_s, AF.motor_time_constant_s
    edges = [time_s, *[c.time_s + lead_s for c in commands if time_s + 1e-6 < c.time_s + lead_s < end_s - 1e-6], end_s]
    thrust = np.minimum(in_force(time_s).thrust_n, bound_n)
    if thrust_now_n is not None:
        thrust = np.where(np.isfinite(thrust_now_n), thrust_now_n, thrust)
    xk = np.array(x, dtype=float)
    for a, b in itertools.pairwise(edges):
        sent = in_force(a)
        pieces = max(1, math.ceil((b - a) / 0.01 - 1e-9))
        h = (b - a) / pieces
        decay = math.exp(-h / tau)
        for k in range(pieces):
            command = sent.thrust_n
            if sent.feedback is not None:
                command = command + sent.feedback.thrust_change_n(xk[rom.RATES], a + k * h - sent.time_s - lead_s, PERIOD)
            command = command.clip(AF.thrust_min_n, AF.thrust_max_n)
            if sent.cover is not None:
                command = command + sent.cover.thrust_change_n(np.maximum(command - bound_n, 0.0))
            command = command.clip(AF.thrust_min_n, bound_n)
            u = np.r_[thrust + (command - thrust) * (1.0 - tau / h * (1.0 - decay)), np.zeros(4)]
            xk = np.asarray(flow(xk, u, d, h)).ravel()
            thrust = command + (thrust - command) * decay
    xk[rom.HIP], xk[rom.HIP_RATE] = x[rom.HIP], x[rom.HIP_RATE]
    return xk


@pytest.mark.parametrize("codegen", [False, True])
def test_the_pieces_flown_in_one_call_predict_what_a_loop_over_them_does(codegen):
    """Commands with and without rate feedback and cover, a rotor bounded below its commands,
    leads that change from step to step and put the commands' arrivals inside the 10 ms
    pieces, one piece to a lead of more pieces than a call flies (three calls), a command in
    force longer than its period: the same state as the loop, to rounding."""
    rng = np.random.default_rng(21)
    x = rom.hover_state(AF)
    x[rom.V], x[rom.RATES], x[rom.EULER] = [0.4, -0.2, 0.3], [0.6, -0.4, 0.2], [0.05, -0.03, 0.2]
    gain = RateFeedbackDesign(AF, 20.0).gain(x[rom.HIP], NO_FAULT)
    cover = ShortfallCover(rng.normal(0.0, 0.5, (4, 4)))                 # any gain the setpoint can carry
    commands = [SentCommand(k * PERIOD, x, np.r_[AF.hover_thrust_per_rotor_n + rng.normal(0.0, 1.5, 4), np.zeros(4)],
                            RateFeedback(rng.normal(0.0, 0.3, 3), rng.normal(0.0, 2.0, 3), gain) if k % 3 != 1 else None,
                            cover if k % 4 else None)
                for k in range(40)]
    history = CommandHistory()
    for c in commands:
        history.add(c)
    predictor = Predictor(AF, F, PERIOD, codegen=codegen, pieces_per_call=8)
    d = rng.normal(0.0, 0.5, rom.ND)
    bound = np.array([AF.thrust_max_n, AF.thrust_max_n, 6.0, AF.thrust_max_n])      # rotor 3 short of its commands
    newest = commands[-1].time_s
    for now, lead, thrust_now in ((newest + 0.0031, 0.0437, None), (newest + 0.0031, 0.1, [9.0, np.nan, 5.0, 11.0]),
                                  (newest + 0.0031, 0.004, None), (newest + 0.0031, 0.0952, None),
                                  (newest + 0.0031, 0.2503, np.full(4, AF.hover_thrust_per_rotor_n)),
                                  (newest + 0.045, 0.06, None)):     # the newest in force beyond its period
        expected = loop_prediction(x, now, lead, commands, d, bound, thrust_now)
        predicted = predictor.predict(x, now, lead, history, d, bound, thrust_now)
        np.testing.assert_allclose(predicted, expected, rtol=0.0, atol=1e-12, err_msg=f"at {now} s, lead {lead} s")
        assert np.abs(expected - x).max() > 1e-3              # the lead moved the state: not the measured one back
