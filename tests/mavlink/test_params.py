"""The parameter table (m4/params.py) and the file that keeps what is set (m4/params_file.py),
shared by the FC and the companion; docs/parameters.md lists every parameter of both."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

from companion.config import load_config
from companion.params import CompanionParams
from m4.airframe import load_airframe
from m4.params import Param, ParamTable, ParamType
from m4.params_file import ParamFile
from m4.scenario import PlantOptions, Scenario
from m4.toml_fields import ConfigError
from sitl.vehicle import Vehicle

DOCS = Path(__file__).resolve().parents[2] / "docs" / "parameters.md"


class Box:
    def __init__(self, value):
        self.value = value


def _param(name="M4_GAIN", box=None, **kw) -> Param:
    box = box or Box(0.3)
    return Param(name, kw.pop("type", ParamType.REAL32), kw.pop("lo", 0.0), kw.pop("hi", 1.0), "", "a gain",
                 get=lambda: box.value, set=lambda v: setattr(box, "value", v), **kw)


@pytest.mark.parametrize("name", ["M4_A_NAME_TOO_LONG", "m4_lower", "4_DIGIT_FIRST", "M4-DASH", ""])
def test_a_name_that_is_not_ardupilot_style_or_longer_than_16_is_refused(name):
    with pytest.raises(ValueError, match="at most 16"):
        ParamTable([_param(name)])


def test_duplicate_names_and_a_value_outside_its_own_range_are_refused():
    with pytest.raises(ValueError, match="unique"):
        ParamTable([_param(), _param()])
    with pytest.raises(ValueError, match="out of range"):
        ParamTable([_param(box=Box(2.0))])


def test_values_are_taken_at_32_bit_precision_and_kept_as_their_shortest_decimal():
    box = Box(0.1)
    table = ParamTable([_param(box=box, hi=0.3)])
    assert table.set("M4_GAIN", 0.30000001192092896) is None          # 0.3 as a float carries it: in range
    assert box.value == 0.3


def test_whole_number_types_take_whole_numbers_only_and_set_them_as_ints():
    box = Box(1)
    table = ParamTable([_param(box=box, type=ParamType.INT8)])
    assert table.set("M4_GAIN", 0.5).reason == "wrong type: INT8 takes whole numbers"
    assert table.set("M4_GAIN", 0.0) is None and box.value == 0 and isinstance(box.value, int)


def test_a_read_only_parameter_is_refused_whatever_the_value():
    table = ParamTable([Param("M4_FIXED", ParamType.REAL32, 0.0, 1.0, "", "fixed", get=lambda: 0.5)])
    assert table.set("M4_FIXED", 0.5).reason == "read-only"


def test_the_file_keeps_what_it_held_and_the_new_value_and_is_loaded_back(tmp_path):
    path = tmp_path / "p.toml"
    assert ParamFile(path).record("M4_GAIN", 0.25) is None
    assert ParamFile(path).record("M4_OTHER", 1) is None
    text = path.read_text()
    assert "M4_GAIN = 0.25\n" in text and "M4_OTHER = 1\n" in text
    box = Box(0.5)
    with pytest.raises(ConfigError, match=r"p\.toml M4_OTHER: no such parameter"):
        ParamFile(path).load(ParamTable([_param(box=box)]))
    path.write_text("M4_GAIN = 0.25\n")
    ParamFile(path).load(ParamTable([_param(box=box)]))
    assert box.value == 0.25


def test_a_file_that_cannot_be_written_says_why(tmp_path):
    assert "cannot write" in ParamFile(tmp_path / "no-such-folder" / "p.toml").record("M4_GAIN", 0.25)


def _documented() -> dict[str, list[str]]:
    rows = [line.split("|")[1:-1] for line in DOCS.read_text().splitlines() if line.startswith("| `")]
    return {re.sub(r"`", "", cells[0]).strip(): [c.strip() for c in cells] for cells in rows}


def test_the_docs_list_every_parameter_of_both_with_its_range_default_and_whether_it_is_settable():
    with contextlib.redirect_stderr(io.StringIO()):
        fc = Vehicle(Scenario(name="hover", duration_s=10.0, plant=PlantOptions(esc_telemetry=True)),
                     load_airframe()).fc.params.table
    companion = CompanionParams(load_config(None)).table
    documented = _documented()
    for table in (fc, companion):
        for p in table.params:
            cells = documented.pop(p.name)
            assert cells[1:6] == [p.type.name, p.unit or "-", f"{'(' if p.lo_open else '['}{p.lo:g}, {p.hi:g}]",
                                  f"{table.value(p):g}", "settable" if p.settable else "read-only"], p.name
    assert not {n for n in documented if re.fullmatch(r"[A-Z][A-Z0-9_]*", n)}, "documented but not a parameter"
