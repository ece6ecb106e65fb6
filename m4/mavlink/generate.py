"""Regenerate the dialect's Python module from `mavlink_defs/m4.xml`.

    python -m m4.mavlink.generate [--output PATH]

The XML includes `common.xml`; it is resolved against the copy that ships inside the
installed pymavlink (its CRCs are the ones every peer of ours uses), never a download. The
output is deterministic, so a test regenerates it into a temporary folder and compares.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import shutil
import sys
import tempfile
from pathlib import Path

import pymavlink
from pymavlink.generator import mavgen

XML_PATH = Path(__file__).resolve().parents[2] / "mavlink_defs" / "m4.xml"
GENERATED_PATH = Path(__file__).resolve().with_name("m4_generated.py")
PYMAVLINK_V20_DIR = Path(pymavlink.__file__).resolve().parent / "dialects" / "v20"


def generate(output: Path, xml_path: Path = XML_PATH) -> None:
    """Write the Python3 MAVLink 2 module for the dialect at `xml_path` into `output`."""
    with tempfile.TemporaryDirectory(prefix="m4-mavgen-") as tmp:
        work = Path(tmp)
        for include in PYMAVLINK_V20_DIR.glob("*.xml"):
            shutil.copy(include, work / include.name)
        xml = work / xml_path.name
        shutil.copy(xml_path, xml)
        module = work / f"{xml.stem}.py"
        opts = mavgen.Opts(str(module), wire_protocol="2.0", language="Python3", validate=False)
        with contextlib.redirect_stdout(io.StringIO()) as log:
            ok = mavgen.mavgen(opts, [str(xml)])
        if not ok or not module.exists():
            raise RuntimeError(f"mavgen failed on {xml_path}:\n{log.getvalue()}")
        shutil.copy(module, output)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m m4.mavlink.generate", description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=GENERATED_PATH, help=f"default: {GENERATED_PATH}")
    args = parser.parse_args(argv)
    generate(args.output)
    print(f"wrote {args.output}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
