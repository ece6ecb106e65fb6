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
                                       mavutil,
                                       new_mav,
)

__all__ = ["COMPANION_COMPONENT_ID", "DIALECT", "FC_COMPONENT_ID", "FC_SYSTEM_ID", "mavlink", "mavutil", "new_mav"]
