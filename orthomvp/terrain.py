"""DEM grids with their georeference, body and height convention.

Conventions (see ARCHITECTURE.md):

- Pixel coordinates are ``(c, r)`` = (column, row); integer values are pixel *centres*.
  GeoTIFF transforms refer to pixel corners; the half-pixel shift happens here and only here.
- Map coordinates are ``(lon, lat)`` in radians inside the library (degrees in files and CLI).
- DEM values are heights above the body's reference surface named by the CRS (GDAL's
  convention), or, with ``radius_values=True``, distances from the body centre (the MVP paper's
  convention). :meth:`Terrain.to_world` and :meth:`Terrain.from_world` speak the terrain's own
  convention.
- The world frame is body-fixed Cartesian metres (``world="body"``), or, for aerial data whose
  cameras live in the DEM's projected CRS, (easting, northing, height) taken as Cartesian
  (``world="map"``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
from affine import Affine
from pyproj import CRS, Transformer
from pyproj.exceptions import CRSError

from orthomvp.errors import InputError
from orthomvp.raster import open_raster, write_geotiff

WORLD_FRAMES = ("body", "map")


def unit_vector(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Eq. (3): body-fixed unit vector (..., 3) of planetocentric ``lon``, ``lat`` (radians)."""
    cl = np.cos(lat)
    return np.stack([np.cos(lon) * cl, np.sin(lon) * cl, np.sin(lat)], axis=-1)


def horizontal_crs(crs: CRS) -> CRS:
    """The horizontal part of a (possibly compound) CRS."""
    if crs.is_compound:
        return crs.sub_crs_list[0]
    return crs


def parse_crs(value: object, source: str) -> CRS:
    """A pyproj CRS from anything pyproj accepts (WKT, PROJ string, 'IAU_2015:30100', ...)."""
    try:
        return horizontal_crs(CRS.from_user_input(value))
    except CRSError as exc:
        raise InputError(f"{source}: cannot understand CRS {value!r} ({exc})") from exc


