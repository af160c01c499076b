"""LOCAL_NED ↔ WGS84 around a fixed origin: the flat-earth projection ArduPilot uses (pure).

ArduPilot's ``Location::get_distance_NE``/``offset`` treat the earth as locally flat with
longitude lines scaled by cos(latitude); over the few kilometres a multirotor flies from
its origin the error is far below a GPS's. The same projection serves GLOBAL_POSITION_INT,
HOME_POSITION and the global targets a ground station sends (DO_REPOSITION,
SET_POSITION_TARGET_GLOBAL_INT), so a point sent back and forth is exact to 1 mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["EARTH_RADIUS_M", "FlatEarth", "valid_lat_lon_e7"]

EARTH_RADIUS_M = 6378137.0  # WGS84 equatorial radius [m]


def valid_lat_lon_e7(lat_e7: int, lon_e7: int) -> bool:
    """True for a latitude/longitude in degE7 within ±90° / ±180° (ArduPilot check_latlng)."""
    return abs(lat_e7) <= 900_000_000 and abs(lon_e7) <= 1_800_000_000


@dataclass(frozen=True)
class FlatEarth:
    """Projection around the LOCAL_NED origin (``lat_deg``, ``lon_deg``, ``alt_amsl_m``)."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float

    @property
    def _cos_lat(self) -> float:
        return max(math.cos(math.radians(self.lat_deg)), 1e-9)

    def geodetic_e7(self, pos_ned_m) -> tuple[int, int, int]:
        """(lat degE7, lon degE7, alt mm AMSL) of a LOCAL_NED point."""
        lat = self.lat_deg + math.degrees(pos_ned_m[0] / EARTH_RADIUS_M)
        lon = self.lon_deg + math.degrees(pos_ned_m[1] / (EARTH_RADIUS_M * self._cos_lat))
        alt_m = self.alt_amsl_m - pos_ned_m[2]
        return round(lat * 1e7), round(lon * 1e7), round(alt_m * 1000.0)

    def ned_from_lat_lon(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """(north, east) [m] of a latitude/longitude [deg]."""
        north = math.radians(lat_deg - self.lat_deg) * EARTH_RADIUS_M
        dlon = (lon_deg - self.lon_deg + 180.0) % 360.0 - 180.0
        east = math.radians(dlon) * EARTH_RADIUS_M * self._cos_lat
        return north, east
