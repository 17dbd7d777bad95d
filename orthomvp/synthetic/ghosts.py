"""Partial ghosts against the city's exact geometry: how much of a post's image sample comes
from surface far from the post.

A bilinear sample at a post's pixel position mixes the four pixels around it, and each pixel of
a city image is the mean of ``supersample`` x ``supersample`` rays (:meth:`CityScene.render`).
Casting exactly those rays, weighted by their pixel's bilinear weight and their share of the
pixel, gives the share of the sample whose rays first hit the surface more than ``reach``
metres (3D) from the post's own surface point and nearer the camera than the post: its
*occluder share*. A sample with an occluder share is a partial ghost: part of its value is an
occluder's (a roof edge, a wall top, a tree crown) seen in the image beside the post. A
visible wall rising at a post's foot stays within reach of the post and does not count, nor
does the ground seen past a roof or crown edge (background, farther than the post).
"""

from __future__ import annotations

import numpy as np

from orthomvp.synthetic.city import ORIGIN, CityScene, _clip, _ellipsoid

CHUNK = 200_000
"""Rays cast at a time."""


def hit_points(scene: CityScene, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Local first-hit points (n, 3) of rays from local origins ``o`` (n, 3) along unit ``d``
    (n, 3) on the city's surface, walls included (NaN where a ray meets nothing), as
    :meth:`~orthomvp.synthetic.city.CitySurface.first_hit` finds them."""
    s = scene.surface
    best = s._ground_hit(o, d)
    for b in s.buildings:
        t_in, t_out, _ = _clip(o, d, *b.planes(), shrink=0.0)
        hit = (t_in <= t_out) & (t_in > 0) & (t_in < best)
        best = np.where(hit, t_in, best)
    for t in s.trees:
        s1, s2 = _ellipsoid(o, d, t, shrink=0.0)
        best = np.where((s1 < s2) & (s1 > 0) & (s1 < best), s1, best)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(best)[:, None], o + best[:, None] * d, np.nan)


def occluder_share(
    scene: CityScene,
    camera_name: str,
    uv: np.ndarray,
    posts: np.ndarray,
    *,
    supersample: int = 3,
    reach: float | None = None,
    nearest: np.ndarray | None = None,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """The occluder share (n,) in 0..1 of the bilinear samples at pixel positions ``uv``
    (n, 2) of the posts at local points ``posts`` (n, 3) in view ``camera_name``: the weight of
    the rays of its four pixels (``supersample`` rays a side, as rendered) that hit the surface
    more than ``reach`` metres (default two post spacings) from the post and nearer the camera
    than it (rays that meet nothing count as not). Pixels outside the image carry no weight
    (NaN where none is inside). ``nearest`` (n,) bool: those posts' samples are their nearest
    pixel's (``cv2.INTER_NEAREST``: the position rounded half to even), not bilinear;
    ``weights`` (4, n): the four pixels' weights instead of the bilinear ones, in the order
    (du, dv) (0, 0), (1, 0), (0, 1), (1, 1) (:func:`orthomvp.ortho.support.clear_taps`)."""
    cam = scene.cameras[camera_name]
    reach = 2 * scene.spacing if reach is None else reach
    k = supersample
    offs = (np.arange(k) + 0.5) / k - 0.5
    sub = np.stack(np.meshgrid(offs, offs, indexing="xy"), -1).reshape(-1, 2)
    if nearest is not None:
        uv = np.where(np.asarray(nearest, bool)[:, None], np.rint(uv), uv)
    base = np.floor(uv)
    frac = uv - base
    share = np.zeros(len(uv))
    total = np.zeros(len(uv))
    for t, (du, dv) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
        if weights is None:
            w = (frac[:, 0] if du else 1 - frac[:, 0]) * (frac[:, 1] if dv else 1 - frac[:, 1])
        else:
            w = np.asarray(weights[t], np.float64)
        pix = base + [du, dv]
        inside = (
            (pix[:, 0] >= 0)
            & (pix[:, 0] <= cam.width - 1)
            & (pix[:, 1] >= 0)
            & (pix[:, 1] <= cam.height - 1)
            & np.isfinite(w)
        )
        w = np.where(inside, w, 0.0)
        total += w
        far = np.zeros(len(uv))
        for i0 in range(0, len(uv), CHUNK // len(sub)):
            i1 = min(i0 + CHUNK // len(sub), len(uv))
            rays = (pix[i0:i1, None, :] + sub).reshape(-1, 2)
            o, d = cam.ray(rays)
            d = d / np.linalg.norm(d, axis=1, keepdims=True)
            q = hit_points(scene, o - ORIGIN, d).reshape(i1 - i0, len(sub), 3)
            o = (o - ORIGIN).reshape(i1 - i0, len(sub), 3)
            dist = np.linalg.norm(q - posts[i0:i1, None, :], axis=-1)
            ahead = np.linalg.norm(q - o, axis=-1) < np.linalg.norm(posts[i0:i1, None] - o, axis=-1)
            far[i0:i1] = ((dist > reach) & ahead).mean(axis=1)
        share += w * far
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, share / total, np.nan)
