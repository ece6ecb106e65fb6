"""What importing each onboard module pulls in, measured by `sys.modules` in a fresh interpreter.

Onboard: every module of `companion/` and of the shared floor `m4/`. None may load the
simulator (MuJoCo), plotting (matplotlib), the simulator's package or the research package
(`pip install .` on the robot has no MuJoCo; research never flies). The MAVLink edge and the
telemetry assembly load no CasADi (nor does anything in `m4/`), the control step's plain types
neither CasADi nor Zenoh, and the controller no Zenoh: each floor imports only what it needs.
It replaces a check that imported every companion module with MuJoCo and matplotlib hidden.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
NEVER_ONBOARD = {"mujoco", "matplotlib", "sitl", "research"}
NOT_IN = {                                  # module (or package prefix) -> top-level packages it must not load
    "m4": {"casadi"},
    "companion.fc_link": {"casadi"},
    "companion.telemetry": {"casadi"},
    "companion.controller": {"zenoh"},
    "companion.core.control_types": {"casadi", "zenoh"},
}
_PROBE = ("import importlib, json, sys; importlib.import_module(sys.argv[1]); "
          "print(json.dumps(sorted({name.partition('.')[0] for name in sys.modules})))")


def _modules(package: str) -> list[str]:
    names = []
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


ONBOARD = _modules("companion") + _modules("m4")


def _forbidden(module: str) -> set[str]:
    extra = [names for prefix, names in NOT_IN.items() if module == prefix or module.startswith(prefix + ".")]
    return NEVER_ONBOARD.union(*extra)


@pytest.fixture(scope="module")
def loaded(tmp_path_factory) -> dict[str, set[str] | str]:
    """module -> the top-level packages importing it loaded, or the error it raised; one interpreter each,
    run side by side, sharing a bytecode cache (the environment may forbid writing one beside the sources)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(tmp_path_factory.mktemp("pycache"))

    def probe(module: str) -> set[str] | str:
        result = subprocess.run([sys.executable, "-c", _PROBE, module], cwd=ROOT, env=env, capture_output=True,
                                text=True, timeout=300)
        return set(json.loads(result.stdout)) if result.returncode == 0 else result.stderr.strip()[-2000:]

    probe("companion.app")                   # fills the bytecode cache for the rest
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
        return dict(zip(ONBOARD, pool.map(probe, ONBOARD)))


@pytest.mark.parametrize("module", ONBOARD)
def test_importing_an_onboard_module_loads_only_what_its_floor_allows(loaded, module):
    modules = loaded[module]
    assert isinstance(modules, set), f"importing {module} failed: {modules}"
    assert not modules & _forbidden(module), f"{module} loads {sorted(modules & _forbidden(module))}"


def test_the_rules_name_modules_that_exist():
    assert {prefix for prefix in NOT_IN if prefix in ONBOARD} == set(NOT_IN)
    assert {"companion.app", "companion.cli", "companion.core.nmpc", "m4.mavlink.dialect"} <= set(ONBOARD)
