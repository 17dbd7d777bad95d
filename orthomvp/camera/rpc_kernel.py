"""RPC00B evaluation as numba kernels: the polynomials with their analytic derivatives, the
projection, the Newton inversion (image and height to ground) and the conversions between
geodetic and geocentric coordinates on an ellipsoid, one point at a time without numpy's
temporaries (about a microsecond a point where numpy takes tens).

The numpy model (:class:`~orthomvp.camera.rpc_model.Rpc`) is their test oracle: the same
polynomials in the same term order (see its module docstring), the same Newton iteration (step
below 1e-10 normalised units, at most 30 steps). The RPC is passed as ``coef`` (4, 20): the
sample numerator and denominator, then the line's (:func:`pack`); and ``scales`` (10,):
``samp_off, samp_scale, line_off, line_scale, long_off, long_scale, lat_off, lat_scale,
height_off, height_scale``.

This module imports numba (through :mod:`orthomvp.jit`): import it where a kernel runs."""

from __future__ import annotations

import functools
import math
import weakref
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera.rpc_model import OFFSETS_SCALES, Rpc
from orthomvp.jit import cached_jit

if TYPE_CHECKING:
    from orthomvp.camera.rpc import RpcCamera

TOLERANCE = 1e-10
"""Newton's last step, normalised longitude and latitude units (as the numpy model)."""
ITERATIONS = 30
"""Newton's steps at most before a point is given up (NaN)."""
_GEODETIC_STEPS = 8  # geocentric to geodetic: fixed-point steps at most (each gains ~e^2 h/N)


def pack(rpc: Rpc) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' ``coef`` (4, 20) and ``scales`` (10,) of ``rpc`` (module docstring)."""
    coef = np.stack(
        [rpc.samp_num_coeff, rpc.samp_den_coeff, rpc.line_num_coeff, rpc.line_den_coeff]
    )
    scales = np.array(
        [
            rpc.samp_off, rpc.samp_scale, rpc.line_off, rpc.line_scale, rpc.long_off,
            rpc.long_scale, rpc.lat_off, rpc.lat_scale, rpc.height_off, rpc.height_scale,
        ]
    )  # fmt: skip
    return np.ascontiguousarray(coef, np.float64), scales


def _poly(c: np.ndarray, k: int, x: float, y: float, z: float, out: np.ndarray) -> None:
    """Into ``out`` (4,): polynomial ``k`` of ``c`` (4, 20) at normalised (L, P, H) = (x, y, z)
    and its derivatives by L, P and H."""
    xx, yy, zz = x * x, y * y, z * z
    out[0] = (
        c[k, 0] + c[k, 1] * x + c[k, 2] * y + c[k, 3] * z + c[k, 4] * x * y + c[k, 5] * x * z
        + c[k, 6] * y * z + c[k, 7] * xx + c[k, 8] * yy + c[k, 9] * zz + c[k, 10] * x * y * z
        + c[k, 11] * xx * x + c[k, 12] * x * yy + c[k, 13] * x * zz + c[k, 14] * xx * y
        + c[k, 15] * yy * y + c[k, 16] * y * zz + c[k, 17] * xx * z + c[k, 18] * yy * z
        + c[k, 19] * zz * z
    )  # fmt: skip
    out[1] = (
        c[k, 1] + c[k, 4] * y + c[k, 5] * z + 2 * c[k, 7] * x + c[k, 10] * y * z
        + 3 * c[k, 11] * xx + c[k, 12] * yy + c[k, 13] * zz + 2 * c[k, 14] * x * y
        + 2 * c[k, 17] * x * z
    )  # fmt: skip
    out[2] = (
        c[k, 2] + c[k, 4] * x + c[k, 6] * z + 2 * c[k, 8] * y + c[k, 10] * x * z
        + 2 * c[k, 12] * x * y + c[k, 14] * xx + 3 * c[k, 15] * yy + c[k, 16] * zz
        + 2 * c[k, 18] * y * z
    )  # fmt: skip
    out[3] = (
        c[k, 3] + c[k, 5] * x + c[k, 6] * y + 2 * c[k, 9] * z + c[k, 10] * x * y
        + 2 * c[k, 13] * x * z + 2 * c[k, 16] * y * z + c[k, 17] * xx + c[k, 18] * yy
        + 3 * c[k, 19] * zz
    )  # fmt: skip


