"""Argument types shared by the command lines (`m4-sitl`, `m4-companion`, the benchmarks and the
link tools): each turns a string into a value or raises argparse's error that names what is wrong."""

from __future__ import annotations

import argparse
import math


def _converted(text: str, kind: type, what: str):
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not {what}: {text!r}") from None


def number(text: str) -> float:
    return _converted(text, float, "a number")


def positive_number(text: str) -> float:
    value = number(text)
    if not (value > 0.0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def positive_int(text: str) -> int:
    value = _converted(text, int, "an integer")
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return value


def seed_number(text: str) -> int:
    value = _converted(text, int, "an integer")
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value
