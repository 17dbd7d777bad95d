"""Local projective approximations of cameras that are not pinholes, for the plane fit.

The fit warps images onto each post's plane by plane-induced homographies ``F [t1 t2 X0]``
(eq. 9), which need a 3 x 4 projection matrix ``F``. A pinhole (its image without lens
distortion) has one; any other camera (a line scanner, RPC) gets one per post and view: the
direct linear transform (Hartley-normalised) fitted to ``camera.project`` of a
:data:`FIT_LATTICE` of world points spanning the post's finest-level patch, ``hwin`` posts
either way, from its starting height minus to plus ``hwin`` post spacings (planes tilted up to
45 degrees). The matrix depends on the post's grid position and starting value only, so a
window of the DEM gets the whole DEM's matrices.

Its reprojection error, the largest distance between the matrix's and the camera's pixels
over the denser :data:`CHECK_LATTICE` of the same box, must stay within :data:`ERROR_BOUND`
pixels, else the view does not take part at that post (its matrix is NaN, as for a patch off
the image); :func:`local_projections` reports the errors. A smaller ``hwin`` shrinks the box:
the error of a pushbroom grows about as the square of the box's size. Coarser pyramid levels
use the same matrix over their larger patches, where it is not bounded: they only bring the
planes near.
Lattice points the camera does not image (NaN) are left out.

The bound, a tenth of a pixel, is set from what the error does to the fit. Two line scanners
over the synthetic crater (tests/test_mvp_linescan.py; 55 and 18 degrees, 64 x 64 posts at
80 m, two levels) have largest errors of 0.016, 0.040 and 0.062 px at hwin 5, 8 and 10 (the
default; the 18-degree view's are twice the 55-degree view's). Their fit's RMSE and median
error stay within 3% of the frame cameras' of the same geometry at hwin 10 and 5 (hwin 8: the
median 4% below, the RMSE 19% above, as much with matrices of less than half the error, so
from the geometry, not the matrices). Scaling the box's heights by 0.25 to 2-3, which takes the
errors from 0.017-0.027 px to 0.12 px (hwin 8 and 10), moves RMSE and median by at most
1.5%, about what moving the starting DEM by 1 m does. The worst an error within the bound can
do, shifting one view's whole patch by it, moves the median error by 0.03 ground pixels (4%)
at a tenth of a pixel and by 0.007 (1%) at 0.03 px (hwin 10). Errors beyond a tenth of a
pixel, e.g. hwin 15 on the 18-degree view (0.15 px), call for a smaller ``hwin``.
"""

from __future__ import annotations

import numpy as np

from orthomvp.camera import Camera
from orthomvp.geometry.terrain import Terrain

ERROR_BOUND = 0.1
"""Largest reprojection error of a local projection matrix over its post's finest-level
patch, level-0 pixels (a tenth: the module docstring says why)."""
FIT_LATTICE = 5
"""Lattice points per axis (columns, rows, heights) the matrix is fitted to."""
CHECK_LATTICE = 6
"""Lattice points per axis its error is measured on."""


