"""`m4-sitl` on an install without the `sim` extra: one line naming the extra, no traceback."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _sitl_without(module: str, *args: str) -> subprocess.CompletedProcess:
    script = textwrap.dedent(f"""
        import sys
        sys.modules[{module!r}] = None          # what an install without it looks like to the import system
        from sitl.cli import main
        sys.exit(main({list(args)!r}))
    """)
    return subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("module, args", [
    ("mujoco", ("fly", "hover-rotor-loss")),
    ("mujoco", ("serve", "--duration", "1")),
    ("matplotlib", ("campaign", "--samples", "1")),
])
def test_a_simulator_command_names_the_sim_extra(module, args):
    result = _sitl_without(module, *args)
    assert result.returncode == 2
    assert result.stderr.splitlines() == [
        f"m4-sitl: error: m4-sitl {args[0]} needs the 'sim' extra ({module} not installed): "
        "pip install 'm4-fault-recovery[sim]'"]


def test_list_needs_no_simulator():
    result = _sitl_without("mujoco", "list")
    assert result.returncode == 0 and "hover-rotor-loss" in result.stdout.split(), result.stderr
