"""Strict reading of TOML tables: every key checked, every error names the key.

Airframe, scenario and companion configuration files all go through `Table`, so a typo or
an out-of-range value is reported the same way everywhere ("m4.toml: [leg] length_m must
be > 0, got -1") and never turns into a traceback or a silent default. A required key that
is missing while a key close to it is there is reported as that unknown key
("unknown key durration_s (did you mean duration_s?)").
"""

from __future__ import annotations

import difflib
import math
import tomllib
from pathlib import Path
from typing import Any


class ConfigError(ValueError):
    """A configuration, airframe or scenario file is malformed; the message names the key."""


def load_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file, turning I/O and syntax errors into ConfigError."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, expected a TOML file") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not UTF-8 text (byte 0x{e.object[e.start]:02x} at offset {e.start}); "
                          f"TOML files must be UTF-8") from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read ({e.strerror or e})") from None


class Table:
    """One TOML table read key by key; `finish()` rejects the keys nobody asked for."""

    def __init__(self, data: Any, where: str):
        if not isinstance(data, dict):
            raise ConfigError(f"{where} must be a table, got {type(data).__name__}")
        self._data = dict(data)
        self._where = where
        self._seen: set[str] = set()

    @property
    def where(self) -> str:
        return self._where

    def has(self, key: str) -> bool:
        return key in self._data

    def _name(self, key: str) -> str:
        return f"{self._where} {key}"

    def _raw(self, key: str, default: Any) -> Any:
        self._seen.add(key)
        if key in self._data:
            return self._data[key]
        if default is _REQUIRED:
            misspelt = difflib.get_close_matches(key, [k for k in self._data if k not in self._seen], n=1)
            if misspelt:
                raise ConfigError(f"{self._where}: unknown key {misspelt[0]} (did you mean {key}?)")
            raise ConfigError(f"{self._name(key)} is missing")
        return default

    def number(self, key: str, default: Any = None, *, lo: float | None = None,
               hi: float | None = None, lo_open: bool = False, why: str = "") -> float:
        """A finite real number within [lo, hi] (lo excluded when lo_open); `why` the range is
        what it is goes into the message of a value outside it."""
        value = self._raw(key, _REQUIRED if default is None else default)
        return _check_number(self._name(key), value, lo, hi, lo_open, why)

    def integer(self, key: str, default: Any = None, *, lo: int | None = None,
                hi: int | None = None, why: str = "") -> int:
        value = self._raw(key, _REQUIRED if default is None else default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{self._name(key)} must be an integer, got {value!r}")
        _check_range(self._name(key), value, lo, hi, False, why)
        return value

    def boolean(self, key: str, default: Any = None) -> bool:
        value = self._raw(key, _REQUIRED if default is None else default)
        if not isinstance(value, bool):
            raise ConfigError(f"{self._name(key)} must be true or false, got {value!r}")
        return value

    def string(self, key: str, default: Any = None, *, choices: tuple[str, ...] | None = None) -> str:
        value = self._raw(key, _REQUIRED if default is None else default)
        if not isinstance(value, str):
            raise ConfigError(f"{self._name(key)} must be a string, got {value!r}")
        if choices is not None and value not in choices:
            raise ConfigError(f"{self._name(key)} must be one of {', '.join(choices)}; got {value!r}")
        return value

    def vector(self, key: str, length: int, default: Any = None, *, lo: float | None = None,
               hi: float | None = None, why: str = "") -> tuple[float, ...]:
        """A list of exactly `length` finite numbers, each within [lo, hi]."""
        value = self._raw(key, _REQUIRED if default is None else default)
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise ConfigError(f"{self._name(key)} must be a list of {length} numbers, got {value!r}")
        return tuple(_check_number(f"{self._name(key)}[{i}]", v, lo, hi, False, why)
                     for i, v in enumerate(value))

    def strings(self, key: str, length: int, default: Any = None, *,
                choices: tuple[str, ...] | None = None) -> tuple[str, ...]:
        """A list of exactly `length` strings, each one of `choices` when given."""
        value = self._raw(key, _REQUIRED if default is None else default)
        if not (isinstance(value, list) and len(value) == length and all(isinstance(v, str) for v in value)):
            raise ConfigError(f"{self._name(key)} must be a list of {length} strings, got {value!r}")
        if choices is not None and not set(value) <= set(choices):
            raise ConfigError(f"{self._name(key)} entries must be among {', '.join(choices)}; got {value!r}")
        return tuple(value)

    def matrix(self, key: str, rows: int, cols: int, *, lo: float | None = None,
               hi: float | None = None) -> tuple[tuple[float, ...], ...]:
        """A list of `rows` lists of `cols` finite numbers."""
        value = self._raw(key, _REQUIRED)
        if not isinstance(value, list) or len(value) != rows:
            raise ConfigError(f"{self._name(key)} must be a list of {rows} lists of {cols} numbers")
        return tuple(Table({key: row}, f"{self._name(key)}[{i}]").vector(key, cols, lo=lo, hi=hi)
                     for i, row in enumerate(value))

    def path(self, key: str, base_dir: Path | None = None, *, must_exist: bool = False) -> Path | None:
        """An optional file path ("" or absent: None), "~" expanded, a relative one taken from base_dir."""
        text = self.string(key, "")
        if not text:
            return None
        p = Path(text).expanduser()
        p = p if p.is_absolute() or base_dir is None else base_dir / p
        if must_exist and not p.is_file():
            raise ConfigError(f"{self._name(key)}: no such file {p}")
        return p

    def table(self, key: str, *, required: bool = False) -> "Table":
        """A sub-table (an empty one when absent and not required)."""
        value = self._raw(key, _REQUIRED if required else {})
        return Table(value, f"{self._where.rstrip(']')}.{key}]" if self._where.endswith("]")
                     else f"{self._where} [{key}]")

    def tables(self, key: str) -> list["Table"]:
        """An array of tables ([[key]]); empty when absent."""
        value = self._raw(key, [])
        if not isinstance(value, list):
            raise ConfigError(f"{self._name(key)} must be an array of tables ([[{key}]])")
        return [Table(v, f"{self._where} [[{key}]] #{i + 1}") for i, v in enumerate(value)]

    def finish(self) -> None:
        unknown = sorted(set(self._data) - self._seen)
        if unknown:
            raise ConfigError(f"{self._where}: unknown key(s) {', '.join(unknown)}")


class _Required:
    def __repr__(self) -> str:
        return "<required>"


_REQUIRED = _Required()


def _check_number(name: str, value: Any, lo: float | None, hi: float | None, lo_open: bool, why: str = "") -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(f"{name} must be finite, got {value!r}")
    _check_range(name, value, lo, hi, lo_open, why)
    return value


def _check_range(name: str, value: float, lo: float | None, hi: float | None, lo_open: bool, why: str = "") -> None:
    because = f" ({why})" if why else ""
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise ConfigError(f"{name} must be {'>' if lo_open else '>='} {lo:g}{because}, got {value:g}")
    if hi is not None and value > hi:
        raise ConfigError(f"{name} must be <= {hi:g}{because}, got {value:g}")
