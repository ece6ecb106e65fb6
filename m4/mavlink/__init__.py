"""MAVLink for the M4: the dialect (MAVLink 2 only), UDP links, signing and tlogs.

Import every MAVLink thing from here (or `m4.mavlink.dialect`): it is the one place
that makes pymavlink speak MAVLink 2 and registers the project's dialect.
"""

from m4.mavlink.dialect import (
                                       COMPANION_COMPONENT_ID,
                                       DIALECT,
                                       FC_COMPONENT_ID,
                                       FC_SYSTEM_ID,
                                       mavlink,
                                       new_mav,
)


def __getattr__(name: str):
    """`mavutil`, loaded on first use (m4/mavlink/dialect.py)."""
    if name != "mavutil":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from m4.mavlink import dialect
    return dialect.mavutil


__all__ = ["COMPANION_COMPONENT_ID", "DIALECT", "FC_COMPONENT_ID", "FC_SYSTEM_ID", "mavlink", "mavutil", "new_mav"]
