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

import os
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from affine import Affine
from rasterio.crs import CRS as FileCRS

from orthomvp.codes import WorldFrame
from orthomvp.errors import InputError
from orthomvp.geometry.crs import (
    as_crs,
    as_pyproj,
    dem_georeference,
    file_radii,
    geocentric_transformer,
    is_pyproj,
    lonlat_transformer,
)
from orthomvp.geometry.datum import HeightOptions, height_shift
from orthomvp.geometry.heights import check_relief, count_unusable, unusable, warn_infinite
from orthomvp.geometry.normals import grid_normals
from orthomvp.geometry.vectors import nan_median, row_norms, unit_vector
from orthomvp.io.preflight import check_memory, count_text
from orthomvp.io.raster import corrupt_data, open_raster, read_values, write_geotiff

if TYPE_CHECKING:
    from pyproj import CRS, Transformer


def _heights(values: object, name: str) -> np.ndarray:
    """``values`` as a float64 array; InputError for anything that is not real numbers."""
    arr = np.asarray(values)
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InputError(f"{name}: DEM values must be real numbers, got {arr.dtype} values")
    return arr.astype(np.float64)


REGRID_BYTES_PER_POST = 160
"""Peak memory of :meth:`Terrain.regrid` per output post (grid coordinates and interpolation
temporaries), bytes."""


