"""RPC cameras: rational polynomial coefficients (RPC00B) bound to a Cartesian world frame.

Conventions:

- An :class:`~orthomvp.camera.rpc_model.Rpc` maps WGS84 longitude, latitude (degrees) and
  ellipsoidal height (metres) to pixels (:mod:`orthomvp.camera.rpc_model`).
- RPC (sample, line) has the first pixel's centre at (0, 0), as orthomvp's (u, v) = (column,
  row): no shift. (GDAL's RPC transformer reports pixel corners: its (col, row) are ours + 0.5.)
- An :class:`RpcCamera` lives in a Cartesian world frame named by a pyproj CRS: geocentric
  (orthomvp's body frame; default WGS84, EPSG:4978) or projected, (easting, northing, height)
  taken as Cartesian (the map frame). World heights are ellipsoidal heights minus
  ``height_offset`` (0 by default), or, in a compound CRS with a vertical datum, heights in that
  datum, which PROJ converts with the geoid's grid (refused without it). A DEM of orthometric
  heights under body-fixed cameras is converted before it reaches the camera
  (:mod:`orthomvp.geometry.datum`); with map-frame cameras it keeps its heights, and the RPC
  camera takes the DEM's compound CRS (:func:`in_vertical_datum`). ``height_offset`` serves
  points of orthometric heights given through the API (the undulation N: ellipsoidal =
  orthometric + N).
- Rays are straight lines in the world frame between the ground points of a pixel at two
  ellipsoidal heights, ``top`` (the ray's origin; default height_off + height_scale, which must
  lie above all terrain the camera sees) and ``bottom`` (default height_off - height_scale).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import KW_ONLY, dataclass, field, replace
from functools import cached_property
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera.model import FieldError, _points, check_crop, image_size
from orthomvp.camera.rpc_model import GEODETIC, Rpc, finite_number
from orthomvp.codes import WorldFrame
from orthomvp.errors import InputError
from orthomvp.geometry.crs import cheap_per_thread
from orthomvp.geometry.datum import geoid_transformer, vertical_part, whole_crs

if TYPE_CHECKING:
    from pyproj import CRS, Transformer

    from orthomvp.geometry.terrain import Terrain

_GSD_STEP = 1.0  # metres, finite-difference step of gsd()


def _pyproj() -> ModuleType:
    """pyproj, imported where a camera needs it (its import takes about 45 ms)."""
    import pyproj
    import pyproj.exceptions

    return pyproj


def _epsg(code: int) -> CRS:
    """The pyproj CRS of EPSG ``code``."""
    return _pyproj().CRS.from_epsg(code)


def world_crs(terrain: Terrain) -> CRS:
    """The CRS of ``terrain``'s world frame: its own (projected) CRS in the map frame, else
    geocentric metres on its ellipsoid (what :meth:`Terrain.to_world` gives)."""
    from pyproj import CRS

    if terrain.world == WorldFrame.MAP:
        return CRS.from_user_input(terrain.crs)
    a, b = terrain.radii
    return CRS.from_proj4(f"+proj=geocent +a={a!r} +b={b!r} +units=m +no_defs")


def _horizontal_3d(crs: CRS) -> CRS:
    """``crs`` with ellipsoidal heights: a compound CRS's horizontal part, made 3D; InputError
    unless it is geocentric or projected (a Cartesian world frame)."""
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    if horizontal.is_geocentric:
        return horizontal
    if horizontal.is_projected:
        return horizontal.to_3d()
    raise FieldError(
        "crs", f"the world CRS must be geocentric or projected (Cartesian), got {crs.name!r}"
    )


def _to_wgs84(crs: CRS) -> Transformer:
    """World coordinates in ``crs`` to WGS84 (lon, lat, ellipsoidal height): through the
    vertical datum of a compound CRS that has one (heights in it; PROJ and its grid), else
    with the heights taken as ellipsoidal; InputError when PROJ lacks the grid."""

    if crs.is_compound and vertical_part(crs) is not None:
        _horizontal_3d(crs)  # a Cartesian world frame still
        return geoid_transformer(crs, f"the world CRS {crs.name!r}", _epsg(GEODETIC))
    return _ellipsoidal(_horizontal_3d(crs).to_wkt())


@functools.lru_cache(maxsize=16)
def _ellipsoidal(wkt: str) -> Transformer:
    """The Cartesian world CRS of WKT ``wkt`` (ellipsoidal heights) to WGS84, made once a
    process (:func:`~orthomvp.geometry.crs.cheap_per_thread`)."""
    from pyproj import CRS, Transformer

    made = Transformer.from_crs(CRS.from_wkt(wkt), _epsg(GEODETIC), always_xy=True)
    return cheap_per_thread(made)


@dataclass(frozen=True, eq=False)
class RpcCamera:
    """An RPC camera in a Cartesian world frame (see the module docstring for conventions).

    ``rpc``: the :class:`Rpc`. Keyword-only: ``width``, ``height``, image size in pixels (or
    None); ``crs``: the world frame, anything pyproj reads, geocentric or projected, or a
    compound CRS whose vertical datum PROJ converts (default WGS84 geocentric, EPSG:4978;
    :meth:`bind` takes a terrain's); ``height_offset``, metres:
    ellipsoidal height = world height + ``height_offset`` (the geoid undulation for
    orthometric world heights; 0 for ellipsoidal ones); ``top``, ``bottom``: the ellipsoidal
    heights (m) between which rays run, ``top`` their origin (defaults height_off +- height_scale;
    ``top`` must lie above all terrain the camera sees); ``margin``: points whose normalised
    longitude, latitude or height exceeds 1 + ``margin`` in magnitude (beyond the RPC's fitted
    domain, where the polynomials may fold) are not imaged (NaN pixels); ``top`` and ``bottom``
    must lie within that domain too.
    Construction raises InputError (a FieldError naming the parameter) for bad values.
    """

    rpc: Rpc
    _: KW_ONLY
    width: int | None = None
    height: int | None = None
    crs: CRS = field(default_factory=lambda: _epsg(4978))
    height_offset: float = 0.0
    top: float | None = None
    bottom: float | None = None
    margin: float = 0.5

    def __post_init__(self) -> None:
        if not isinstance(self.rpc, Rpc):
            raise FieldError("rpc", f"rpc must be an Rpc, got {type(self.rpc).__name__}")
        for name in ("width", "height"):
            object.__setattr__(self, name, image_size(name, getattr(self, name)))
        try:
            crs = _pyproj().CRS.from_user_input(self.crs)
        except _pyproj().exceptions.CRSError as exc:
            raise FieldError(
                "crs", f"cannot understand the world CRS {self.crs!r}: {exc}"
            ) from None
        _horizontal_3d(crs)
        object.__setattr__(self, "crs", crs)
        if vertical_part(crs) is not None:
            _to_wgs84(crs)  # refused now when PROJ lacks the geoid's grid
        rpc = self.rpc
        defaults = {
            "top": rpc.height_off + abs(rpc.height_scale),
            "bottom": rpc.height_off - abs(rpc.height_scale),
        }
        for name in ("height_offset", "margin", "top", "bottom"):
            value = getattr(self, name)
            object.__setattr__(
                self, name, finite_number(name, defaults[name] if value is None else value)
            )
        if self.margin < 0:
            raise FieldError("margin", f"margin must be >= 0, got {self.margin!r}")
        if not self.top > self.bottom:
            raise FieldError("top", f"top ({self.top} m) must lie above bottom ({self.bottom} m)")
        for name in ("top", "bottom"):
            if not self._in_domain(rpc.long_off, rpc.lat_off, getattr(self, name)):
                low, high = (
                    rpc.height_off + k * abs(rpc.height_scale) * (1 + self.margin) for k in (-1, 1)
                )
                raise FieldError(
                    name,
                    f"{name} ({getattr(self, name)} m) lies beyond the RPC's heights "
                    f"({low:g} to {high:g} m with the margin)",
                )

    def __getstate__(self) -> dict[str, object]:
        """Pickled without the cached pyproj transformer."""
        return {k: v for k, v in self.__dict__.items() if k != "_to_geodetic"}

    @cached_property
    def _to_geodetic(self) -> Transformer:
        return _to_wgs84(self.crs)

    def bind(self, terrain: Terrain) -> RpcCamera:
        """A copy in ``terrain``'s world frame (:func:`world_crs`)."""
        return replace(self, crs=world_crs(terrain))

    def with_image_size(self, width: int | None, height: int | None) -> RpcCamera:
        """A copy with the image size (pixels) set."""
        return replace(self, width=width, height=height)

    def crop(self, c0: int, r0: int, width: int, height: int) -> RpcCamera:
        """The camera of the ``width`` x ``height`` pixel window whose first pixel is pixel
        (``c0``, ``r0``) here: the RPC's sample and line offsets move by the offset, so
        ``crop.project(x)`` is ``project(x) - (c0, r0)``."""
        check_crop(c0, r0, width, height)
        rpc = replace(
            self.rpc, samp_off=self.rpc.samp_off - int(c0), line_off=self.rpc.line_off - int(r0)
        )
        return replace(self, rpc=rpc, width=int(width), height=int(height))

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """Whether pixels ``uv`` (..., 2) lie within half a pixel of the outermost pixel
        centres; NaN is outside. Needs the image size."""
        if self.width is None or self.height is None:
            raise InputError("the camera needs its image size (width, height)")
        u, v = uv[..., 0], uv[..., 1]
        return (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)

    def to_geodetic(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """WGS84 (lon, lat) in degrees and ellipsoidal height in metres of world points
        ``xyz`` (..., 3) (``height_offset`` added); NaN where ``xyz`` is not finite."""
        xyz = _points(xyz, "to_geodetic", 3)
        if xyz.shape[-1:] != (3,):
            raise InputError(f"to_geodetic needs points of shape (..., 3), got {xyz.shape}")
        ok = np.isfinite(xyz).all(axis=-1)
        out = np.full(xyz.shape, np.nan)
        lon, lat, h = self._to_geodetic.transform(*xyz[ok].T)
        out[ok] = np.stack([lon, lat, np.asarray(h) + self.height_offset], axis=-1)
        return out[..., 0], out[..., 1], out[..., 2]

    def to_world(self, lon: np.ndarray, lat: np.ndarray, height: np.ndarray) -> np.ndarray:
        """World points (..., 3) of WGS84 ``lon``, ``lat`` (degrees) and ellipsoidal ``height``
        (metres), broadcast together; NaN where they are not finite."""
        lon, lat, height = np.broadcast_arrays(
            *(np.asarray(a, np.float64) for a in (lon, lat, height))
        )
        ok = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(height)
        out = np.full(lon.shape + (3,), np.nan)
        xyz = self._to_geodetic.transform(
            lon[ok], lat[ok], height[ok] - self.height_offset, direction="INVERSE"
        )
        out[ok] = np.stack(xyz, axis=-1)
        return out

    def _in_domain(self, lon: np.ndarray, lat: np.ndarray, height: np.ndarray) -> np.ndarray:
        """Whether normalised |L|, |P|, |H| are all within 1 + margin (False for NaN)."""
        limit = 1.0 + self.margin
        lon, lat, height = self.rpc.normalise(lon, lat, height)
        return (np.abs(lon) <= limit) & (np.abs(lat) <= limit) & (np.abs(height) <= limit)

    def _ray_point(
        self, uv: np.ndarray, height: float, start: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(lon, lat) degrees (...) and world point (..., 3) imaged at ``uv`` at ellipsoidal
        ``height``; NaN outside the domain."""
        lon, lat = self.rpc.ground(uv, height, start=start)
        inside = self._in_domain(lon, lat, height)
        lon, lat = np.where(inside, lon, np.nan), np.where(inside, lat, np.nan)
        return np.stack([lon, lat], axis=-1), self.to_world(lon, lat, height)

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``uv`` (..., 2) of world points ``xyz`` (..., 3), metres, NaN beyond the RPC's
        domain (see ``margin``), and ``depth`` (...), metres: the distance from the ray's
        origin (the point at height ``top`` imaged at the same pixel), positive below ``top``;
        NaN where ``uv`` is."""
        xyz = _points(xyz, "project", 3)
        lon, lat, height, uv = self._pixels_of(xyz)
        _, origin = self._ray_point(uv, self.top, start=(lon, lat))
        depth = np.linalg.norm(xyz - origin, axis=-1)
        depth = np.where(height <= self.top, depth, -depth)
        return uv, depth

    def _pixels_of(self, xyz: np.ndarray) -> tuple[np.ndarray, ...]:
        """WGS84 (lon, lat) degrees and ellipsoidal height of world points ``xyz`` (..., 3),
        and their pixels (..., 2), NaN beyond the domain: :meth:`project` without the depth
        (which costs an inversion of the RPC)."""
        lon, lat, height = self.to_geodetic(xyz)
        uv = self.rpc.project(lon, lat, height)
        uv[~self._in_domain(lon, lat, height)] = np.nan
        return lon, lat, height, uv

    def ray(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays through pixels ``uv`` (..., 2): ``origins`` (..., 3), the world points imaged at
        ``uv`` at height ``top``, and unit ``directions`` (..., 3) towards the points at height
        ``bottom``; NaN where a point lies beyond the domain or the iteration fails."""
        uv = self._pixels(uv, "ray")
        lonlat, origins = self._ray_point(uv, self.top)
        _, low = self._ray_point(uv, self.bottom, start=(lonlat[..., 0], lonlat[..., 1]))
        d = low - origins
        return origins, d / np.linalg.norm(d, axis=-1, keepdims=True)

    def origins(self, uv: np.ndarray) -> np.ndarray:
        """The ``origins`` of :meth:`ray` alone (..., 3), world metres."""
        return self._ray_point(self._pixels(uv, "origins"), self.top)[1]

    def gsd(self, xyz: np.ndarray) -> np.ndarray:
        """Metres per pixel (...) at world points ``xyz`` (..., 3) on a plane perpendicular to
        the ray: 1 / sqrt(|det J|) with J (pixels per metre) by central differences of 1 m
        along two axes of that plane; NaN where the point is not imaged."""
        xyz = _points(xyz, "gsd", 3)
        _, d = self.ray(self._pixels_of(xyz)[3])  # (the pixels alone: no depths needed)
        helper = np.where(np.abs(d[..., :1]) < 0.9, np.eye(3)[0], np.eye(3)[1])
        e1 = np.cross(d, helper)
        e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
        e2 = np.cross(d, e1)
        step = _GSD_STEP * np.stack([e1, e2])  # (2, ..., 3)
        ahead, behind = self._pixels_of(xyz + step)[3], self._pixels_of(xyz - step)[3]
        jac = (ahead - behind) / (2 * _GSD_STEP)  # (2 axes, ..., 2 pixel coordinates)
        det = jac[0, ..., 0] * jac[1, ..., 1] - jac[0, ..., 1] * jac[1, ..., 0]
        return 1.0 / np.sqrt(np.abs(det))

    @staticmethod
    def _pixels(uv: np.ndarray, what: str) -> np.ndarray:
        uv = _points(uv, what, 2)
        if uv.shape[-1:] != (2,):
            raise InputError(f"{what} needs pixels of shape (..., 2), got {uv.shape}")
        return uv


def map_frame_rpc(
    cameras: Sequence[tuple[str, object]], world: WorldFrame, dem_crs: object, as_read: bool
) -> str | None:
    """The name of the first RPC camera among ``cameras`` ((name, camera) pairs) in the map
    frame ``world`` of a DEM whose CRS ``dem_crs`` has a vertical part and whose heights are
    used ``as_read`` (the map frame's rule, :mod:`orthomvp.geometry.datum`): heights in that
    datum, not the ellipsoidal ones an RPC wants. None when there is none."""
    if not as_read or world != WorldFrame.MAP or vertical_part(dem_crs) is None:
        return None
    return next((name for name, camera in cameras if isinstance(camera, RpcCamera)), None)


def in_vertical_datum(
    cameras: Sequence[tuple[str, object]], world: WorldFrame, dem_crs: object, as_read: bool
) -> list[object]:
    """The cameras of ``cameras`` ((name, camera) pairs), each RPC camera that
    :func:`map_frame_rpc` finds given the DEM's whole CRS ``dem_crs`` as its world CRS, so that
    PROJ converts its world heights (the DEM's, in its vertical datum) to ellipsoidal ones
    with the geoid's grid; InputError, naming the grid, when PROJ lacks it."""
    if map_frame_rpc(cameras, world, dem_crs, as_read) is None:
        return [camera for _, camera in cameras]
    crs = whole_crs(dem_crs, "the DEM's CRS")
    return [
        replace(camera, crs=crs) if isinstance(camera, RpcCamera) else camera
        for _, camera in cameras
    ]


def check_map_frame_heights(
    cameras: Sequence[tuple[str, object]], world: WorldFrame, dem_crs: object, as_read: bool
) -> None:
    """InputError for an RPC camera that :func:`map_frame_rpc` finds, where the cameras are not
    given the DEM's vertical datum (the in-memory commands)."""
    name = map_frame_rpc(cameras, world, dem_crs, as_read)
    if name is not None:
        raise InputError(
            f"{name}: an RPC camera wants heights above the WGS84 ellipsoid, but with cameras "
            f"in the DEM's map frame the DEM's heights stay in its vertical datum "
            f"({vertical_part(dem_crs).name!r}): give --height-offset METRES (the geoid "
            "undulation, added to the DEM's heights for every camera) or --vertical-datum ignore"
        )
