"""A component's parameters, as the MAVLink parameter protocol shows them: the table, free of I/O.

Each parameter has a name in ArduPilot's style (capitals, digits and underscores, at most
`NAME_MAX` characters, the protocol's limit), a type (MAV_PARAM_TYPE's numbers: INT8 for a
switch, INT32 for a count, REAL32 for a quantity), a unit, a range, and where its value lives:
a getter and, for a parameter that may change in flight, a setter into the very objects that
use it. One without a setter is read-only: shown, never changed but in its file
(`read_only_why` says where and why).

`ParamTable.set` takes a value as a parameter message carries it (a 32-bit float) and either
applies it or says why not (`Refusal`): not a number, a whole-number type given a fraction,
out of range, read-only. Values are compared and kept at 32-bit precision, written as their
shortest decimal (0.3, not 0.30000001192092896), so what a ground station shows is what it set.

The FC's list is sitl/fc/params.py, the companion's companion/params.py; the protocol
(PARAM_REQUEST_LIST, _READ, _SET, PARAM_VALUE) is m4/mavlink/param_service.py, the file that
keeps the values set m4/params_file.py.
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

NAME_MAX = 16
_NAME = re.compile(r"[A-Z][A-Z0-9_]*\Z")


class ParamType(enum.IntEnum):
    """MAV_PARAM_TYPE's numbers for the types used here."""
    INT8 = 2
    INT32 = 6
    REAL32 = 9

    @property
    def whole(self) -> bool:
        return self is not ParamType.REAL32


def float32(value: float) -> float:
    """`value` as a 32-bit float carries it, written as its shortest decimal."""
    return float(str(np.float32(value)))


@dataclass(frozen=True)
class Param:
    name: str
    type: ParamType
    lo: float
    hi: float
    unit: str                                     # "" for a switch or a count
    text: str                                     # what it is, one line
    get: Callable[[], float]
    set: Callable[[float], None] | None = None    # None: read-only
    read_only_why: str = ""                       # for a read-only one: where it is changed, and why not here
    lo_open: bool = False                         # lo itself excluded

    @property
    def settable(self) -> bool:
        return self.set is not None

    def fault(self, value: float) -> str | None:
        """Why `value` cannot be this parameter's (None: it can); read-only is not judged here."""
        if not math.isfinite(value):
            return "not a number"
        if self.type.whole and value != int(value):
            return f"wrong type: {self.type.name} takes whole numbers"
        lo, hi = float32(self.lo), float32(self.hi)
        if value < lo or value > hi or (self.lo_open and value == lo):
            return f"out of range {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}]"
        return None


class Refusal(NamedTuple):
    name: str
    reason: str

    @property
    def text(self) -> str:
        return f"{self.name} refused: {self.reason}"


class ParamTable:
    def __init__(self, params: Iterable[Param]):
        self.params = tuple(params)
        self._index = {p.name: i for i, p in enumerate(self.params)}
        for p in self.params:
            if len(p.name) > NAME_MAX or not _NAME.match(p.name):
                raise ValueError(f"parameter name {p.name!r}: at most {NAME_MAX} capitals, digits and underscores")
            if not p.lo <= p.hi:
                raise ValueError(f"parameter {p.name}: empty range {p.lo:g}..{p.hi:g}")
            if (fault := p.fault(self.value(p))) is not None:
                raise ValueError(f"parameter {p.name}: its value {self.value(p):g} is {fault}")
        if len(self._index) != len(self.params):
            raise ValueError("parameter names must be unique")

    def __len__(self) -> int:
        return len(self.params)

    def index(self, name: str) -> int | None:
        return self._index.get(name)

    @staticmethod
    def value(p: Param) -> float:
        """The value in force, as the protocol carries it."""
        return float32(p.get())

    def set(self, name: str, value: float) -> Refusal | None:
        """Apply `value` (a 32-bit float) to parameter `name`, or say why not. KeyError: no such name."""
        p = self.params[self._index[name]]
        value = float32(value) if math.isfinite(value) else value
        reason = "read-only" if not p.settable else p.fault(value)
        if reason is not None:
            return Refusal(name, reason)
        p.set(int(value) if p.type.whole else value)
        return None
