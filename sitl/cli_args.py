"""Argument types and the bad-input error shared by the `m4-sitl` subcommands (sitl/cli.py
and sitl/flight_cli.py)."""

from __future__ import annotations

import argparse


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
