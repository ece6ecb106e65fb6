"""Fixtures of the feed and watch tests: loopback endpoints, example data for every topic."""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest


@pytest.fixture
def endpoint() -> str:
    """A TCP endpoint on 127.0.0.1 with a port that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


@pytest.fixture
def wait_until():
    return _wait_until


def _wait_until(predicate, timeout_s: float = 5.0, poll_s: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()


PREDICTED_P_NED_M = np.array([[0.1 * k, 0.0, -2.0] for k in range(6)])

# One call of each Feed method: topic -> keyword arguments (t_s apart).
TOPIC_FIELDS = {
    "state": dict(pos_ned_m=np.array([1.0, -2.0, -3.0]), vel_ned_m_s=np.array([0.5, 0.0, -0.1]),
                  euler_rad=np.array([0.0, math.radians(10.0), math.pi]),
                  rates_frd_rad_s=np.array([0.01, -0.02, 3.5]),
                  hip_rad=np.full(4, math.radians(30.0)), thrust_n=np.array([7.0, 7.5, 8.0, np.nan])),
    "setpoint": dict(thrust_n=np.array([7.0, 7.5, 8.0, 0.0]), hip_rad=np.full(4, math.radians(45.0)),
                     hip_rate_rad_s=np.array([math.radians(90.0), 0.0, 0.0, 0.0]), thrust_cut=False),
    "fault": dict(state="confirmed", rotor=4, thrust_max_estimate_n=np.array([30.0, 30.0, 30.0, 0.0]),
                  message="thrust loss rotor 4", detected_at_s=4.02),
    "nmpc": dict(solve_ms=3.25, iterations=2, status="Solve_Succeeded", cost=12.5, ok=True,
                 fallback=False, dt_s=0.05, predicted_p_ned_m=PREDICTED_P_NED_M),
    "link": dict(connected=True, last_msg_age_s=0.012, msgs_per_s=250.0, bad_crc=1,
                 bad_signature=2, dropped_foreign=3),
}


@pytest.fixture
def topic_fields() -> dict[str, dict]:
    return TOPIC_FIELDS


@pytest.fixture
def publish_all():
    """publish_all(feed, t_s): one call of each Feed method with TOPIC_FIELDS."""
    def publish(feed, t_s: float = 5.0) -> None:
        for topic, fields in TOPIC_FIELDS.items():
            getattr(feed, topic)(t_s, **fields)
    return publish
