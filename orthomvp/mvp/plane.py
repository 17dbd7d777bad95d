"""Plane geometry of the MVP model: a tangent plane per DEM post and its homographies.

Section 3.2 of the MVP paper. A plane at post z' = (c', r') has a height h (in the DEM's own
convention: height above the reference surface, or radius with ``radius_values``) and a normal n
(eq. 11, angles (n_theta, n_phi) = longitude and latitude of n in the world frame). Every DEM
grid pixel z near z' names a *height line*, the set of world points that the DEM can put at z;
the patch of the plane is where those lines cross the plane, and projecting it through a camera
F gives the homography ``H = F G`` from grid pixels (c, r, 1) to image pixels (eq. 17).

Two exact-to-second-order models of the height lines:

- *central* (the body frame, the paper's case): every line runs from a centre C along a
  direction d(z). On a sphere C is the body centre and d = e(z) (eq. 3), linearised around z' as
  ``[e; 1] = L S_z [z; 1]`` (eqs. 5-7, with the Jacobian's sign corrected and S in radians),
  and ``G = P L S`` (eqs. 15-16), up to scale; only e's direction matters here, so its
  second-order radial error has no effect. On an ellipsoid the height lines are its normals,
  which near the post pass close to the post's centre of mean curvature: C is that point and
  d(z) the (linearised) direction from C to the surface at z.
- *parallel* (the map frame): the lines are vertical, through the points X(z, h0) =
  (easting, northing, h0), which are affine in z: then ``G`` is affine and exact.

In both, G is linear in n (the plane does not depend on |n|) and affine in h; the fitter uses
this for exact derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.codes import WorldFrame
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import unit_vector

FD_STEP = 0.5  # pixels, for the local affine maps of projected CRSs and ellipsoids


def normal_from_angles(n_theta: np.ndarray, n_phi: np.ndarray) -> np.ndarray:
    """Eq. (11): unit normal (..., 3) in the world frame from its longitude ``n_theta`` and
    latitude ``n_phi`` (radians)."""
    return unit_vector(np.asarray(n_theta, dtype=np.float64), np.asarray(n_phi, dtype=np.float64))


def angles_from_normal(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of eq. (11): (n_theta, n_phi) in radians of normals ``n`` (..., 3), any length."""
    n = np.asarray(n, dtype=np.float64)
    return np.arctan2(n[..., 1], n[..., 0]), np.arctan2(n[..., 2], np.hypot(n[..., 0], n[..., 1]))


