"""Every companion started by the tests (in this process or a subprocess) writes its flight
log under a temporary folder, not /var/log/m4."""

from __future__ import annotations

import os

import pytest


@pytest.fixture(autouse=True, scope="session")
def _flight_logs_in_a_temporary_folder(tmp_path_factory):
    os.environ["M4_LOG_DIR"] = str(tmp_path_factory.mktemp("flight-logs"))
