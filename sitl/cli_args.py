"""Argument types and the bad-input error shared by the `m4-sitl` subcommands (sitl/cli.py
and sitl/flight_cli.py)."""

from __future__ import annotations

import argparse
from pathlib import Path


class BadInput(Exception):
    """A command-line argument is wrong, or the server cannot start with it."""


class Parser(argparse.ArgumentParser):
    def error(self, message):              # one line, not the usage block
        raise BadInput(f"{self.prog}: {message}")


def positive_number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def seed_number(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def output_dir(path: Path) -> Path:
    """`path` as an output folder, created if need be; BadInput in one line if it cannot be."""
    if path.exists() and not path.is_dir():
        raise BadInput(f"--out {path}: exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise BadInput(f"--out {path}: cannot create the folder ({e.strerror or e})") from None
    return path