def lonlat_jacobian(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Eq. (5), corrected: d e / d(lon, lat), (..., 3, 2), for planetocentric radians.

    The paper prints +cos(lon) sin(lat) in the first row; the derivative of cos(lon) cos(lat)
    with respect to lat is -cos(lon) sin(lat).
    """
    lon, lat = np.broadcast_arrays(np.asarray(lon, float), np.asarray(lat, float))
    sl, cl, sp, cp = np.sin(lon), np.cos(lon), np.sin(lat), np.cos(lat)
    zero = np.zeros_like(lon)
    d_lon = np.stack([-sl * cp, cl * cp, zero], axis=-1)
    d_lat = np.stack([-cl * sp, -sl * sp, cp], axis=-1)
    return np.stack([d_lon, d_lat], axis=-1)


def L_matrix(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Eq. (7): (..., 4, 3) affine map ``[e; 1] = L [lon; lat; 1]`` (radians), the first-order
    Taylor expansion of eq. (3) around (lon, lat)."""
    J = lonlat_jacobian(lon, lat)
    e = unit_vector(np.asarray(lon, float), np.asarray(lat, float))
    theta = np.stack(np.broadcast_arrays(np.asarray(lon, float), np.asarray(lat, float)), -1)
    out = np.zeros(J.shape[:-2] + (4, 3))
    out[..., :3, :2] = J
    out[..., :3, 2] = e - np.einsum("...ij,...j->...i", J, theta)
    out[..., 3, 2] = 1.0
    return out


def local_S(terrain: Terrain, c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) affine map from pixel-centre ``(c, r, 1)`` to body ``(lon, lat, 1)`` in
    radians near each ``(c, r)``: eq. (2) in radians for geographic CRSs (exact), the local
    Jacobian by central differences for projected CRSs."""
    c = np.asarray(c, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    out = np.zeros(c.shape + (3, 3))
    out[..., 2, 2] = 1.0
    if terrain.crs.is_geographic:
        S = terrain.S
        out[..., :2, :] = np.radians(S[:2])
        # longitudes near the grid centre, as pixel_to_lonlat returns them
        lon0, _ = terrain.pixel_to_lonlat(c, r)
        lon_raw, _ = terrain.pixel_to_lonlat(c, r, wrap=False)
        out[..., 0, 2] += lon0 - lon_raw
        return out
    h = FD_STEP
    lon_c1, lat_c1 = terrain.pixel_to_lonlat(c + h, r)
    lon_c0, lat_c0 = terrain.pixel_to_lonlat(c - h, r)
    lon_r1, lat_r1 = terrain.pixel_to_lonlat(c, r + h)
    lon_r0, lat_r0 = terrain.pixel_to_lonlat(c, r - h)
    lon, lat = terrain.pixel_to_lonlat(c, r)
    out[..., 0, 0], out[..., 1, 0] = (lon_c1 - lon_c0) / (2 * h), (lat_c1 - lat_c0) / (2 * h)
    out[..., 0, 1], out[..., 1, 1] = (lon_r1 - lon_r0) / (2 * h), (lat_r1 - lat_r0) / (2 * h)
    out[..., 0, 2] = lon - out[..., 0, 0] * c - out[..., 0, 1] * r
    out[..., 1, 2] = lat - out[..., 1, 0] * c - out[..., 1, 1] * r
    return out


@dataclass
class PostLines:
    """The height lines around a batch of B posts (see the module docstring).

    ``central``: the model. ``M`` (B, 3, 3): grid ``(c, r, 1)`` to the line direction d(z)
    (central) or to the base point X(z, h0) (parallel), metres. ``centre`` (B, 3): C of the
    central model (zeros on a sphere). ``a``, ``b`` (B, 3): the post's own point at height h is
    ``a + h b``, with ``b`` the post's unit height direction.
    """

    central: bool
    c: np.ndarray
    r: np.ndarray
    M: np.ndarray
    a: np.ndarray
    b: np.ndarray
    centre: np.ndarray

    @property
    def up(self) -> np.ndarray:
        return self.b / np.linalg.norm(self.b, axis=-1, keepdims=True)

    def point(self, h: np.ndarray) -> np.ndarray:
        """x' = a + h b (eq. 13 in the central model), (B, 3) metres."""
        return self.a + np.asarray(h, dtype=np.float64)[..., None] * self.b

    def take(self, index: np.ndarray) -> PostLines:
        """The lines of a subset of the posts."""
        return PostLines(
            self.central,
            self.c[index],
            self.r[index],
            self.M[index],
            self.a[index],
            self.b[index],
            self.centre[index],
        )


def uses_central_model(terrain: Terrain) -> bool:
    """True in the body frame (height lines from a centre), False in the map frame."""
    return terrain.world == WorldFrame.BODY


def _curvature_radius(terrain: Terrain, lat: np.ndarray) -> np.ndarray:
    """Mean radius of curvature of the reference ellipsoid at geodetic ``lat`` (radians):
    the harmonic mean of the meridional (M) and prime-vertical (N) radii, metres."""
    a, b = terrain.radii
    e2 = 1.0 - (b / a) ** 2
    w = 1.0 - e2 * np.sin(lat) ** 2
    N = a / np.sqrt(w)
    M = a * (1.0 - e2) / w**1.5
    return 2.0 / (1.0 / M + 1.0 / N)


def post_lines(terrain: Terrain, c: np.ndarray, r: np.ndarray, h0: np.ndarray) -> PostLines:
    """Height lines around posts at pixel centres ``c``, ``r`` (B,) with current values ``h0``
    (B,) in the DEM's convention (used by the parallel model as the linearisation height)."""
    c = np.asarray(c, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    h0 = np.asarray(h0, dtype=np.float64)
    st = FD_STEP
    if terrain.world == WorldFrame.BODY and (terrain.is_sphere or terrain.radius_values):
        lon, lat = terrain.pixel_to_lonlat(c, r)
        M = np.einsum("...ij,...jk->...ik", L_matrix(lon, lat), local_S(terrain, c, r))[..., :3, :]
        e = unit_vector(lon, lat)
        r0 = 0.0 if terrain.radius_values else terrain.radii[0]
        return PostLines(True, c, r, M, r0 * e, e, np.zeros_like(e))
    X = terrain.to_world(c, r, h0)
    up = terrain.to_world(c, r, h0 + 0.5) - terrain.to_world(c, r, h0 - 0.5)
    up /= np.linalg.norm(up, axis=-1, keepdims=True)
    a = X - h0[..., None] * up
    if terrain.world == WorldFrame.BODY:  # an ellipsoid: lines through the centre of curvature
        _, lat = terrain.pixel_to_lonlat(c, r)
        C = X - (_curvature_radius(terrain, lat) + h0)[..., None] * up

        def d(cc: np.ndarray, rr: np.ndarray) -> np.ndarray:
            v = terrain.to_world(cc, rr, h0) - C
            return v / np.einsum("...i,...i->...", v, up)[..., None]

        base = d(c, r)
    else:
        C = np.zeros_like(X)

        def d(cc: np.ndarray, rr: np.ndarray) -> np.ndarray:
            return terrain.to_world(cc, rr, h0)

        base = X
    dc = (d(c + st, r) - d(c - st, r)) / (2 * st)
    dr = (d(c, r + st) - d(c, r - st)) / (2 * st)
    M = np.stack([dc, dr, base - dc * c[..., None] - dr * r[..., None]], axis=-1)
    return PostLines(terrain.world == WorldFrame.BODY, c, r, M, a, up, C)


def plane_map(lines: PostLines, h: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``G`` (B, 4, 3) with ``[X; 1] ~ G [c; r; 1]``: grid pixels to the points of the plane
    through ``a + h b`` with normal ``n`` (B, 3, any length). Linear in n, affine in h.

    Central: ``G = [n.(x' - C) M + C n^T M; n^T M]`` (on a sphere C = 0 and this is P L S of
    eqs. 15-16 times n.x'). Parallel: ``G = [(n.u) M + u ((n.x') e3^T - n^T M); (n.u) e3^T]``.
    """
    n = np.asarray(n, dtype=np.float64)
    nM = np.einsum("...i,...ij->...j", n, lines.M)
    G = np.zeros(n.shape[:-1] + (4, 3))
    if lines.central:
        k = np.einsum("...i,...i->...", n, lines.point(h) - lines.centre)
        G[..., :3, :] = k[..., None, None] * lines.M + lines.centre[..., :, None] * nM[..., None, :]
        G[..., 3, :] = nM
        return G
    k = np.einsum("...i,...i->...", n, lines.point(h))
    u = lines.b
    nu = np.einsum("...i,...i->...", n, u)
    row = -nM
    row[..., 2] += k
    G[..., :3, :] = nu[..., None, None] * lines.M + u[..., :, None] * row[..., None, :]
    G[..., 3, 2] = nu
    return G


def tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (B, 3) orthogonal to unit ``n`` and to each other (t1 roughly east)."""
    ref = np.zeros_like(n)
    ref[..., 2] = 1.0
    polar = np.abs(n[..., 2]) > 0.9
    ref[polar] = (1.0, 0.0, 0.0)
    t1 = np.cross(ref, n)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    return t1, np.cross(n, t1)