_poly = cached_jit(_poly, fastmath=False, error_model="numpy")


def _ratios(c: np.ndarray, x: float, y: float, z: float, out: np.ndarray, work: np.ndarray) -> None:
    """Into ``out`` (2, 4): the normalised sample and line at normalised (x, y, z) and their
    derivatives by L, P and H; ``work`` (2, 4) scratch."""
    for i in range(2):
        _poly(c, 2 * i, x, y, z, work[0])
        _poly(c, 2 * i + 1, x, y, z, work[1])
        num, den = work[0, 0], work[1, 0]
        out[i, 0] = num / den
        for j in range(1, 4):
            out[i, j] = (work[0, j] * den - num * work[1, j]) / (den * den)


_ratios = cached_jit(_ratios, fastmath=False, error_model="numpy")


def _ground(
    c: np.ndarray,
    s: np.ndarray,
    u: float,
    v: float,
    z: float,
    x0: float,
    y0: float,
    r: np.ndarray,
    work: np.ndarray,
) -> tuple[float, float]:
    """Normalised (L, P) imaged at pixel (``u``, ``v``) at normalised height ``z``, by Newton's
    method from (``x0``, ``y0``) as :meth:`Rpc.ground`; NaN where it fails. ``r``, ``work``
    (2, 4) scratch."""
    tu, tv = (u - s[0]) / s[1], (v - s[2]) / s[3]
    x, y = x0, y0
    if not (math.isfinite(tu) and math.isfinite(tv) and math.isfinite(z)):
        return math.nan, math.nan
    if not (math.isfinite(x) and math.isfinite(y)):
        return math.nan, math.nan
    for _ in range(ITERATIONS):
        _ratios(c, x, y, z, r, work)
        ru, rv = r[0, 0] - tu, r[1, 0] - tv
        det = r[0, 1] * r[1, 2] - r[0, 2] * r[1, 1]
        dx = (r[1, 2] * ru - r[0, 2] * rv) / det
        dy = (r[0, 1] * rv - r[1, 1] * ru) / det
        x -= dx
        y -= dy
        size = max(abs(dx), abs(dy))
        if size <= TOLERANCE:
            return x, y
        if not math.isfinite(size):
            break
    return math.nan, math.nan


_ground = cached_jit(_ground, fastmath=False, error_model="numpy")


def _project(
    lon: np.ndarray, lat: np.ndarray, height: np.ndarray, c: np.ndarray, s: np.ndarray,
    out: np.ndarray,
) -> None:  # fmt: skip
    """Into ``out`` (n, 2): the pixels (sample, line) of WGS84 ``lon``, ``lat`` (degrees) and
    ellipsoidal ``height`` (metres), each (n,); no domain check (:meth:`Rpc.project`)."""
    r, work = np.empty((2, 4)), np.empty((2, 4))
    for p in range(lon.shape[0]):
        x, y, z = (lon[p] - s[4]) / s[5], (lat[p] - s[6]) / s[7], (height[p] - s[8]) / s[9]
        _ratios(c, x, y, z, r, work)
        out[p, 0] = s[0] + s[1] * r[0, 0]
        out[p, 1] = s[2] + s[3] * r[1, 0]


