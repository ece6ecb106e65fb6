"""Every companion started by the tests (in this process or a subprocess) writes its flight
log under a temporary folder, not /var/log/m4; every test starts and ends with nothing frozen
out of the garbage collector."""

from __future__ import annotations

import gc
import os

import pytest


@pytest.fixture(autouse=True, scope="session")
def _flight_logs_in_a_temporary_folder(tmp_path_factory):
    os.environ["M4_LOG_DIR"] = str(tmp_path_factory.mktemp("flight-logs"))


@pytest.fixture(autouse=True)
def _nothing_frozen_out_of_the_garbage_collector():
    """`m4-companion run` and `m4-sitl serve` freeze what they built (gc.freeze) and a test that
    runs either in this process never unfreezes it: the next test's freeze check would pass on
    what was frozen before it, and the whole suite would carry its frozen objects."""
    gc.unfreeze()
    yield
    gc.unfreeze()
