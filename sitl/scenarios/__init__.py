"""The built-in scenarios (`m4-sitl list`), and resolving a name or a path to a scenario."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from m4.scenario import Scenario, load_scenario
from m4.toml_fields import ConfigError


def builtin_names() -> list[str]:
    return sorted(p.name.removesuffix(".toml") for p in resources.files(__name__).iterdir()
                  if p.name.endswith(".toml"))


def scenario_path(name_or_path: str) -> Path:
    """A built-in scenario's file, or the given path when it names a file."""
    if name_or_path in builtin_names():
        with resources.as_file(resources.files(__name__) / f"{name_or_path}.toml") as p:
            return Path(p)
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        return path
    raise ConfigError(f"unknown scenario {name_or_path!r}: not a built-in ({', '.join(builtin_names())}) "
                      f"nor a .toml file")


def resolve(name_or_path: str) -> Scenario:
    return load_scenario(scenario_path(name_or_path))
