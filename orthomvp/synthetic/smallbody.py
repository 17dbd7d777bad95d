"""An analytic irregular small body (asteroid-like): its radius along each direction, its mesh,
its DEM of radii on a lon/lat grid, and visibility truth marched against its radius."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import trimesh
from affine import Affine
from pyproj import CRS

from orthomvp.camera import PinholeCamera
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import unit_vector
from orthomvp.synthetic.truth import visibility_truth

SMALL_BODY_RADIUS = 2500.0
SMALL_BODY_AXES = (1.6, 1.0, 0.85)  # semi-axes of the base ellipsoid, in proportion (x, y, z)
CRATER_DEPTH = 0.2  # bowl depth below the rim crest / rim diameter
CRATER_RIM = 0.04  # rim height above the surroundings / rim diameter
CRATER_RIM_WIDTH = 0.35  # e-folding width of the rim's outer flank, in crater radii


@dataclass(frozen=True, eq=False)
class SmallBody:
    """An irregular, star-shaped, asteroid-like body given analytically by its radius (metres
    from the body centre) along each body-fixed direction; frame: x along the long axis, z the
    short one (as a spin axis).

    r(u) = R e(u) (1 + sum_k a_k exp((u . b_k - 1) / w_k^2)) + sum_j crater_j(u), where e(u) is
    the radius of a triaxial ellipsoid with semi-axes in the proportion ``axes`` (product 1, so
    ``mean_radius`` R is its volume-equivalent radius), the sum over k smooth bumps of relative
    amplitude a_k and angular width w_k (radians) centred on unit vectors b_k, and each crater
    a parabolic bowl with a raised rim: with rho = (angle from its centre) / (its angular
    radius) and D its nominal diameter (2 R times the angular radius), CRATER_DEPTH D (rho^2 - 1)
    + CRATER_RIM D inside, CRATER_RIM D exp(-((rho - 1) / CRATER_RIM_WIDTH)^2) outside.
    """

    mean_radius: float
    axes: np.ndarray
    bump_centres: np.ndarray
    bump_amplitudes: np.ndarray
    bump_widths: np.ndarray
    crater_centres: np.ndarray
    crater_radii: np.ndarray

    @classmethod
    def from_seed(
        cls,
        seed: int = 0,
        mean_radius: float = SMALL_BODY_RADIUS,
        bumps: int = 12,
        craters: int = 8,
    ) -> SmallBody:
        """A random body: bumps of amplitude up to 20% and width 0.3-0.8 rad, craters of
        angular radius 6-15 degrees, all centred at random directions."""
        rng = np.random.default_rng(seed)
        axes = np.array(SMALL_BODY_AXES) / np.prod(SMALL_BODY_AXES) ** (1 / 3)
        b = rng.normal(size=(bumps, 3))
        c = rng.normal(size=(craters, 3))
        return cls(
            mean_radius,
            axes,
            b / np.linalg.norm(b, axis=1, keepdims=True),
            rng.uniform(-0.2, 0.2, bumps),
            rng.uniform(0.3, 0.8, bumps),
            c / np.linalg.norm(c, axis=1, keepdims=True),
            np.radians(rng.uniform(6.0, 15.0, craters)),
        )

    def radius_along(self, u: np.ndarray) -> np.ndarray:
        """Radius (...) in metres along body-fixed unit vectors ``u`` (..., 3)."""
        u = np.asarray(u, dtype=np.float64)
        ellipsoid = 1.0 / np.sqrt(np.sum((u / self.axes) ** 2, axis=-1))
        bumps = np.exp((u @ self.bump_centres.T - 1.0) / self.bump_widths**2) @ self.bump_amplitudes
        rho = np.arccos(np.clip(u @ self.crater_centres.T, -1.0, 1.0)) / self.crater_radii
        diameter = 2.0 * self.mean_radius * self.crater_radii
        crater = np.where(
            rho < 1.0,
            CRATER_DEPTH * diameter * (rho**2 - 1.0) + CRATER_RIM * diameter,
            CRATER_RIM * diameter * np.exp(-(((rho - 1.0) / CRATER_RIM_WIDTH) ** 2)),
        )
        return self.mean_radius * ellipsoid * (1.0 + bumps) + crater.sum(axis=-1)

    def radius(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Radius in metres at planetocentric ``lon``, ``lat`` (radians)."""
        return self.radius_along(unit_vector(np.asarray(lon), np.asarray(lat)))

    def surface_point(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Body-fixed xyz (..., 3) of the surface at ``lon``, ``lat`` (radians)."""
        u = unit_vector(np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64))
        return self.radius_along(u)[..., None] * u

    def surface_normal(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Unit outward normal (..., 3) at ``lon``, ``lat`` (radians; central differences of
        1e-7 rad, so not at the poles)."""
        e = 1e-7
        d_lon = self.surface_point(lon + e, lat) - self.surface_point(lon - e, lat)
        d_lat = self.surface_point(lon, lat + e) - self.surface_point(lon, lat - e)
        n = np.cross(d_lon, d_lat)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    @cached_property
    def max_radius(self) -> float:
        """An upper bound of the radius, metres."""
        bumps = np.clip(self.bump_amplitudes, 0, None).sum()
        rims = CRATER_RIM * 2.0 * self.mean_radius * self.crater_radii.sum()
        return float(self.mean_radius * self.axes.max() * (1.0 + bumps) + rims)

    def mesh(self, subdivisions: int = 5) -> trimesh.Trimesh:
        """The surface on an icosphere's vertex directions (``subdivisions`` 5: 10,242
        vertices, 20,480 triangles), body-fixed metres, faces wound outward."""
        sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
        u = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
        return trimesh.Trimesh(
            self.radius_along(u)[:, None] * u, sphere.faces, process=False, validate=False
        )

    def terrain(
        self, step: float = 1.0, bounds: tuple[float, float, float, float] = (-180, -90, 180, 90)
    ) -> Terrain:
        """The body as a DEM of radii (``radius_values=True``) on a lon/lat grid of ``step``
        degrees covering ``bounds`` (left, bottom, right, top; degrees), CRS
        ``+proj=longlat +R=mean_radius``. The global default has no posts on the poles and
        no cells across the 180-degree meridian: its mesh has small holes there."""
        left, bottom, right, top = bounds
        cols, rows = round((right - left) / step), round((top - bottom) / step)
        crs = CRS.from_proj4(f"+proj=longlat +R={self.mean_radius!r} +no_defs")
        grid = Terrain(
            np.zeros((rows, cols)),
            Affine(step, 0, left, 0, -step, top),
            crs,
            radius_values=True,
            name="small-body",
        )
        return grid.with_values(self.radius(*grid.pixel_to_lonlat(*grid.grid())))

    def below(self, xyz: np.ndarray) -> np.ndarray:
        """Whether body-fixed points ``xyz`` (n, 3) lie inside the body (closer to its centre
        than the radius in their direction, by more than 1 um)."""
        rho = np.linalg.norm(xyz, axis=1)
        return rho < self.radius_along(xyz / rho[:, None]) - 1e-6

    def visibility_truth(
        self, terrain: Terrain, camera: PinholeCamera, step: float | None = None
    ) -> np.ndarray:
        """Truth visibility codes (rows, cols) uint8 of the posts of a lon/lat ``terrain`` grid
        (placed on the analytic surface, facing by the analytic normal) for ``camera``, marched
        against the analytic radius every ``step`` metres (default a quarter of the post
        spacing) until the segment leaves the sphere of :attr:`max_radius`; see
        :func:`orthomvp.synthetic.truth.visibility_truth`."""
        lon, lat = terrain.pixel_to_lonlat(*terrain.grid())
        return visibility_truth(
            camera,
            self.surface_point(lon, lat),
            self.surface_normal(lon, lat),
            self.below,
            self.max_radius,
            step or min(terrain.post_spacing()) / 4,
        )
