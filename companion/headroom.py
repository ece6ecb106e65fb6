"""How much of a control period one control step takes on this computer: `m4-companion bench`'s
headroom, so a user reads at a glance what rate the computer can hold.

The whole control step is timed (companion.controller.Controller.step: plausibility, fault
detector, disturbance estimate, mission reference, NMPC, setpoint check, rate feedback; then
what the companion runs after the send: the detector on a frame left for then
(Controller.read_deferred) and Controller.prepare, the NMPC's preparation of the next step:
all take their share of every period),
along given measured states (the bench's closed-loop-like sequence: kicks, a rotor lost
halfway), with the companion's default configuration. Headroom at a rate is its period over
the p99 step: how many steps of that length fit in one period. The link, the feed and the
operating system need their share too, so a rate is called held when the p99 step takes at
most HELD_SHARE of its period.
"""

from __future__ import annotations

import time

import numpy as np

from companion.config import CompanionConfig
from companion.controller import Controller, ControllerSettings

HELD_SHARE = 0.5
RATES_HZ = (25.0, 50.0, 100.0, 200.0)


def control_step_ms(config: CompanionConfig, states: np.ndarray, thrust_limit_n: np.ndarray) -> np.ndarray:
    """Wall time (ms) of each Controller.step and the preparation after it along `states` (K, 20),
    one control period apart, with the thrust limits the FC reports (K, 4); the first step (it
    starts the mission) not counted."""
    controller = Controller(ControllerSettings.of(config))
    period_s = config.control_period_s
    controller.start(0.0, states[0])
    took_ms = np.empty(len(states) - 1)
    for k in range(1, len(states)):
        t0 = time.perf_counter()
        controller.step(k * period_s, states[k], thrust_limit_n=thrust_limit_n[k])
        controller.read_deferred()                 # after the send, as the app does
        controller.prepare()
        took_ms[k - 1] = 1e3 * (time.perf_counter() - t0)
    return took_ms


def summary(step_ms: np.ndarray) -> dict[str, float]:
    """The step's median and p99 (ms), and the highest rate whose period holds the p99 step
    within HELD_SHARE."""
    p99 = float(np.percentile(step_ms, 99))
    return {"control_step_ms_median": float(np.median(step_ms)), "control_step_ms_p99": p99,
            "max_rate_hz": 1e3 * HELD_SHARE / p99}


def headroom_lines(step_ms: np.ndarray) -> list[str]:
    """The step's median and p99, then per rate: the p99 step and what is left, in control periods."""
    s = summary(step_ms)
    median, p99 = s["control_step_ms_median"], s["control_step_ms_p99"]
    lines = [(f"control step (detector, estimate, NMPC, setpoint, the next step's preparation), {len(step_ms)} "
              f"steps: median {median:.2f} ms, p99 {p99:.2f} ms, max {float(step_ms.max()):.2f} ms"),
             (f"headroom in control periods (held: the p99 step within {HELD_SHARE:.0%} of the period, the rest "
              "for the link, the feed and the system):")]
    for rate_hz in RATES_HZ:
        period_ms = 1e3 / rate_hz
        share = p99 / period_ms
        held = "held" if share <= HELD_SHARE else "NOT held"
        lines.append(f"  {rate_hz:3.0f} Hz ({period_ms:4.1f} ms): p99 step {share:4.2f} period, headroom "
                     f"{max(1.0 - share, 0.0):4.2f} period  {held}")
    lines.append(f"this computer holds up to {s['max_rate_hz']:.0f} Hz")
    return lines
