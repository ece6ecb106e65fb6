"""Install the project's dialect where pymavlink's own tools look for dialects, so that
`mavlogdump.py --dialect m4 flight.tlog`, `MAVExplorer.py --dialect m4 flight.tlog` and
`mavproxy.py --dialect m4` decode M4_SETPOINT, M4_FAULT_STATUS, ... by name.

    python -m m4.mavlink.install_dialect [--pymavlink DIR]

Writes the generated module (m4/mavlink/m4_generated.py, the same the project imports) as
`pymavlink/dialects/v20/m4.py` and the XML beside it (and into
`message_definitions/v1.0/` when the pymavlink is a source checkout that has one). Its
includes (common.xml, ...) already ship with pymavlink. Run it again after upgrading
pymavlink; the project itself never needs it (m4.mavlink registers the dialect at import).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import pymavlink

from m4.mavlink.dialect import DIALECT
from m4.mavlink.generate import GENERATED_PATH, XML_PATH

PYMAVLINK_DIR = Path(pymavlink.__file__).resolve().parent


def install(pymavlink_dir: Path = PYMAVLINK_DIR) -> list[Path]:
    """Copy the dialect into the pymavlink package at `pymavlink_dir`; the files written."""
    v20 = pymavlink_dir / "dialects" / "v20"
    if not v20.is_dir():
        raise FileNotFoundError(f"{pymavlink_dir} is not a pymavlink package (no dialects/v20)")
    written = [Path(shutil.copyfile(GENERATED_PATH, v20 / f"{DIALECT}.py")),
               Path(shutil.copyfile(XML_PATH, v20 / f"{DIALECT}.xml"))]
    definitions = pymavlink_dir / "message_definitions" / "v1.0"
    if definitions.is_dir():
        written.append(Path(shutil.copyfile(XML_PATH, definitions / f"{DIALECT}.xml")))
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m m4.mavlink.install_dialect", description=__doc__.splitlines()[0])
    parser.add_argument("--pymavlink", type=Path, default=PYMAVLINK_DIR, metavar="DIR",
                        help=f"the pymavlink package folder (default: the installed one, {PYMAVLINK_DIR})")
    args = parser.parse_args(argv)
    try:
        written = install(args.pymavlink)
    except OSError as e:
        print(f"install_dialect: error: {e}", file=sys.stderr)
        return 1
    for path in written:
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
