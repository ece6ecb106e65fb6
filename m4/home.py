"""The flight controller's fixed home and the local NED frame around it, in one place.

The FC reports positions in local NED metres around a fixed home, and places that frame on the
WGS-84 ellipsoid with a flat-earth approximation (GLOBAL_POSITION_INT, HOME_POSITION); mission
items in a global frame come back into the local frame by the inverse of the same
approximation (m4.mission_items). Altitudes relative to home are heights above it: z_ned = -alt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

EARTH_RADIUS_M = 6378137.0


@dataclass(frozen=True)
class Home:
    lat_deg: float = 47.397742          # PX4's default SITL home (Zurich)
    lon_deg: float = 8.545594
    alt_amsl_m: float = 488.0

    def geodetic(self, ned_m) -> tuple[float, float, float]:
        """(lat_deg, lon_deg, alt_amsl_m) of a local NED point."""
        lat = self.lat_deg + math.degrees(ned_m[0] / EARTH_RADIUS_M)
        lon = self.lon_deg + math.degrees(ned_m[1] / self._east_radius_m())
        return lat, lon, self.alt_amsl_m - ned_m[2]

    def north_east_m(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """The local north and east (m) of a latitude and longitude: geodetic()'s inverse."""
        return (math.radians(lat_deg - self.lat_deg) * EARTH_RADIUS_M,
                math.radians(lon_deg - self.lon_deg) * self._east_radius_m())

    def _east_radius_m(self) -> float:
        return EARTH_RADIUS_M * math.cos(math.radians(self.lat_deg))
