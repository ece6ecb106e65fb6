"""Flights whose companion and SITL are forked from pre-loaded parents (m4/fork_server.py), for
campaigns: a flight then starts without the two interpreters' start and imports. A `ForkedStart`
is `run_flight`'s `start`; it starts its two fork servers (`python -m companion.forks`,
`python -m sitl.forks`) at its first flight and keeps them for the next ones. Each child runs
the same `m4-companion run` and `m4-sitl serve` command line a new process would.
"""

from __future__ import annotations

from pathlib import Path

from m4.fork_server import ForkServer, ForkServerError, Run
from sitl.flights.flight_run import COMPANION, SITL, FlightError

FORK_SERVERS = {COMPANION: "companion.forks", SITL: "sitl.forks"}     # program -> its fork server's module


class ForkedStart:
    """`run_flight`'s `start` through the programs' fork servers."""

    def __init__(self):
        self._servers = {program: ForkServer(module) for program, module in FORK_SERVERS.items()}

    def __call__(self, program: str, args: list[str], log_path: Path, pass_fd: tuple[str, int]) -> Run:
        try:
            return self._servers[program].start(args, log_path, pass_fd)
        except ForkServerError as e:
            raise FlightError(str(e)) from None

    def close(self) -> None:
        for server in self._servers.values():
            server.close()