def _ground_all(
    uv: np.ndarray, height: np.ndarray, start: np.ndarray, c: np.ndarray, s: np.ndarray,
    out: np.ndarray,
) -> None:  # fmt: skip
    """Into ``out`` (n, 2): WGS84 (lon, lat), degrees, imaged at pixels ``uv`` (n, 2) at
    ellipsoidal ``height`` (n,) metres, from ``start`` (n, 2) (lon, lat degrees), as
    :meth:`Rpc.ground`."""
    r, work = np.empty((2, 4)), np.empty((2, 4))
    for p in range(uv.shape[0]):
        x, y = _ground(
            c, s, uv[p, 0], uv[p, 1], (height[p] - s[8]) / s[9], (start[p, 0] - s[4]) / s[5],
            (start[p, 1] - s[6]) / s[7], r, work,
        )  # fmt: skip
        out[p, 0] = x * s[5] + s[4]
        out[p, 1] = y * s[7] + s[6]


def _geodetic(x: float, y: float, z: float, a: float, e2: float) -> tuple[float, float, float]:
    """Geodetic (lon, lat) radians and height (m) of geocentric (x, y, z) metres on the
    ellipsoid of semi-major axis ``a`` and squared eccentricity ``e2``: a fixed-point
    iteration on the latitude to float64's precision."""
    p = math.hypot(x, y)
    lon = math.atan2(y, x)
    lat = math.atan2(z, p * (1.0 - e2))
    h = 0.0
    for _ in range(_GEODETIC_STEPS):
        sin, cos = math.sin(lat), math.cos(lat)
        n = a / math.sqrt(1.0 - e2 * sin * sin)
        h = p * cos + z * sin - a * a / n
        new = math.atan2(z, p * (1.0 - e2 * n / (n + h)))
        if abs(new - lat) <= 1e-15:
            lat = new
            break
        lat = new
    sin, cos = math.sin(lat), math.cos(lat)
    n = a / math.sqrt(1.0 - e2 * sin * sin)
    return lon, lat, p * cos + z * sin - a * a / n


_geodetic = cached_jit(_geodetic, fastmath=False, error_model="numpy")


def _geocentric(
    lon: float, lat: float, h: float, a: float, e2: float, out: np.ndarray, jac: np.ndarray
) -> None:
    """Into ``out`` (3,): geocentric metres of geodetic ``lon``, ``lat`` (radians) and height
    ``h`` (m) on the ellipsoid (``a``, ``e2``); into ``jac`` (3, 3): its derivatives by lon,
    lat (per radian) and h (columns)."""
    sl, cl, sp, cp = math.sin(lon), math.cos(lon), math.sin(lat), math.cos(lat)
    w = 1.0 - e2 * sp * sp
    n = a / math.sqrt(w)
    m = a * (1.0 - e2) / (w * math.sqrt(w))
    out[0] = (n + h) * cp * cl
    out[1] = (n + h) * cp * sl
    out[2] = (n * (1.0 - e2) + h) * sp
    jac[0, 0], jac[1, 0], jac[2, 0] = -(n + h) * cp * sl, (n + h) * cp * cl, 0.0
    jac[0, 1], jac[1, 1], jac[2, 1] = -(m + h) * sp * cl, -(m + h) * sp * sl, (m + h) * cp
    jac[0, 2], jac[1, 2], jac[2, 2] = cp * cl, cp * sl, sp


_geocentric = cached_jit(_geocentric, fastmath=False, error_model="numpy")


def _to_geodetic(xyz: np.ndarray, a: float, e2: float, offset: float, out: np.ndarray) -> None:
    """Into ``out`` (n, 3): WGS84-style (lon, lat) degrees and height (m, ``offset`` added) of
    geocentric points ``xyz`` (n, 3) on the ellipsoid (``a``, ``e2``); NaN where not finite."""
    for p in range(xyz.shape[0]):
        x, y, z = xyz[p, 0], xyz[p, 1], xyz[p, 2]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            out[p, 0] = out[p, 1] = out[p, 2] = math.nan
            continue
        lon, lat, h = _geodetic(x, y, z, a, e2)
        out[p, 0], out[p, 1], out[p, 2] = math.degrees(lon), math.degrees(lat), h + offset


