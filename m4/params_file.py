"""The file that keeps the parameters a ground station set, across restarts: `NAME = value` lines.

A component loads it at start over its configuration (`ParamFile.load`): every entry must
name one of its settable parameters and hold a value that parameter takes, else ConfigError
naming the file and the entry, as the TOML configuration files are checked (m4/toml_fields.py).
Each accepted PARAM_SET writes the file anew (`ParamFile.record`: what it held and the new
value, as a whole new file renamed over the old one, so a crash never leaves half of one);
only the parameters set are in it, the rest keep their configured values. A missing file is
an empty one.
"""

from __future__ import annotations

import os
from pathlib import Path

from m4.params import ParamTable
from m4.toml_fields import ConfigError, load_toml

HEADER = "# parameters set over MAVLink (PARAM_SET); loaded at start over the configuration\n"


class ParamFile:
    def __init__(self, path: Path):
        self.path = Path(path)

    def load(self, table: ParamTable) -> None:
        """Apply the file's values to `table` (nothing when there is no file); ConfigError on a bad entry."""
        if not self.path.exists():
            return
        for name, value in load_toml(self.path).items():
            where = f"{self.path} {name}"
            i = table.index(name)
            if i is None:
                raise ConfigError(f"{where}: no such parameter")
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"{where} must be a number, got {value!r}")
            refusal = table.set(name, float(value))
            if refusal is not None:
                extra = f" ({table.params[i].read_only_why})" if refusal.reason == "read-only" else ""
                raise ConfigError(f"{where}: {refusal.reason}{extra}, got {value!r}")

    def record(self, name: str, value: float) -> str | None:
        """Keep `name = value` in the file; the reason when it could not be written (None: written)."""
        try:
            values = load_toml(self.path) if self.path.exists() else {}
        except ConfigError as e:
            return str(e)
        values[name] = value
        lines = [HEADER] + [f"{n} = {_toml_number(v)}\n" for n, v in sorted(values.items())]
        partial = self.path.with_name(self.path.name + ".partial")
        try:
            partial.write_text("".join(lines))
            os.replace(partial, self.path)
        except OSError as e:
            return f"cannot write {self.path}: {e.strerror or e}"
        return None


def _toml_number(value: float) -> str:
    return str(value) if isinstance(value, int) else repr(float(value))
