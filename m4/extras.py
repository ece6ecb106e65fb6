"""The optional extras of the package (pyproject's [project.optional-dependencies]) and a
check that names the one to install when a command needs a module that is not there.

The robot's install has none of them: a command that needs one says which, in one line,
instead of failing with an ImportError traceback half-way.
"""

from __future__ import annotations

import importlib.util

PACKAGE = "m4-fault-recovery"
SIM = ("mujoco", "matplotlib", "tqdm")        # the simulator extra: plant, figures, progress bars
PLOT = ("matplotlib",)                         # the plot extra: figures from a tlog on a laptop


def missing_modules(modules: tuple[str, ...]) -> list[str]:
    """Those of `modules` that cannot be imported (without importing any)."""
    return [name for name in modules if importlib.util.find_spec(name) is None]


def extra_hint(command: str, extra: str, modules: tuple[str, ...]) -> str | None:
    """None when every module is there; else the line saying which extra `command` needs."""
    missing = missing_modules(modules)
    if not missing:
        return None
    return (f"{command} needs the '{extra}' extra ({', '.join(missing)} not installed): "
            f"pip install '{PACKAGE}[{extra}]'")
