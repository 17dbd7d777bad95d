"""The lunar tile of the synthetic scenes: its local frame and its analytic, lit surface.

The Moon is taken as a sphere of :data:`MOON_RADIUS`. Local coordinates ``(x, y)`` are metres
east and north of the tile centre ``(lon0, lat0)`` along the equirectangular grid:
``x = R cos(lat0) (lon - lon0)``, ``y = R (lat - lat0)``. Heights are metres above the sphere;
world points are body-fixed Cartesian metres.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from orthomvp.geometry.vectors import unit_vector

MOON_RADIUS = 1737400.0
MOON_CRS = "+proj=longlat +R=1737400 +no_defs"

LocalField = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""A function of local (x, y) metres: heights in metres, or albedo in [0, 1]."""


def local_frame(lon: float, lat: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body-fixed unit vectors (up, east, north) at planetocentric ``lon``, ``lat`` (radians)."""
    up = unit_vector(np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64))
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    return up, east, np.cross(up, east)


@dataclass(frozen=True, eq=False)
class LocalSurface:
    """The analytic surface of a tile centred on ``lon0``, ``lat0`` (radians): ``height`` and
    ``albedo`` of local (x, y), lit from the body-fixed unit vector ``sun``."""

    lon0: float
    lat0: float
    height: LocalField
    albedo: LocalField
    sun: np.ndarray

    def lonlat_to_local(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lon, lat) radians to local (x, y) metres."""
        dlon = (lon - self.lon0 + np.pi) % (2 * np.pi) - np.pi
        return MOON_RADIUS * np.cos(self.lat0) * dlon, MOON_RADIUS * (lat - self.lat0)

    def local_to_lonlat(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local (x, y) metres to (lon, lat) radians."""
        return self.lon0 + x / (MOON_RADIUS * np.cos(self.lat0)), self.lat0 + y / MOON_RADIUS

    def world_to_local(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body-fixed xyz (..., 3) to local (x, y) and height above the sphere, metres."""
        rho = np.linalg.norm(xyz, axis=-1)
        lon = np.arctan2(xyz[..., 1], xyz[..., 0])
        lat = np.arcsin(np.clip(xyz[..., 2] / rho, -1, 1))
        x, y = self.lonlat_to_local(lon, lat)
        return x, y, rho - MOON_RADIUS

    def surface_point(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Body-fixed xyz (..., 3) of the surface above local (x, y)."""
        lon, lat = self.local_to_lonlat(x, y)
        return (MOON_RADIUS + self.height(x, y))[..., None] * unit_vector(lon, lat)

    def surface_normal(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Unit outward normal (..., 3) at local (x, y) (central differences, 1 cm)."""
        e = 0.01
        dx = self.surface_point(x + e, y) - self.surface_point(x - e, y)
        dy = self.surface_point(x, y + e) - self.surface_point(x, y - e)
        n = np.cross(dx, dy)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def radiance(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Lambertian radiance at local (x, y): albedo * (0.25 + 0.75 max(0, n . sun))."""
        n = self.surface_normal(x, y)
        return self.albedo(x, y) * (0.25 + 0.75 * np.clip(n @ self.sun, 0, None))

    def below(self, xyz: np.ndarray) -> np.ndarray:
        """Whether body-fixed points ``xyz`` (n, 3) lie under the surface (by more than 1 um)."""
        x, y, h = self.world_to_local(xyz)
        return h < self.height(x, y) - 1e-6
