"""The simulator's rooms import only downwards (docs/architecture.md, "The simulator's rooms").

Read from the source (every `import` and `from ... import`, at any depth: a function's lazy
import counts as much as one at the top), so a tangle fails here before it fails anyone.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
OURS = {"sitl", "companion", "research", "analysis", "benchmarks", "tests", "m4"}

SCENARIOS = ("sitl.scenarios",)   # the built-in scenarios (their format, m4.scenario, is on the shared floor)
TOP = ("sitl.cli", "sitl.cli_args", "sitl.flight_cli", "sitl.serve", "sitl.vehicle", "sitl.standin_companion",
       "sitl.forks")
# room -> the sitl modules (or packages) it may import besides its own and `m4`
ALLOWED = {
    "sitl.scenarios": (),
    "sitl.plant": (),
    "sitl.fc": ("sitl.plant.state",),
    "sitl.links": (),
    "sitl.ardupilot": ("sitl.plant", "sitl.flights"),
    "sitl.flights": (*SCENARIOS, "sitl.plant", "sitl.links"),
    "sitl.campaigns": (*SCENARIOS, "sitl.plant", "sitl.links", "sitl.flights"),
    **{top: ("sitl",) for top in TOP},
}
# outside sitl, what a sitl module may import, by importer (prefix match)
OUTSIDE = {
    "analysis": ("sitl.flights", "sitl.campaigns"),                 # reading records and tlogs
    "companion.core.rom": ("sitl.flights.model_matching",),         # the ROM it matches the plant to
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """Every module `path` names in an import statement (for `from a import b`: `a.b`, whether b is a
    module or a name in `a`)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
    return {name for name in names if name.partition(".")[0] in OURS}


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def room_of(module: str) -> str:
    return max((room for room in ALLOWED if _under(module, room)), key=len, default="sitl")


def violations(module: str, imported: set[str]) -> list[str]:
    room = room_of(module)
    allowed = (room, "m4", *ALLOWED.get(room, ()))
    found = []
    for name in sorted(imported):
        if name.startswith("sitl"):
            if name != "sitl" and not any(_under(name, a) for a in allowed):
                found.append(name)
        elif not _under(name, "m4") and not any(_under(name, lib) and any(_under(module, who) for who in importers)
                                              for lib, importers in OUTSIDE.items()):
            found.append(name)
    return found


SITL_MODULES = {_module_name(p): p for p in sorted((ROOT / "sitl").rglob("*.py"))}


@pytest.mark.parametrize("module", sorted(SITL_MODULES))
def test_a_sitl_module_imports_only_its_room_and_the_rooms_below(module):
    bad = violations(module, imports_of(SITL_MODULES[module]))
    assert not bad, f"{module} (room {room_of(module)}) imports {bad}: see docs/architecture.md"


def test_nothing_outside_the_benchmarks_imports_them():
    importers = [p for package in ("sitl", "companion", "m4", "analysis", "research")
                 for p in (ROOT / package).rglob("*.py") if any(_under(n, "benchmarks") for n in imports_of(p))]
    assert not importers


@pytest.mark.parametrize("module, imported, wrong", [
    ("sitl.plant.mujoco_plant", {"sitl.fc.flight_controller"}, ["sitl.fc.flight_controller"]),
    ("sitl.fc.flight_controller", {"sitl.flights.fly", "sitl.campaigns.parallel"},
     ["sitl.campaigns.parallel", "sitl.flights.fly"]),
    ("sitl.fc.commands", {"sitl.plant.thrusters.FailureKind"}, ["sitl.plant.thrusters.FailureKind"]),
    ("sitl.flights.compare", {"sitl.campaigns.parallel"}, ["sitl.campaigns.parallel"]),
    ("sitl.log_bench", {"companion.app"}, ["companion.app"]),     # the tangle that started these rules
    ("sitl.flights.fly", {"companion.config"}, ["companion.config"]),
    ("sitl.scenarios", {"sitl.plant.thrusters"}, ["sitl.plant.thrusters"]),
    ("sitl.links.netem_proxy", {"sitl.cli_args"}, ["sitl.cli_args"]),
    ("sitl.flights.model_matching", {"companion.core.rom", "sitl.plant.mujoco_plant"}, []),
    ("sitl.serve", {"sitl.fc.routing", "sitl.vehicle", "sitl.links.emulation"}, []),
])
def test_the_rules_catch_what_they_forbid(module, imported, wrong):
    assert violations(module, imported) == wrong


def test_every_room_the_rules_name_exists():
    rooms = {room for room in ALLOWED} | {a for allowed in ALLOWED.values() for a in allowed if a != "sitl"}
    assert all((ROOT / (room.replace(".", "/") + ".py")).exists() or (ROOT / room.replace(".", "/")).is_dir()
               for room in rooms)


def test_every_sitl_module_lives_in_a_room_the_rules_name():
    assert [m for m in SITL_MODULES if m != "sitl" and room_of(m) == "sitl"] == []
