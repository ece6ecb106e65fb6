"""`python -m companion.forks FD`: the companion pre-loaded, forking one `m4-companion run` per
request on FD (m4/fork_server.py), for campaigns: each flight's companion starts without the
interpreter's start and the imports (CasADi, the MAVLink dialect, Zenoh, the control core).
The child runs `m4-companion`'s own `main` with the request's arguments.
"""

from __future__ import annotations

import importlib
import sys

from companion import cli
from m4 import fork_server

# What `m4-companion run` imports (companion/run.py: its configuration, its app, its start).
PRELOADED = ("companion.run", "companion.app", "companion.config", "companion.params", "companion.realtime",
             "companion.core.codegen_cache", "m4.mavlink.connect", "m4.mavlink.link", "m4.scenario")


def preload() -> None:
    """The imports of `m4-companion run`, BLAS's threads limited first as `m4-companion` does."""
    cli.single_thread_blas()
    for module in PRELOADED:
        importlib.import_module(module)


if __name__ == "__main__":
    preload()
    sys.exit(cli.main(fork_server.serve(int(sys.argv[1]))))
