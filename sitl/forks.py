"""`python -m sitl.forks FD`: the SITL pre-loaded, forking one `m4-sitl serve` per request on FD
(m4/fork_server.py), for campaigns: each flight's SITL starts without the interpreter's start
and the imports (MuJoCo, the plant, the flight controller, the MAVLink dialect). The child
runs `m4-sitl`'s own `main` with the request's arguments.
"""

from __future__ import annotations

import importlib
import os
import sys

from m4 import fork_server
from sitl import cli


def preload() -> None:
    """The imports of `m4-sitl serve`, MuJoCo without OpenGL as `serve` loads it (without a viewer)."""
    os.environ.setdefault("MUJOCO_GL", "disable")
    importlib.import_module("sitl.serve")


if __name__ == "__main__":
    preload()
    sys.exit(cli.main(fork_server.serve(int(sys.argv[1]))))
