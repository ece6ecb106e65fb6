"""python -m benchmarks.log: the flight log's cost timed where it runs, in a real flight."""

from __future__ import annotations

import pytest

from benchmarks.log import WARM_START_STEPS, step_times

pytestmark = pytest.mark.flight


def test_the_logs_cost_is_timed_in_the_loops_pack_each_poll_and_in_the_writers_write(tmp_path):
    """Since the loop makes the records after its send (FlightLog.pack), the answer's and the
    writer's times miss the packing: the bench times the pack of every poll of the flight."""
    on = step_times("hover-rotor-loss", 0.5, tmp_path)
    assert len(on.pack_cpu_ms) >= len(on.wall_ms) + WARM_START_STEPS and on.writer_batch_cpu_ms   # a pack each poll