def _to_geocentric(
    lonlath: np.ndarray, a: float, e2: float, offset: float, out: np.ndarray
) -> None:  # fmt: skip
    """Into ``out`` (n, 3): geocentric metres of (lon, lat) degrees and height (m, ``offset``
    taken off) ``lonlath`` (n, 3), on the ellipsoid (``a``, ``e2``)."""
    jac = np.empty((3, 3))
    for p in range(lonlath.shape[0]):
        _geocentric(
            math.radians(lonlath[p, 0]), math.radians(lonlath[p, 1]), lonlath[p, 2] - offset, a,
            e2, out[p], jac,
        )  # fmt: skip


def _in_domain(x: float, y: float, z: float, limit: float) -> bool:
    """Whether normalised |L|, |P|, |H| are all within ``limit`` (False for NaN)."""
    return abs(x) <= limit and abs(y) <= limit and abs(z) <= limit


_in_domain = cached_jit(_in_domain, fastmath=False, error_model="numpy")


def _values(
    xyz: np.ndarray, c: np.ndarray, s: np.ndarray, frame: np.ndarray, out: np.ndarray
) -> None:
    """Into ``out`` (n, 10) (NaN on entry): the values of
    :func:`~orthomvp.occlusion.post_lattice.exact_values` of an RPC camera in a geocentric
    world frame at world points ``xyz`` (n, 3): pixel (u, v), depth (m, from the ray's origin,
    negative above ``top``), the ray's origin (m) and unit direction, GSD (m). ``frame``:
    ``a``, ``e2`` of the ellipsoid, the camera's ``height_offset``, ``top``, ``bottom`` (m)
    and ``1 + margin``. One evaluation gives all: the origin is the inversion at ``top``, the
    ray's low end the inversion at ``bottom``, each started from the first-order move along
    the ray from the point (from the origin), and the GSD comes from the analytic Jacobian of
    the pixel by the world point (the pixels per metre along two axes perpendicular to the
    ray)."""
    a, e2, offset, top, bottom, limit = frame[0], frame[1], frame[2], frame[3], frame[4], frame[5]
    r, work = np.empty((2, 4)), np.empty((2, 4))
    origin, low, here = np.empty(3), np.empty(3), np.empty(3)
    jac, ju, jv = np.empty((3, 3)), np.empty(3), np.empty(3)
    for p in range(xyz.shape[0]):
        px, py, pz = xyz[p, 0], xyz[p, 1], xyz[p, 2]
        if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
            continue
        lon, lat, h = _geodetic(px, py, pz, a, e2)
        h += offset
        x = (math.degrees(lon) - s[4]) / s[5]
        y = (math.degrees(lat) - s[6]) / s[7]
        z = (h - s[8]) / s[9]
        if not _in_domain(x, y, z, limit):
            continue
        _ratios(c, x, y, z, r, work)
        u, v = s[0] + s[1] * r[0, 0], s[2] + s[3] * r[1, 0]
        if not (math.isfinite(u) and math.isfinite(v)):
            continue
        out[p, 0], out[p, 1] = u, v
        # the pixel's derivatives by (lon, lat) radians and h metres
        du0 = s[1] * r[0, 1] / s[5] * (180.0 / math.pi)
        du1 = s[1] * r[0, 2] / s[7] * (180.0 / math.pi)
        du2 = s[1] * r[0, 3] / s[9]
        dv0 = s[3] * r[1, 1] / s[5] * (180.0 / math.pi)
        dv1 = s[3] * r[1, 2] / s[7] * (180.0 / math.pi)
        dv2 = s[3] * r[1, 3] / s[9]
        # Newton starts from the first-order move along the ray (the same pixel at another
        # height: the L, P that undo the height's change of the pixel)
        det = r[0, 1] * r[1, 2] - r[0, 2] * r[1, 1]
        ax = -(r[1, 2] * r[0, 3] - r[0, 2] * r[1, 3]) / det  # dL/dH along the ray
        ay = -(r[0, 1] * r[1, 3] - r[1, 1] * r[0, 3]) / det  # dP/dH
        if not (math.isfinite(ax) and math.isfinite(ay)):
            ax, ay = 0.0, 0.0
        zt = (top - s[8]) / s[9]
        xt, yt = _ground(c, s, u, v, zt, x + ax * (zt - z), y + ay * (zt - z), r, work)
        if not _in_domain(xt, yt, zt, limit):
            continue
        _geocentric(
            math.radians(xt * s[5] + s[4]), math.radians(yt * s[7] + s[6]), top - offset, a, e2,
            origin, jac,
        )  # fmt: skip
        depth = math.sqrt((px - origin[0]) ** 2 + (py - origin[1]) ** 2 + (pz - origin[2]) ** 2)
        out[p, 2] = depth if h <= top else -depth
        for k in range(3):
            out[p, 3 + k] = origin[k]
        zb = (bottom - s[8]) / s[9]
        xb, yb = _ground(c, s, u, v, zb, xt + ax * (zb - zt), yt + ay * (zb - zt), r, work)
        if not _in_domain(xb, yb, zb, limit):
            continue
        _geocentric(
            math.radians(xb * s[5] + s[4]), math.radians(yb * s[7] + s[6]), bottom - offset, a,
            e2, low, jac,
        )  # fmt: skip
        dx, dy, dz = low[0] - origin[0], low[1] - origin[1], low[2] - origin[2]
        norm = math.sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = dx / norm, dy / norm, dz / norm
        out[p, 6], out[p, 7], out[p, 8] = dx, dy, dz
        # the pixel's Jacobian by the world point: through the geodetic one, whose columns
        # (east, north, up, scaled) are orthogonal, so that its inverse's rows are the columns
        # over their squared lengths
        _geocentric(lon, lat, h - offset, a, e2, here, jac)
        ju[:] = 0.0
        jv[:] = 0.0
        for k in range(3):
            q = jac[0, k] ** 2 + jac[1, k] ** 2 + jac[2, k] ** 2
            gu = (du0, du1, du2)[k] / q
            gv = (dv0, dv1, dv2)[k] / q
            for i in range(3):
                ju[i] += gu * jac[i, k]
                jv[i] += gv * jac[i, k]
        # two axes perpendicular to the ray, as RpcCamera.gsd takes them
        if abs(dx) < 0.9:
            hx, hy, hz = 1.0, 0.0, 0.0
        else:
            hx, hy, hz = 0.0, 1.0, 0.0
        e1x, e1y, e1z = dy * hz - dz * hy, dz * hx - dx * hz, dx * hy - dy * hx
        n1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        e1x, e1y, e1z = e1x / n1, e1y / n1, e1z / n1
        e2x, e2y, e2z = dy * e1z - dz * e1y, dz * e1x - dx * e1z, dx * e1y - dy * e1x
        a_u = ju[0] * e1x + ju[1] * e1y + ju[2] * e1z
        a_v = jv[0] * e1x + jv[1] * e1y + jv[2] * e1z
        b_u = ju[0] * e2x + ju[1] * e2y + ju[2] * e2z
        b_v = jv[0] * e2x + jv[1] * e2y + jv[2] * e2z
        out[p, 9] = 1.0 / math.sqrt(abs(a_u * b_v - a_v * b_u))