def fit_projections(xyz: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The 3 x 4 projection matrices ``P`` (B, 3, 4) with ``[uv; 1] ~ P [xyz; 1]`` of B sets
    of world points ``xyz`` (B, N, 3), metres, and their pixels ``uv`` (B, N, 2) (NaN rows
    left out; at least 6 points not coplanar each): the direct linear transform on coordinates
    centred and scaled to unit RMS size, signed so that the points lie in front (positive
    third coordinate)."""
    ok = np.isfinite(uv).all(axis=-1) & np.isfinite(xyz).all(axis=-1)
    wt = ok / np.maximum(ok.sum(axis=1, keepdims=True), 1)  # (B, N) weights of the means
    xyz0, uv0 = np.where(ok[..., None], xyz, 0.0), np.where(ok[..., None], uv, 0.0)
    mx, mu = np.einsum("bn,bni->bi", wt, xyz0), np.einsum("bn,bni->bi", wt, uv0)
    dx, du = (xyz0 - mx[:, None]) * ok[..., None], (uv0 - mu[:, None]) * ok[..., None]
    sx = np.sqrt(3.0 / np.einsum("bn,bn->b", wt, np.sum(dx * dx, axis=-1)))
    su = np.sqrt(2.0 / np.einsum("bn,bn->b", wt, np.sum(du * du, axis=-1)))
    X = np.concatenate([dx * sx[:, None, None], ok[..., None].astype(float)], axis=-1)
    u, v = (du * su[:, None, None])[..., 0], (du * su[:, None, None])[..., 1]
    B, N = ok.shape
    A = np.zeros((B, 2 * N, 12))
    A[:, 0::2, 0:4], A[:, 0::2, 8:12] = X, -u[..., None] * X
    A[:, 1::2, 4:8], A[:, 1::2, 8:12] = X, -v[..., None] * X
    Pn = np.linalg.svd(A, full_matrices=False)[2][:, -1].reshape(B, 3, 4)
    Tx = np.tile(np.eye(4), (B, 1, 1))
    Tx[:, :3, :3] *= sx[:, None, None]
    Tx[:, :3, 3] = -sx[:, None] * mx
    Tu = np.tile(np.eye(3), (B, 1, 1))
    Tu[:, 0, 0] = Tu[:, 1, 1] = 1 / su
    Tu[:, :2, 2] = mu
    P = Tu @ Pn @ Tx
    w = np.einsum("bnj,bj->bn", np.concatenate([xyz0, np.ones((B, N, 1))], axis=-1), P[:, 2])
    front = np.sum(np.where(ok, np.sign(w), 0.0), axis=1) >= 0
    return np.where(front[:, None, None], P, -P)


def reprojection_errors(P: np.ndarray, xyz: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(B,) largest distance (pixels) between the pixels of ``P`` (B, 3, 4) at ``xyz``
    (B, N, 3) and ``uv`` (B, N, 2), over the finite ``uv`` (0 without any)."""
    h = np.einsum("bij,bnj->bni", P, np.concatenate([xyz, np.ones(xyz.shape[:-1] + (1,))], -1))
    d = np.linalg.norm(h[..., :2] / h[..., 2:] - uv, axis=-1)
    return np.max(np.where(np.isfinite(uv).all(axis=-1), d, 0.0), axis=1)


def lattice(
    grid: Terrain, c: np.ndarray, r: np.ndarray, h: np.ndarray, reach: int, slack: float, n: int
) -> np.ndarray:
    """World points (B, n**3, 3) of an ``n`` x ``n`` x ``n`` lattice around each post
    (``c``, ``r``) (B,) of ``grid``: ``reach`` posts either way, heights ``h`` (B,) minus to
    plus ``slack`` (the DEM's units)."""
    t = np.linspace(-1.0, 1.0, n)
    dc, dr, dh = (x.ravel() for x in np.meshgrid(t, t, t, indexing="ij"))
    cc = np.asarray(c, np.float64)[:, None] + reach * dc
    rr = np.asarray(r, np.float64)[:, None] + reach * dr
    hh = np.asarray(h, np.float64)[:, None] + slack * dh
    return grid.to_world(cc, rr, hh)


def local_projections(
    camera: Camera,
    grid: Terrain,
    c: np.ndarray,
    r: np.ndarray,
    h: np.ndarray,
    *,
    hwin: int,
    spacing: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Projection matrices (B, 3, 4) of ``camera`` at posts (``c``, ``r``) (B,) of ``grid``
    with starting values ``h`` (B,) and their reprojection errors (B,) in pixels over the
    posts' finest-level patches (module docstring); ``hwin`` the window's half-size in posts,
    ``spacing`` the mean post spacing in metres. NaN matrices where the camera images fewer
    than 12 of the lattice's points (error 0) or the error exceeds :data:`ERROR_BOUND`."""
    slack = hwin * spacing
    xyz = lattice(grid, c, r, h, hwin, slack, FIT_LATTICE)
    uv, depth = camera.project(xyz)
    uv = np.where((depth > 0)[..., None], uv, np.nan)
    enough = np.isfinite(uv).all(axis=-1).sum(axis=1) >= 12
    P = np.full((len(xyz), 3, 4), np.nan)
    errors = np.zeros(len(xyz))
    if not enough.any():
        return P, errors
    P[enough] = fit_projections(xyz[enough], uv[enough])
    check = lattice(grid, c[enough], r[enough], h[enough], hwin, slack, CHECK_LATTICE)
    uvc, depth = camera.project(check)
    uvc = np.where((depth > 0)[..., None], uvc, np.nan)
    errors[enough] = reprojection_errors(P[enough], check, uvc)
    P[~(errors <= ERROR_BOUND)] = np.nan
    return P, errors
