"""The scene kinds' analytic heights and albedo, as functions of local (x, y) metres.

``planar``: a tilted 3D plane; ``crater``: a complex crater with a central peak; ``hills``:
rolling terrain; ``city`` (box buildings and trees in a projected CRS) is built by
:mod:`orthomvp.synthetic.city`. Each builder draws its random parameters from the generator it
is given, so a seed fixes the scene.
"""

from __future__ import annotations

import numpy as np

from orthomvp.geometry.vectors import unit_vector
from orthomvp.synthetic.surface import MOON_RADIUS, LocalField, local_frame

KINDS = ("planar", "crater", "hills", "city")
DEFAULTS = {
    "planar": (64, 40.0, 0.8),
    "crater": (160, 40.0, 0.8),
    "hills": (128, 30.0, 0.8),
    "city": (160, 0.5, 0.5),
}
"""Default (size in posts, post spacing in metres, image GSD / post spacing) of each kind.
The city's images are twice as fine as its surface model: a surface model matched from aerial
images has at most one independent height per two pixels or so, and true orthophotos are made
from such pairs (at 0.8, the images' 0.4 m pixels straddle each wall edge next to the 0.5 m
posts, and no choice of view brings the mosaic's correlation with the true radiance above
0.994 bilinear; see the README's city figures)."""


def relief(
    kind: str, extent: float, lon0: float, lat0: float, rng: np.random.Generator
) -> tuple[LocalField, dict]:
    """The height function of ``kind`` (one of :data:`KINDS`) on a tile ``extent`` metres wide
    centred on ``lon0``, ``lat0`` (radians), and the facts about it that a scene summary
    records."""
    if kind == "crater":
        return crater(extent, rng)
    if kind == "hills":
        return hills(extent, rng)
    return plane(lon0, lat0, rng)


def texture(rng: np.random.Generator, spacing: float) -> LocalField:
    """Band-limited analytic noise albedo in [0.05, 0.95]: a sum of random plane waves with
    wavelengths from 3 to 16 post spacings (resolved by every view, even the oblique one)."""
    k = 64
    wl = spacing * np.exp(rng.uniform(np.log(3.0), np.log(16.0), k))
    ang = rng.uniform(0, np.pi, k)
    kx, ky = 2 * np.pi * np.cos(ang) / wl, 2 * np.pi * np.sin(ang) / wl
    ph = rng.uniform(0, 2 * np.pi, k)
    amp = np.sqrt(wl / wl.max())
    amp *= 0.22 / np.sqrt(np.sum(amp**2) / 2)

    def albedo(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        acc = np.full(np.broadcast_shapes(x.shape, y.shape), 0.5)
        for i in range(k):
            acc += amp[i] * np.cos(kx[i] * x + ky[i] * y + ph[i])
        return np.clip(acc, 0.05, 0.95)

    return albedo


def crater(extent: float, rng: np.random.Generator) -> tuple[LocalField, dict]:
    """A complex crater with a terraced-looking steep wall, raised rim and central peak."""
    rc = 0.36 * extent
    depth, rim, peak = 0.45 * rc, 0.12 * rc, 0.40 * rc
    ph = rng.uniform(0, 2 * np.pi, 2)

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        rho = np.hypot(x, y)
        s = np.clip((rho - 0.4 * rc) / (0.6 * rc), 0, 1)
        wall = -depth + (depth + rim) * s * s * (3 - 2 * s)
        outside = rim * np.exp(-(((rho - rc) / (0.35 * rc)) ** 2))
        base = np.where(rho < rc, wall, outside)
        central = peak * np.exp(-((rho / (0.13 * rc)) ** 2))
        waves = 0.01 * rc * (np.sin(x / (0.3 * rc) + ph[0]) * np.cos(y / (0.4 * rc) + ph[1]))
        return base + central + waves

    return height, {"crater_radius_m": rc, "crater_depth_m": depth, "peak_height_m": peak}


def hills(extent: float, rng: np.random.Generator) -> tuple[LocalField, dict]:
    """Rolling hills: a few smooth Gaussian bumps and long waves, slopes up to ~20 degrees."""
    n = 7
    cx, cy = rng.uniform(-0.45, 0.45, (2, n)) * extent
    sig = rng.uniform(0.08, 0.18, n) * extent
    amp = rng.uniform(-0.05, 0.06, n) * extent
    ph = rng.uniform(0, 2 * np.pi, 2)

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        h = (
            0.02
            * extent
            * np.sin(2 * np.pi * x / (0.7 * extent) + ph[0])
            * np.cos(2 * np.pi * y / (0.9 * extent) + ph[1])
        )
        for i in range(n):
            h = h + amp[i] * np.exp(-((x - cx[i]) ** 2 + (y - cy[i]) ** 2) / (2 * sig[i] ** 2))
        return h

    return height, {}


def plane(lon0: float, lat0: float, rng: np.random.Generator) -> tuple[LocalField, dict]:
    """A true 3D plane through the point at height -1500 m above the tile centre, tilted by a
    few degrees; its height above the sphere is n.x0 / n.e - R (eq. 14)."""
    e0, east, north = local_frame(lon0, lat0)
    x0 = (MOON_RADIUS - 1500.0) * e0
    tilt, az = np.radians(rng.uniform(4, 8)), rng.uniform(0, 2 * np.pi)
    n = np.cos(tilt) * e0 + np.sin(tilt) * (np.cos(az) * east + np.sin(az) * north)
    scale_x = MOON_RADIUS * np.cos(lat0)

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        e = unit_vector(lon0 + np.asarray(x) / scale_x, lat0 + np.asarray(y) / MOON_RADIUS)
        return (n @ x0) / (e @ n) - MOON_RADIUS

    n_theta, n_phi = np.degrees(np.arctan2(n[1], n[0])), np.degrees(np.arcsin(n[2]))
    return height, {
        "plane_normal": n.tolist(),
        "plane_normal_angles_deg": [float(n_theta), float(n_phi)],
        "plane_point": x0.tolist(),
    }