project = cached_jit(_project, fastmath=False, error_model="numpy")
ground = cached_jit(_ground_all, fastmath=False, error_model="numpy")
to_geodetic = cached_jit(_to_geodetic, fastmath=False, error_model="numpy")
to_geocentric = cached_jit(_to_geocentric, fastmath=False, error_model="numpy")
values = cached_jit(_values, fastmath=False, error_model="numpy")


FRAME_TOLERANCE = 1e-6
"""Metres: how closely the kernels' geocentric conversions must reproduce the camera's own
(PROJ's) at probe points across the RPC's domain for :func:`camera_values` to serve it."""

_FRAMES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def frame(camera: RpcCamera) -> np.ndarray | None:
    """The ``frame`` of :func:`values` for ``camera`` (a, e2, height_offset, top, bottom,
    1 + margin), or None where its world frame is not plain geocentric metres on an ellipsoid
    whose conversions the kernels reproduce within :data:`FRAME_TOLERANCE` of PROJ's (checked
    once per world CRS and RPC domain at the 27 points of a 3 x 3 x 3 grid over the domain)."""
    found = _FRAMES.get(camera)
    if found is None:
        crs, rpc = camera.crs, camera.rpc
        domain = tuple(getattr(rpc, key) for key in OFFSETS_SCALES)
        found = _FRAMES[camera] = _frame(
            crs.to_wkt() if crs.is_geocentric and not crs.is_compound else "",
            domain,
            camera.height_offset,
            camera.top,
            camera.bottom,
            camera.margin,
        )
    return found if found.size else None


