"""THE one place that picks MAVLink 2 and the project's dialect; import MAVLink from here.

pymavlink decides the wire protocol from the environment when it first loads (MAVLink 1
unless `MAVLINK20` is set) and keeps one global dialect, so both are settled here, before
anything else imports pymavlink. The dialect module (generated from `mavlink_defs/m4.xml`
by `python -m m4.mavlink.generate`) is registered as `pymavlink.dialects.v20.m4`, so
`mavutil.mavlink_connection(..., dialect="m4")` finds it without regenerating anything into
site-packages; `new_mav()` gives the bare protocol object for a transport of one's own.
`mavutil` (tlogs, connections) is loaded on first use, with the dialect set: it loads
pymavlink's two largest dialects, a tenth of a second of every start of a process that never
calls it (the SITL and the companion in flight).
pymavlink's own log lines (one per rejected signature) are rate-limited (m4/log_limit.py).
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

os.environ["MAVLINK20"] = "1"

# Imported after MAVLINK20 is set, on purpose.
import pymavlink.dialects.v20 as _v20

from m4.bytecode_cache import load_module
from m4.log_limit import RepeatFilter
from m4.mavlink.frame_packer import x25_crc

# 35 000 lines: its bytecode cached even where Python may not cache it (m4/bytecode_cache.py)
mavlink = load_module(f"{__package__}.m4_generated", Path(__file__).with_name("m4_generated.py"))
from m4.mavlink.packing import fast_pack  # it wraps the dialect loaded above

DIALECT = "m4"
sys.modules[f"{_v20.__name__}.{DIALECT}"] = mavlink
setattr(_v20, DIALECT, mavlink)
# pymavlink logs every rejected signature ("sig mismatch", "bad new stream") at INFO: a peer
# with the wrong key would flood the log of any process that shows INFO.
logging.getLogger(mavlink.__name__).addFilter(RepeatFilter())
# pymavlink checks and signs every packet's CRC through fastcrc's C mcrf4xx when it is installed
# (recent pymavlink requires it); without it, byte by byte in Python. Its fast path takes any
# mcrf4xx(data, crc): binascii's (frame_packer) stands in, about 4x fastcrc's time.
if mavlink.mcrf4xx is None:
    mavlink.mcrf4xx = x25_crc
    mavlink.x25crc = mavlink._x25crc_fast
# Every frame sent is packed (and signed) by m4/mavlink/packing.py: pymavlink's bytes, faster.
mavlink.MAVLink_message._pack = fast_pack

FC_SYSTEM_ID = 1
FC_COMPONENT_ID = 1                                  # MAV_COMP_ID_AUTOPILOT1
COMPANION_COMPONENT_ID = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER    # 191


def __getattr__(name: str):
    """`mavutil`, imported and set to the project's dialect on first use."""
    if name != "mavutil":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from pymavlink import mavutil
    mavutil.set_dialect(DIALECT)
    globals()["mavutil"] = mavutil
    return mavutil


def new_mav(file, source_system: int, source_component: int) -> mavlink.MAVLink:
    """A MAVLink 2 protocol object writing packed packets to `file.write(bytes)`.

    Robust parsing: garbage and rejected packets come back as BAD_DATA instead of raising.
    """
    mav = mavlink.MAVLink(file, srcSystem=source_system, srcComponent=source_component)
    mav.robust_parsing = True
    return mav


__all__ = ["COMPANION_COMPONENT_ID", "DIALECT", "FC_COMPONENT_ID", "FC_SYSTEM_ID", "mavlink", "mavutil", "new_mav"]