@dataclass(frozen=True)
class Terrain:
    """A DEM on a regular grid: values, georeference, body and conventions.

    ``values`` is float64 ``(rows, cols)``, NaN at nodata posts (holes); infinite values are
    holes too (they become NaN). ``transform`` maps pixel *corner* coordinates to CRS
    coordinates (GDAL convention); ``crs`` is a pyproj CRS or anything it reads, or a file's
    CRS as rasterio reads it (kept as it is, read by GDAL: pyproj, whose import takes about
    45 ms, is then imported only where a transformation or the body's geodetic CRS is needed,
    not for a map-frame run). Construction checks all of this and raises
    :class:`~orthomvp.errors.InputError`.
    ``wrap_lon``: the longitude (radians) that :meth:`pixel_to_lonlat` keeps longitudes within
    pi of, default the grid centre's (a window of a larger grid may take the larger grid's).
    """

    values: np.ndarray
    transform: Affine
    crs: CRS | FileCRS
    radius_values: bool = False
    world: WorldFrame = WorldFrame.BODY
    name: str = field(default="dem", compare=False)
    wrap_lon: float | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        vals = _heights(self.values, self.name)
        if vals.ndim != 2 or min(vals.shape) < 2:
            raise InputError(f"{self.name}: a DEM needs at least 2 x 2 posts, got {vals.shape}")
        bad = unusable(vals)
        if bad.any():
            vals = np.where(bad, np.nan, vals)
        object.__setattr__(self, "values", vals)
        if not isinstance(self.transform, Affine):
            raise InputError(
                f"{self.name}: the transform must be an affine.Affine, got "
                f"{type(self.transform).__name__}"
            )
        object.__setattr__(self, "crs", as_crs(self.crs, self.name))
        object.__setattr__(self, "world", WorldFrame(self.world))  # InputError on a bad name
        if not (self.crs.is_geographic or self.crs.is_projected):
            raise InputError(f"{self.name}: CRS is neither geographic nor projected")
        if self.world == WorldFrame.MAP and not self.crs.is_projected:
            raise InputError(f"{self.name}: the map frame (--world map) needs a projected CRS")
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
        world: WorldFrame | str = WorldFrame.BODY,
        crs: object | None = None,
        *,
        vertical_datum: str = "auto",
        height_offset: float | None = None,
    ) -> Terrain:
        """Read band 1 of a GeoTIFF DEM; nodata posts become NaN, and so do infinite values
        (with an :class:`~orthomvp.errors.OrthoMVPWarning` that counts them). ``crs``
        overrides the file's. Heights become those the cameras of ``world`` need
        (:mod:`orthomvp.geometry.datum`): in the body frame a compound CRS's vertical datum is
        converted to heights above its ellipsoid (``vertical_datum="ignore"``: not); a
        ``height_offset`` (metres) is added instead, in either frame."""
        if not isinstance(path, (str, os.PathLike)):
            raise InputError(f"a DEM file name is a str or a Path, got {type(path).__name__}")
        with open_raster(path) as src:
            try:
                values = read_values(src, 1, None, np.float64)
            except InputError:
                raise
            except Exception as exc:  # rasterio raises several unrelated types on corrupt data
                raise corrupt_data(path, exc) from exc
            file_crs = src.crs
            transform = src.transform
        the_crs = dem_georeference(path, file_crs, transform, crs, shape=values.shape)
        warn_infinite(path, *count_unusable(values))
        values[unusable(values)] = np.nan
        heights = HeightOptions(vertical_datum, height_offset)
        whole, name = file_crs if crs is None else crs, str(path)
        args = {"world": world, "heights": heights, "radius_values": radius_values, "name": name}
        if (shift := height_shift(whole, transform, values.shape, **args)) is not None:
            values = values + shift.window((0, values.shape[0], 0, values.shape[1]))
        terrain = cls(values, transform, the_crs, radius_values, world, name=str(path))
        terrain.check_convention()
        return terrain

    def check_convention(self) -> None:
        """InputError when the values cannot be in the convention this DEM says (body frame
        only): radii far from the body's radius (heights read with ``radius_values``), or
        heights of the order of the radius (radii read without it); in either frame, values
        that stray too far from the others for any body (:func:`check_relief`)."""
        median = nan_median(self.values)
        radius = self.radii[0]
        check_relief(self.name, np.nanmin(self.values), np.nanmax(self.values), median, radius)
        if self.world != WorldFrame.BODY:
            return
        if self.radius_values and abs(median - radius) > 0.5 * radius:
            raise InputError(
                f"{self.name}: the values are taken as radii from the body centre "
                f"(--radius-values), but their median, {median:,.0f} m, is far from the body's "
                f"radius, {radius:,.0f} m: are they heights above it?"
            )
        if not self.radius_values and abs(median) > 0.5 * radius:
            raise InputError(
                f"{self.name}: the values are taken as heights above the body's surface, but "
                f"their median, {median:,.0f} m, is of the order of its radius, {radius:,.0f} "
                "m: are they radii from its centre (--radius-values)?"
            )

    def write(
        self, path: str | Path, values: np.ndarray | None = None, *, overwrite: bool = False
    ) -> None:
        """Write ``values`` (default: this DEM's; (rows, cols) as the DEM) as a float32
        GeoTIFF (``.tif``) on this grid, NaN = nodata, atomically. InputError for other
        values' shape or another file type, and for a file that exists unless ``overwrite``
        (as every output of the API)."""
        from orthomvp.io.output_checks import API_FLAGS, Output, check_outputs
        from orthomvp.io.outputs import atomic_path

        data = self.values if values is None else np.asarray(values)
        if data.shape != self.shape:
            raise InputError(
                f"{self.name}: values to write must have the DEM's shape {self.shape}, got "
                f"{data.shape}"
            )
        check_outputs([Output("Terrain.write", Path(path))], overwrite=overwrite, flags=API_FLAGS)
        with atomic_path(path) as tmp:
            write_geotiff(tmp, data.astype(np.float32), self.transform, self.crs, nodata=np.nan)

    def with_values(self, values: np.ndarray) -> Terrain:
        """The same grid and conventions with other ``values`` of the same (rows, cols) shape."""
        vals = _heights(values, self.name)
        if vals.shape != self.shape:
            raise InputError(
                f"{self.name}: new values must have the DEM's shape {self.shape}, got {vals.shape}"
            )
        return replace(self, values=vals)

    def crop(self, r0: int, r1: int, c0: int, c1: int) -> Terrain:
        """The posts ``[r0:r1, c0:c1]`` as a Terrain of their own (a view of the values)."""
        return replace(
            self,
            values=self.values[r0:r1, c0:c1],
            transform=self.transform @ Affine.translation(c0, r0),
        )

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
        """The geographic CRS (lon/lat on the body) underlying this DEM's CRS (pyproj's)."""
        crs = as_pyproj(self.crs)
        return crs if crs.is_geographic else crs.geodetic_crs

    @cached_property
    def radii(self) -> tuple[float, float]:
        """(semi-major, semi-minor) axes of the body's reference ellipsoid, metres; of a
        file's CRS from its WKT, without pyproj, when the WKT says them plainly."""
        if not is_pyproj(self.crs) and (radii := file_radii(self.crs)) is not None:
            return radii
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
        return lonlat_transformer(self.crs)

    @cached_property
    def _to_geocentric(self) -> Transformer:
        return geocentric_transformer(self.crs, self.radii)

    @cached_property
    def centre_lon(self) -> float:
        """Longitude of the grid centre (or ``wrap_lon``), radians; longitudes are returned
        within pi of it."""
        if self.wrap_lon is not None:
            return float(self.wrap_lon)
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

    # ---------------------------------------------------------------- map <-> world frame
    def to_world(self, c: np.ndarray, r: np.ndarray, value: np.ndarray) -> np.ndarray:
        """Eqs. (1)-(4): pixel-centre ``(c, r)`` with DEM ``value`` to world xyz, (..., 3) metres.

        Body frame: on a sphere ``x = (R + height) e(lon, lat)`` (eqs. 3-4); with radius values
        ``x = value * e``; on an ellipsoid, geodetic height through pyproj (radius values then
        use the planetocentric direction). Map frame: ``(easting, northing, value)``."""
        if self.world == WorldFrame.MAP:
            x, y = self.pixel_to_crs(c, r)
            return np.stack(np.broadcast_arrays(x, y, np.asarray(value, np.float64)), axis=-1)
        return self.lonlat_to_world(*self.pixel_to_lonlat(c, r, wrap=False), value)

    def lonlat_to_world(self, lon: np.ndarray, lat: np.ndarray, value: np.ndarray) -> np.ndarray:
        """:meth:`to_world` in a body frame, from body (lon, lat) in radians."""
        value = np.asarray(value, dtype=np.float64)
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
        if self.world == WorldFrame.MAP:
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
        if self.world == WorldFrame.MAP:
            up = np.zeros_like(xyz)
            up[..., 2] = 1.0
            return up
        return xyz / row_norms(xyz)[..., None]

    def normals(self) -> np.ndarray:
        """Unit outward surface normals at every post, (rows, cols, 3); see :func:`grid_normals`."""
        p = self.world_points()
        return grid_normals(p, self.up_vectors(p))

    def post_spacing(self) -> tuple[float, float]:
        """Ground distance between neighbouring posts at the grid centre (along c, along r), m."""
        rows, cols = self.shape
        c0, r0 = (cols - 1) / 2, (rows - 1) / 2
        h = nan_median(self.values)
        p = self.to_world(np.array([c0, c0 + 1, c0]), np.array([r0, r0, r0 + 1]), np.full(3, h))
        return float(np.linalg.norm(p[1] - p[0])), float(np.linalg.norm(p[2] - p[0]))

    def interpolate(self, c: np.ndarray, r: np.ndarray) -> np.ndarray:
        """DEM values at fractional pixel positions, linear on the mesh's own triangles.

        Each cell splits along the diagonal from (c+1, r) to (c, r+1), as in
        :func:`orthomvp.occlusion.mesh.grid_triangles`; NaN outside the grid or next to a hole.
        """
        rows, cols = self.shape
        c = np.asarray(c, dtype=np.float64)
        r = np.asarray(r, dtype=np.float64)
        inside = (c >= 0) & (c <= cols - 1) & (r >= 0) & (r <= rows - 1)
        c0 = np.clip(np.floor(np.where(inside, c, 0)), 0, cols - 2).astype(np.int64)
        r0 = np.clip(np.floor(np.where(inside, r, 0)), 0, rows - 2).astype(np.int64)
        fx, fy = c - c0, r - r0
        v = self.values
        a, b = v[r0, c0], v[r0, c0 + 1]
        d, e = v[r0 + 1, c0], v[r0 + 1, c0 + 1]
        lower = fx + fy <= 1
        out = np.where(
            lower,
            a + fx * (b - a) + fy * (d - a),
            e + (1 - fx) * (d - e) + (1 - fy) * (b - e),
        )
        return np.where(inside, out, np.nan)

    def grid_cells(self, c: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, ...]:
        """The cells of :meth:`interpolate_grid`'s fractional columns ``c`` (n,) and rows
        ``r`` (m,): each column's first column, fraction within its cell and whether it is on
        the grid, then each row's: (c0, fx, c_in, r0, fy, r_in)."""
        rows, cols = self.shape
        c = np.asarray(c, dtype=np.float64)
        r = np.asarray(r, dtype=np.float64)
        c_in = (c >= 0) & (c <= cols - 1)
        r_in = (r >= 0) & (r <= rows - 1)
        c0 = np.clip(np.floor(np.where(c_in, c, 0)), 0, cols - 2).astype(np.int64)
        r0 = np.clip(np.floor(np.where(r_in, r, 0)), 0, rows - 2).astype(np.int64)
        return c0, c - c0, c_in, r0, r - r0, r_in

    def interpolate_grid(self, c: np.ndarray, r: np.ndarray) -> np.ndarray:
        """:meth:`interpolate` at every pair of the fractional column positions ``c`` (n,)
        and row positions ``r`` (m,): (m, n), the same values bit for bit, with the cell
        search done once per column and once per row (a grid axis-aligned with this one)."""
        c0, fx, c_in, r0, fy, r_in = self.grid_cells(c, r)
        fx, fy = fx[None, :], fy[:, None]
        top, bottom = self.values[r0], self.values[r0 + 1]  # rows gathered once, then columns
        a, b = np.take(top, c0, axis=1), np.take(top, c0 + 1, axis=1)
        d, e = np.take(bottom, c0, axis=1), np.take(bottom, c0 + 1, axis=1)
        out = np.where(
            fx + fy <= 1,
            a + fx * (b - a) + fy * (d - a),
            e + (1 - fx) * (d - e) + (1 - fy) * (b - e),
        )
        if r_in.all() and c_in.all():
            return out
        return np.where(r_in[:, None] & c_in[None, :], out, np.nan)

    def output_grid(
        self, res: tuple[float, float] | None = None, bounds: tuple[float, ...] | None = None
    ) -> tuple[Affine, tuple[int, int]]:
        """The transform and (rows, cols) of the grid that :meth:`regrid` makes for ``res``
        and ``bounds``, checked (finite, positive, ordered), without making it."""
        t = self.transform
        rows, cols = self.shape
        left, top = t.c, t.f
        right, bottom = left + cols * t.a, top + rows * t.e
        if bounds is not None:
            try:
                left, bottom, right, top = (float(v) for v in bounds)
            except (TypeError, ValueError):
                raise InputError(
                    f"bounds must be four numbers (left, bottom, right, top), got {bounds!r}"
                ) from None
            if not (
                np.isfinite([left, bottom, right, top]).all() and right > left and top > bottom
            ):
                raise InputError(
                    f"bounds must be finite, left < right and bottom < top, got {bounds}"
                )
        if res is None:
            dx, dy = abs(t.a), abs(t.e)
        else:
            try:
                dx, dy = (float(v) for v in res)
            except (TypeError, ValueError):
                raise InputError(f"resolution must be two numbers (x, y), got {res!r}") from None
            if not (np.isfinite([dx, dy]).all() and dx > 0 and dy > 0):
                raise InputError(f"resolution must be finite and positive, got {res}")
        n_c = max(round((right - left) / dx), 2)
        n_r = max(round((top - bottom) / dy), 2)
        return Affine(dx, 0, left, 0, -dy, top), (n_r, n_c)

    def regrid(
        self, res: tuple[float, float] | None = None, bounds: tuple[float, ...] | None = None
    ) -> Terrain:
        """The DEM on another grid of the same CRS: pixel size ``res`` (x, y) and ``bounds``
        (left, bottom, right, top), both in CRS units (degrees or metres); values interpolated
        with :meth:`interpolate`. Defaults keep this DEM's resolution and extent. A grid that
        cannot fit in memory is refused before it is made (InputError)."""
        grid, (n_r, n_c) = self.output_grid(res, bounds)
        check_memory(
            f"this grid is {count_text(n_r * n_c)} posts ({n_c:,} x {n_r:,})",
            n_r * n_c * REGRID_BYTES_PER_POST,
            "choose a coarser resolution or smaller bounds",
        )
        new = replace(self, values=np.zeros((n_r, n_c)), transform=grid)
        if self.S[0, 1] == 0 and self.S[1, 0] == 0:  # north up: columns and rows map apart
            c, _ = self.crs_to_pixel(*new.pixel_to_crs(np.arange(n_c, dtype=np.float64), 0.0))
            _, r = self.crs_to_pixel(*new.pixel_to_crs(0.0, np.arange(n_r, dtype=np.float64)))
            values = self.interpolate_grid(c, r)
        else:
            values = self.interpolate(*self.crs_to_pixel(*new.pixel_to_crs(*new.grid())))
        if not np.isfinite(values).any():
            raise InputError("the requested grid does not overlap the DEM")
        return replace(new, values=values)