@functools.lru_cache(maxsize=64)
def _frame(
    wkt: str,
    domain: tuple[float, ...],
    height_offset: float,
    top: float,
    bottom: float,
    margin: float,
) -> np.ndarray:
    """:func:`frame` of a camera in the geocentric world CRS ``wkt`` ("": another kind) with
    an RPC of offsets and scales ``domain`` (:data:`OFFSETS_SCALES`); empty where it does not
    serve."""
    if not wkt:
        return np.empty(0)
    from pyproj import CRS

    from orthomvp.camera.rpc import _to_wgs84

    crs = CRS.from_wkt(wkt)
    a, b = crs.ellipsoid.semi_major_metre, crs.ellipsoid.semi_minor_metre
    e2 = 1.0 - (b / a) ** 2
    offsets = dict(zip(OFFSETS_SCALES, domain, strict=True))
    k = np.array([-1.0, 0.0, 1.0])
    nl, np_, nh = (g.ravel() for g in np.meshgrid(k, k, k, indexing="ij"))
    geo = np.stack(
        [
            offsets["long_off"] + nl * offsets["long_scale"],
            offsets["lat_off"] + np_ * offsets["lat_scale"],
            offsets["height_off"] + nh * offsets["height_scale"],
        ],
        -1,
    )
    x, y, z = _to_wgs84(crs).transform(
        geo[:, 0], geo[:, 1], geo[:, 2] - height_offset, direction="INVERSE"
    )
    truth = np.stack([x, y, z], -1)
    mine, back, again = (np.empty_like(truth) for _ in range(3))
    to_geocentric(geo, a, e2, height_offset, mine)
    to_geodetic(truth, a, e2, height_offset, back)
    to_geocentric(back, a, e2, height_offset, again)
    if not (
        np.isfinite(truth).all()
        and np.abs(mine - truth).max() <= FRAME_TOLERANCE
        and np.abs(again - truth).max() <= FRAME_TOLERANCE
    ):
        return np.empty(0)
    return np.array([a, e2, height_offset, top, bottom, 1.0 + margin])


def camera_values(camera: RpcCamera, xyz: np.ndarray) -> np.ndarray | None:
    """The values (..., 10) of :func:`values` of ``camera`` at world points ``xyz`` (..., 3),
    or None where :func:`frame` does not serve it."""
    found = frame(camera)
    if found is None:
        return None
    coef, scales = pack(camera.rpc)
    flat = np.ascontiguousarray(xyz, np.float64).reshape(-1, 3)
    out = np.full((flat.shape[0], 10), np.nan)
    values(flat, coef, scales, found, out)
    return out.reshape(*xyz.shape[:-1], 10)