@dataclass(frozen=True)
class Terrain:
    """A DEM on a regular grid: values, georeference, body and conventions.

    ``values`` is float64 ``(rows, cols)``, NaN at nodata posts (holes). ``transform`` maps pixel
    *corner* coordinates to CRS coordinates (GDAL convention).
    """

    values: np.ndarray
    transform: Affine
    crs: CRS
    radius_values: bool = False
    world: str = "body"
    name: str = field(default="dem", compare=False)

    def __post_init__(self) -> None:
        vals = np.asarray(self.values, dtype=np.float64)
        if vals.ndim != 2 or min(vals.shape) < 2:
            raise InputError(f"{self.name}: a DEM needs at least 2 x 2 posts, got {vals.shape}")
        object.__setattr__(self, "values", vals)
        object.__setattr__(self, "crs", horizontal_crs(self.crs))
        if self.world not in WORLD_FRAMES:
            raise InputError(f"world frame must be one of {WORLD_FRAMES}, not {self.world!r}")
        if not (self.crs.is_geographic or self.crs.is_projected):
            raise InputError(f"{self.name}: CRS is neither geographic nor projected")
        if self.world == "map" and not self.crs.is_projected:
            raise InputError(f"{self.name}: world='map' needs a projected CRS")
        if self.transform.b != 0 or self.transform.d != 0:
            raise InputError(f"{self.name}: rotated georeferences are not supported")
        if not np.isfinite(vals).any():
            raise InputError(f"{self.name}: the DEM holds no valid heights")

    # ----------------------------------------------------------------- construction and I/O
    @classmethod
    def read(
        cls,
        path: str | Path,
        radius_values: bool = False,
        world: str = "body",
        crs: object | None = None,
    ) -> Terrain:
        """Read band 1 of a GeoTIFF DEM; nodata posts become NaN. ``crs`` overrides the file's."""
        with open_raster(path) as src:
            try:
                band = src.read(1, masked=True)
            except Exception as exc:  # rasterio raises several unrelated types on corrupt data
                raise InputError(f"{path}: corrupt raster data ({exc})") from exc
            file_crs = src.crs
            transform = src.transform
        if crs is not None:
            the_crs = parse_crs(crs, str(path))
        elif file_crs is None:
            raise InputError(f"{path}: the DEM has no CRS; give one with --dem-crs")
        else:
            the_crs = parse_crs(file_crs.to_wkt(), str(path))
        if transform == Affine.identity():
            raise InputError(f"{path}: the DEM has no georeference (identity transform)")
        values = np.ma.filled(band.astype(np.float64), np.nan)
        return cls(values, transform, the_crs, radius_values, world, name=str(path))

    def write(self, path: str | Path, values: np.ndarray | None = None) -> None:
        """Write ``values`` (default: this DEM's) as float32 GeoTIFF on this grid, NaN = nodata."""
        data = self.values if values is None else values
        write_geotiff(path, data.astype(np.float32), self.transform, self.crs, nodata=np.nan)

    def with_values(self, values: np.ndarray) -> Terrain:
        """The same grid and conventions with other values."""
        return replace(self, values=np.asarray(values, dtype=np.float64))

    # ----------------------------------------------------------------------------- the grid
    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        return self.values.shape  # type: ignore[return-value]

    @property
    def valid(self) -> np.ndarray:
        """Boolean (rows, cols): posts that hold a height."""
        return np.isfinite(self.values)

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel-centre coordinates ``(c, r)`` of every post, each (rows, cols) float64."""
        rows, cols = self.shape
        r, c = np.mgrid[0:rows, 0:cols].astype(np.float64)
        return c, r

    @property
    def S(self) -> np.ndarray:
        """Eq. (2): 3x3 affine from pixel-centre ``(c, r, 1)`` to CRS coordinates ``(x, y, 1)``.

        For geographic CRSs these are (lon, lat) in degrees, exactly the paper's S; for projected
        CRSs they are map units (metres). Note: the paper's t_c, t_r name the upper-left corner;
        here the translation is that of the centre of pixel (0, 0), because integer pixel
        coordinates are centres.
        """
        t = self.transform @ Affine.translation(0.5, 0.5)
        return np.array([[t.a, t.b, t.c], [t.d, t.e, t.f], [0.0, 0.0, 1.0]])

    def pixel_to_crs(self, c: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel-centre coordinates to CRS coordinates (degrees or map units)."""
        S = self.S
        c = np.asarray(c, dtype=np.float64)
        r = np.asarray(r, dtype=np.float64)
        return S[0, 0] * c + S[0, 1] * r + S[0, 2], S[1, 0] * c + S[1, 1] * r + S[1, 2]

    def crs_to_pixel(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """CRS coordinates to pixel-centre coordinates."""
        Si = np.linalg.inv(self.S)
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return Si[0, 0] * x + Si[0, 1] * y + Si[0, 2], Si[1, 0] * x + Si[1, 1] * y + Si[1, 2]

    # --------------------------------------------------------------------------- the body
    @cached_property
    def geodetic_crs(self) -> CRS:
        """The geographic CRS (lon/lat on the body) underlying this DEM's CRS."""
        return self.crs if self.crs.is_geographic else self.crs.geodetic_crs

    @cached_property
    def radii(self) -> tuple[float, float]:
        """(semi-major, semi-minor) axes of the body's reference ellipsoid, metres."""
        ell = self.geodetic_crs.ellipsoid
        return float(ell.semi_major_metre), float(ell.semi_minor_metre)

    @property
    def is_sphere(self) -> bool:
        """True when the reference body is a sphere (then eqs. (3)-(4) are exact)."""
        a, b = self.radii
        return abs(a - b) < 1e-9 * a

    @cached_property
    def _to_lonlat(self) -> Transformer | None:
        if self.crs.is_geographic:
            return None
        return Transformer.from_crs(self.crs, self.geodetic_crs, always_xy=True)

    @cached_property
    def _to_geocentric(self) -> Transformer:
        a, b = self.radii
        geocent = CRS.from_proj4(f"+proj=geocent +a={a!r} +b={b!r} +units=m +no_defs")
        return Transformer.from_crs(self.geodetic_crs.to_3d(), geocent, always_xy=True)

    @cached_property
    def centre_lon(self) -> float:
        """Longitude of the grid centre, radians; longitudes are returned within pi of it."""
        rows, cols = self.shape
        mid = np.array([(cols - 1) / 2, (rows - 1) / 2])
        lon, _ = self.pixel_to_lonlat(mid[0], mid[1], wrap=False)
        return float(lon)

    def pixel_to_lonlat(
        self, c: np.ndarray, r: np.ndarray, wrap: bool = True
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pixel-centre coordinates to body (lon, lat) in radians (geodetic for ellipsoids)."""
        x, y = self.pixel_to_crs(c, r)
        if self._to_lonlat is not None:
            x, y = self._to_lonlat.transform(x, y)
        lon, lat = np.radians(x), np.radians(y)
        return (self._wrap(lon) if wrap else lon), lat

    def lonlat_to_pixel(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body (lon, lat) in radians to pixel-centre coordinates."""
        x, y = np.degrees(self._wrap(np.asarray(lon))), np.degrees(np.asarray(lat))
        if self._to_lonlat is not None:
            x, y = self._to_lonlat.transform(x, y, direction="INVERSE")
        return self.crs_to_pixel(x, y)

    def _wrap(self, lon: np.ndarray) -> np.ndarray:
        """Longitudes within pi of the grid centre (a grid may straddle +-180 degrees)."""
        if not self.crs.is_geographic:
            return lon
        return self.centre_lon + (lon - self.centre_lon + np.pi) % (2 * np.pi) - np.pi

    def value_to_height(self, value: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """DEM values to heights above the reference surface (identity unless radius values)."""
        if not self.radius_values:
            return np.asarray(value, dtype=np.float64)
        return np.asarray(value, dtype=np.float64) - self.reference_radius(lat)

    def reference_radius(self, lat: np.ndarray) -> np.ndarray:
        """Distance from the body centre to the reference surface at planetocentric ``lat``."""
        a, b = self.radii
        lat = np.asarray(lat, dtype=np.float64)
        return a * b / np.hypot(b * np.cos(lat), a * np.sin(lat))

    # ---------------------------------------------------------------- map <-> world frame
    def to_world(self, c: np.ndarray, r: np.ndarray, value: np.ndarray) -> np.ndarray:
        """Eqs. (1)-(4): pixel-centre ``(c, r)`` with DEM ``value`` to world xyz, (..., 3) metres.

        Body frame: on a sphere ``x = (R + height) e(lon, lat)`` (eqs. 3-4); with radius values
        ``x = value * e``; on an ellipsoid, geodetic height through pyproj (radius values then
        use the planetocentric direction). Map frame: ``(easting, northing, value)``.
        """
        value = np.asarray(value, dtype=np.float64)
        if self.world == "map":
            x, y = self.pixel_to_crs(c, r)
            return np.stack(np.broadcast_arrays(x, y, value), axis=-1)
        lon, lat = self.pixel_to_lonlat(c, r, wrap=False)
        if self.radius_values:
            return value[..., None] * unit_vector(lon, lat)
        if self.is_sphere:
            return (self.radii[0] + value)[..., None] * unit_vector(lon, lat)
        lon, lat, value = np.broadcast_arrays(lon, lat, value)
        xyz = self._to_geocentric.transform(np.degrees(lon), np.degrees(lat), value)
        return np.stack(xyz, axis=-1)

    def from_world(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact inverse of :meth:`to_world`: world xyz (..., 3) to pixel ``(c, r)`` and value."""
        xyz = np.asarray(xyz, dtype=np.float64)
        x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
        if self.world == "map":
            c, r = self.crs_to_pixel(x, y)
            return c, r, z.copy()
        if self.radius_values or self.is_sphere:
            rho = np.sqrt(x * x + y * y + z * z)
            lon, lat = np.arctan2(y, x), np.arctan2(z, np.hypot(x, y))
            value = rho if self.radius_values else rho - self.radii[0]
        else:
            lon_d, lat_d, value = self._to_geocentric.transform(x, y, z, direction="INVERSE")
            lon, lat, value = np.radians(lon_d), np.radians(lat_d), np.asarray(value)
        c, r = self.lonlat_to_pixel(lon, lat)
        return c, r, value

    def world_points(self) -> np.ndarray:
        """World xyz of every post, (rows, cols, 3); NaN at holes."""
        c, r = self.grid()
        return self.to_world(c, r, self.values)

    def up_vectors(self, xyz: np.ndarray) -> np.ndarray:
        """Unit 'up' directions at world points: radial in the body frame, +z in the map frame."""
        if self.world == "map":
            up = np.zeros_like(xyz)
            up[..., 2] = 1.0
            return up
        return xyz / np.linalg.norm(xyz, axis=-1, keepdims=True)

    def normals(self) -> np.ndarray:
        """Unit outward surface normals at every post from central differences, (rows, cols, 3).

        One-sided differences at the border; NaN where a neighbour needed is a hole.
        """
        p = self.world_points()
        dc = np.gradient(p, axis=1)
        dr = np.gradient(p, axis=0)
        n = np.cross(dc, dr)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        flip = np.sum(n * self.up_vectors(p), axis=-1) < 0
        n[flip] *= -1
        return n

    def post_spacing(self) -> tuple[float, float]:
        """Ground distance between neighbouring posts at the grid centre (along c, along r), m."""
        rows, cols = self.shape
        c0, r0 = (cols - 1) / 2, (rows - 1) / 2
        h = np.nanmedian(self.values)
        p = self.to_world(np.array([c0, c0 + 1, c0]), np.array([r0, r0, r0 + 1]), np.full(3, h))
        return float(np.linalg.norm(p[1] - p[0])), float(np.linalg.norm(p[2] - p[0]))
