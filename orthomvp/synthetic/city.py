"""A city with exact truth: box buildings with vertical walls and gabled roofs, and trees, on
gentle ground, in a projected CRS, seen by four oblique aerial frames in the map world frame.

Coordinates: local ``(x, y, z)`` metres are the map frame (easting, northing, height) less
:data:`ORIGIN` (the tile centre; heights are not shifted). The surface model is the height
field ``H(x, y) = max(ground, roofs over their footprints, tree crowns)``.

Why the truth is exact despite vertical walls. The solid under the surface, ``z < H(x, y)``,
is the union of convex pieces plus the ground: each building is a convex polytope (four walls,
two roof planes, a floor below the lowest ground), each tree crown an ellipsoid whose centre
lies below the lowest ground under it (so its column is convex and its buried lower half
changes nothing). A segment dips under the surface iff it enters one of them or the ground:

- polytopes: Cyrus-Beck clipping against the planes moved 1 um inwards, exact;
- ellipsoids: the quadratic for the ellipsoid shrunk by 1 um, exact;
- ground: its slope is bounded (:attr:`CitySurface.max_slope`); a segment that rises faster
  than that from a point on or above the ground never meets it, others are marched.

A fixed-step march against ``below`` could step over the corner of a wall; clipping cannot.
Walls, ridges and tree centres sit on DEM cell corners (half-post offsets), so every post lies
at least half a post from a wall or ridge: its height and analytic normal are those of one
piece. Images are rendered with the same exact first hits (no mesh), walls shaded with their own
horizontal normals; the truth radiance at the posts is that of the top surface.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from affine import Affine
from pyproj import CRS

from orthomvp.camera import PinholeCamera
from orthomvp.codes import WorldFrame
from orthomvp.geometry.terrain import Terrain
from orthomvp.synthetic.cameras import ViewSpec, orbital_camera
from orthomvp.synthetic.kinds import texture
from orthomvp.synthetic.rendering import MAX_SUPERSAMPLE
from orthomvp.synthetic.surface import LocalField
from orthomvp.synthetic.truth import truth_codes
from orthomvp.synthetic.writer import write_scene
from orthomvp.validate import number

CITY_CRS = "EPSG:32633"
"""UTM zone 33N (WGS 84)."""
ORIGIN = np.array([500_000.0, 5_000_000.0, 0.0])
"""Map coordinates of the local origin (the tile centre), metres."""
BASE_HEIGHT = 300.0
"""Mean ground height, metres."""
SUN = (150.0, 50.0)
"""Sun azimuth (degrees clockwise from north) and elevation (degrees)."""
TOL = 1e-6
"""How far inside a piece a segment must reach to count as under the surface, metres."""
VIEW_ANGLES = (("ne", 40.0, 45.0), ("se", 35.0, 135.0), ("sw", 45.0, 225.0), ("nw", 38.0, 315.0))
"""The four oblique aerial frames: name, emission angle and azimuth from the ground (degrees)."""
ALTITUDE = 2.0
"""Flying height above the tile centre, in tile widths (160 m over the default 80 m tile)."""


@dataclass(frozen=True)
class Building:
    """A box on footprint ``x0 < x < x1``, ``y0 < y < y1`` (local metres) with a gabled roof:
    eaves at height ``eave`` (metres), rising with slope ``pitch`` (tan of the roof angle)
    to a ridge along ``ridge`` ("x" or "y") through the middle; ``floor`` lies below the
    lowest ground under it. ``albedo`` of the roof and ``wall`` albedo, in [0, 1]."""

    x0: float
    x1: float
    y0: float
    y1: float
    eave: float
    pitch: float
    ridge: str
    floor: float
    albedo: float
    wall: float

    def planes(self) -> tuple[np.ndarray, np.ndarray]:
        """The polytope as ``n . p <= b``: normals (7, 3) (outward; walls, roofs, floor) and
        offsets (7,)."""
        p = self.pitch
        if self.ridge == "x":  # z <= eave + p (half - |y - cy|)
            cy, half = (self.y0 + self.y1) / 2, (self.y1 - self.y0) / 2
            roofs = [
                ([0, p, 1], self.eave + p * (half + cy)),
                ([0, -p, 1], self.eave + p * half - p * cy),
            ]
        else:
            cx, half = (self.x0 + self.x1) / 2, (self.x1 - self.x0) / 2
            roofs = [
                ([p, 0, 1], self.eave + p * (half + cx)),
                ([-p, 0, 1], self.eave + p * half - p * cx),
            ]
        rows = [
            ([1, 0, 0], self.x1),
            ([-1, 0, 0], -self.x0),
            ([0, 1, 0], self.y1),
            ([0, -1, 0], -self.y0),
            *roofs,
            ([0, 0, -1], -self.floor),
        ]
        return np.array([r[0] for r in rows], float), np.array([r[1] for r in rows], float)

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether local (x, y) lie in the footprint."""
        return (x > self.x0) & (x < self.x1) & (y > self.y0) & (y < self.y1)

    def roof(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Roof height and its gradient (dz/dx, dz/dy) at local (x, y) in the footprint."""
        if self.ridge == "x":
            d = y - (self.y0 + self.y1) / 2
            z = self.eave + self.pitch * ((self.y1 - self.y0) / 2 - np.abs(d))
            return z, np.zeros_like(z), -self.pitch * np.sign(d)
        d = x - (self.x0 + self.x1) / 2
        z = self.eave + self.pitch * ((self.x1 - self.x0) / 2 - np.abs(d))
        return z, -self.pitch * np.sign(d), np.zeros_like(z)


@dataclass(frozen=True)
class Tree:
    """A crown: the ellipsoid of centre (``x``, ``y``, ``z``) (local metres), horizontal
    semi-axis ``radius`` and vertical semi-axis ``height``; ``z`` lies below the lowest ground
    within ``radius``."""

    x: float
    y: float
    z: float
    radius: float
    height: float

    def top(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Crown height (-inf outside the crown) and its gradient at local (x, y)."""
        q = ((x - self.x) ** 2 + (y - self.y) ** 2) / self.radius**2
        s = np.sqrt(np.clip(1 - q, 1e-12, None))
        z = np.where(q < 1, self.z + self.height * s, -np.inf)
        k = -self.height / (self.radius**2 * s)
        return z, k * (x - self.x), k * (y - self.y)


@dataclass(frozen=True, eq=False)
class Ground:
    """Gentle ground: ``BASE_HEIGHT + sx x + sy y + amp sin(kx x + px) cos(ky y + py)``."""

    sx: float
    sy: float
    amp: float
    kx: float
    ky: float
    px: float
    py: float

    def height(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ground height and its gradient at local (x, y)."""
        sx, cx = np.sin(self.kx * x + self.px), np.cos(self.kx * x + self.px)
        sy, cy = np.sin(self.ky * y + self.py), np.cos(self.ky * y + self.py)
        z = BASE_HEIGHT + self.sx * x + self.sy * y + self.amp * sx * cy
        return z, self.sx + self.amp * self.kx * cx * cy, self.sy - self.amp * self.ky * sx * sy

    @property
    def max_slope(self) -> float:
        """An upper bound of the ground's slope (|gradient|)."""
        return float(np.hypot(abs(self.sx) + self.amp * self.kx, abs(self.sy) + self.amp * self.ky))


@dataclass(frozen=True, eq=False)
class CitySurface:
    """The analytic city: ``ground``, ``buildings``, ``trees``, the ground ``albedo`` texture
    (a function of local x, y) and the unit vector ``sun`` towards the sun."""

    ground: Ground
    buildings: tuple[Building, ...]
    trees: tuple[Tree, ...]
    albedo: LocalField
    sun: np.ndarray

    def pieces(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, ...]:
        """Height, gradient (dz/dx, dz/dy) and piece (0 ground, 1.. buildings, then trees) of
        the top surface at local (x, y)."""
        z, gx, gy = self.ground.height(x, y)
        piece = np.zeros(np.shape(z), int)
        for k, b in enumerate(self.buildings, start=1):
            inside = b.inside(x, y)
            rz, rx, ry = b.roof(x, y)
            z, gx, gy = (np.where(inside, a, o) for a, o in ((rz, z), (rx, gx), (ry, gy)))
            piece = np.where(inside, k, piece)
        for k, t in enumerate(self.trees, start=1 + len(self.buildings)):
            tz, tx, ty = t.top(x, y)
            above = tz > z
            z, gx, gy = (np.where(above, a, o) for a, o in ((tz, z), (tx, gx), (ty, gy)))
            piece = np.where(above, k, piece)
        return z, gx, gy, piece

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Surface height H (metres) at local (x, y)."""
        return self.pieces(x, y)[0]

    def normal(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Unit upward normal (..., 3) of the piece on top at local (x, y)."""
        _, gx, gy, _ = self.pieces(x, y)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def _base(self, piece: np.ndarray) -> np.ndarray:
        bases = [0.5] + [b.albedo for b in self.buildings] + [0.2] * len(self.trees)
        return np.asarray(bases)[piece]

    def radiance(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Lambertian radiance of the top surface at local (x, y): albedo * (0.25 + 0.75
        max(0, n . sun)), albedo = the piece's base + 0.6 (texture - 0.5), in [0.03, 0.97]."""
        _, gx, gy, piece = self.pieces(x, y)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        albedo = np.clip(self._base(piece) + 0.6 * (self.albedo(x, y) - 0.5), 0.03, 0.97)
        return albedo * (0.25 + 0.75 * np.clip(n @ self.sun, 0, None))

    def below(self, p: np.ndarray) -> np.ndarray:
        """Whether local points ``p`` (n, 3) lie under the surface (by more than :data:`TOL`)."""
        return p[:, 2] < self.height(p[:, 0], p[:, 1]) - TOL

    # ----------------------------------------------------------------- segments and rays
    def hidden(self, p: np.ndarray, end: np.ndarray, step: float) -> np.ndarray:
        """Whether the segment from each local point ``p`` (n, 3) on the surface to ``end``
        ((3,) or (n, 3)) dips under the surface: (n,) bool (see the module docstring; the
        ground is marched every ``step`` metres only on segments shallower than its slope)."""
        seg = np.broadcast_to(end, p.shape) - p
        length = np.linalg.norm(seg, axis=1)
        u = seg / length[:, None]
        hidden = np.zeros(len(p), bool)
        for b in self.buildings:
            t_in, t_out, _ = _clip(p, u, *b.planes(), shrink=TOL)
            hidden |= (t_in < t_out) & (t_in < length) & (t_out > 0)
        for t in self.trees:
            s1, s2 = _ellipsoid(p, u, t, shrink=TOL)
            hidden |= (s1 < s2) & (s1 < length) & (s2 > 0)
        shallow = np.flatnonzero(u[:, 2] <= self.ground.max_slope * np.hypot(u[:, 0], u[:, 1]))
        for i in shallow:  # rare: march the ground
            s = np.arange(step / 2, length[i], step)
            q = p[i] + s[:, None] * u[i]
            hidden[i] |= bool((q[:, 2] < self.ground.height(q[:, 0], q[:, 1])[0] - TOL).any())
        return hidden

    def first_hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Radiance of the first surface point (walls included) on rays from local origins
        ``o`` (n, 3) along unit ``d`` (n, 3) (0 where a ray meets nothing)."""
        best = self._ground_hit(o, d)
        what = np.zeros(len(o), int)  # 0 ground or top surface, k > 0 wall of building k
        normals = np.zeros((len(o), 3))
        for k, b in enumerate(self.buildings, start=1):
            n, off = b.planes()
            t_in, t_out, face = _clip(o, d, n, off, shrink=0.0)
            hit = (t_in <= t_out) & (t_in > 0) & (t_in < best)
            best = np.where(hit, t_in, best)
            wall = hit & (face < 4)
            what = np.where(hit, np.where(wall, k, 0), what)
            normals[wall] = n[face[wall]]
        for t in self.trees:
            s1, s2 = _ellipsoid(o, d, t, shrink=0.0)
            hit = (s1 < s2) & (s1 > 0) & (s1 < best)
            best = np.where(hit, s1, best)
            what[hit] = 0
        out = np.zeros(len(o))
        found = np.isfinite(best)
        q = o[found] + best[found, None] * d[found]
        top = what[found] == 0
        out_f = np.empty(len(q))
        out_f[top] = self.radiance(q[top, 0], q[top, 1])
        walls = ~top
        if walls.any():
            base = np.array([0.0] + [b.wall for b in self.buildings])[what[found][walls]]
            qw = q[walls]
            albedo = np.clip(
                base + 0.6 * (self.albedo(qw[:, 0] + qw[:, 1], qw[:, 2]) - 0.5), 0.03, 0.97
            )
            nw = normals[found][walls]
            out_f[walls] = albedo * (0.25 + 0.75 * np.clip(nw @ self.sun, 0, None))
        out[found] = out_f
        return out

    def _ground_hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Distance along each ray to the ground (inf for rays not steeper than its slope):
        z - g falls strictly along a steeper ray, so bisection finds its one root."""
        g = self.ground
        fall = d[:, 2] + g.max_slope * np.hypot(d[:, 0], d[:, 1])  # bound of d(z - g)/dt
        ok = fall < 0
        f0 = o[:, 2] - g.height(o[:, 0], o[:, 1])[0]
        lo = np.zeros(len(o))
        hi = np.where(ok, f0 / -np.where(ok, fall, -1.0), 0.0)
        for _ in range(45):  # from at most ~1 km to below 1e-10 m
            mid = (lo + hi) / 2
            q = o + mid[:, None] * d
            above = q[:, 2] > g.height(q[:, 0], q[:, 1])[0]
            lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
        return np.where(ok & (f0 > 0), (lo + hi) / 2, np.inf)


def _clip(
    o: np.ndarray, u: np.ndarray, n: np.ndarray, b: np.ndarray, shrink: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cyrus-Beck: the parameter interval (t_in, t_out) of lines ``o + t u`` (n, 3) inside the
    polytope ``n . p <= b - shrink``, and the plane each line enters through (t_in > t_out:
    no intersection)."""
    num = (b - shrink)[None, :] - o @ n.T  # > 0: on the inner side at t = 0
    den = u @ n.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / den
    entering = den < 0
    leaving = den > 0
    t_in = np.where(entering, t, -np.inf)
    t_out = np.where(leaving, t, np.inf)
    parallel_out = (den == 0) & (num < 0)
    face = np.argmax(t_in, axis=1)
    t_in, t_out = t_in.max(axis=1), t_out.min(axis=1)
    t_out = np.where(parallel_out.any(axis=1), -np.inf, t_out)
    return t_in, t_out, face


def _ellipsoid(
    o: np.ndarray, u: np.ndarray, tree: Tree, shrink: float
) -> tuple[np.ndarray, np.ndarray]:
    """The parameter interval (s1, s2) of lines ``o + s u`` inside the crown ellipsoid shrunk
    by ``shrink`` metres (s1 >= s2: none)."""
    scale = np.array([tree.radius, tree.radius, tree.height]) - shrink
    a = u / scale
    c = (o - [tree.x, tree.y, tree.z]) / scale
    qa = np.einsum("ij,ij->i", a, a)
    qb = 2 * np.einsum("ij,ij->i", a, c)
    qc = np.einsum("ij,ij->i", c, c) - 1
    disc = qb * qb - 4 * qa * qc
    root = np.sqrt(np.clip(disc, 0, None))
    s1, s2 = (-qb - root) / (2 * qa), (-qb + root) / (2 * qa)
    return np.where(disc > 0, s1, np.inf), np.where(disc > 0, s2, -np.inf)


def make_city_surface(extent: float, spacing: float, rng: np.random.Generator) -> CitySurface:
    """A random city on a square tile ``extent`` metres wide centred on the local origin, its
    walls, ridges and tree centres on the corners of DEM cells ``spacing`` metres wide (the
    tile's edges are cell corners)."""
    kx, ky = 2 * np.pi / rng.uniform(60, 90, 2)
    ground = Ground(*rng.uniform(-0.03, 0.03, 2), 0.4, kx, ky, *rng.uniform(0, 2 * np.pi, 2))
    half = extent / 2

    def snap(v: float) -> float:  # the nearest cell corner
        return round((v + half) / spacing) * spacing - half

    buildings: list[Building] = []
    wanted = max(1, round(0.3 * extent**2 / 170))  # about 30% covered by 170 m2 buildings
    for _ in range(50 * wanted):
        if len(buildings) == wanted:
            break
        w, d = (2 * max(2, round(rng.uniform(8, 18) / spacing / 2)) * spacing for _ in range(2))
        if max(w, d) > extent - 4:
            continue  # no room on a small tile
        x0 = snap(rng.uniform(-half + 2, half - 2 - w))
        y0 = snap(rng.uniform(-half + 2, half - 2 - d))
        if any(
            x0 < b.x1 + 3 and b.x0 < x0 + w + 3 and y0 < b.y1 + 3 and b.y0 < y0 + d + 3
            for b in buildings
        ):
            continue
        corners = ground.height(
            np.array([x0, x0 + w, x0, x0 + w]), np.array([y0, y0, y0 + d, y0 + d])
        )[0]
        low = corners.min() - ground.max_slope * (w + d)
        eave = corners.max() + rng.uniform(4, 10)
        buildings.append(
            Building(
                x0,
                x0 + w,
                y0,
                y0 + d,
                eave,
                rng.uniform(0.3, 0.8),
                "xy"[int(rng.integers(2))],
                low - 1.0,
                rng.uniform(0.25, 0.75),
                rng.uniform(0.3, 0.7),
            )
        )
    trees: list[Tree] = []
    for _ in range(round(extent**2 / 150)):
        r = rng.uniform(2, 4)
        if 2 * r > extent:
            continue
        x, y = snap(rng.uniform(-half + r, half - r)), snap(rng.uniform(-half + r, half - r))
        if any(
            np.hypot(x - np.clip(x, b.x0, b.x1), y - np.clip(y, b.y0, b.y1)) < r + 1
            for b in buildings
        ):
            continue
        low = ground.height(np.array(x), np.array(y))[0] - ground.max_slope * r - 0.2
        trees.append(Tree(x, y, float(low), r, rng.uniform(5, 10) + (ground.max_slope * r + 0.2)))
    az, el = np.radians(SUN)
    sun = np.array([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)])
    return CitySurface(ground, tuple(buildings), tuple(trees), texture(rng, spacing), sun)


@dataclass(frozen=True, eq=False)
class CityScene:
    """A city scene, complete but not rendered: the ``surface``, the DEM ``terrain`` (map
    frame, :data:`CITY_CRS`, the true heights at its posts), the ``views`` and their
    ``cameras`` (map frame, with image sizes) of ground sample distance ``gsd`` metres at the
    tile centre, the post ``spacing`` in metres, the ``seed`` and the ``facts`` recorded in the
    summary. A :class:`~orthomvp.synthetic.writer.WritableScene`, as
    :class:`~orthomvp.synthetic.scene.Scene` is."""

    kind: str
    surface: CitySurface
    terrain: Terrain
    views: tuple[ViewSpec, ...]
    cameras: dict[str, PinholeCamera]
    spacing: float
    gsd: float
    seed: int
    facts: dict

    def post_local(self) -> tuple[np.ndarray, np.ndarray]:
        """Local (x, y) metres of every DEM post, each (rows, cols)."""
        e, n = self.terrain.pixel_to_crs(*self.terrain.grid())
        return e - ORIGIN[0], n - ORIGIN[1]

    def frame_facts(self) -> dict:
        """The summary's facts about the frame: CRS, world frame, local origin."""
        return {"crs": CITY_CRS, "world": WorldFrame.MAP.value, "origin_map_m": ORIGIN.tolist()}

    def visibility_truth(self, camera: PinholeCamera, step: float | None = None) -> np.ndarray:
        """Truth visibility codes (rows, cols) uint8 of the DEM posts for ``camera``, exact
        (see the module docstring; ``step`` metres, default a quarter post, only for the
        ground's march)."""
        x, y = self.post_local()
        local = np.stack([x, y, self.surface.height(x, y)], axis=-1)
        step = step or self.spacing / 4
        return truth_codes(
            camera,
            local + ORIGIN,
            self.surface.normal(x, y),
            lambda p, s: self.surface.hidden(p - ORIGIN, s - ORIGIN, step),
        )

    def render(self, camera: PinholeCamera, supersample: int = 3) -> np.ndarray:
        """The image (rows, cols) float32 of ``camera``: per pixel the mean radiance of
        ``supersample`` x ``supersample`` rays' exact first hits (walls included)."""
        k = number(
            supersample,
            "supersample (rays per pixel side)",
            minimum=1,
            maximum=MAX_SUPERSAMPLE,
            integer=True,
        )
        w, h = camera.width, camera.height
        offs = (np.arange(k) + 0.5) / k - 0.5
        sub = np.stack(np.meshgrid(offs, offs, indexing="xy"), -1).reshape(-1, 2)
        out = np.empty(h * w)
        rows_per = max(1, 100_000 // (w * k * k))
        for r0 in range(0, h, rows_per):
            rr, cc = np.mgrid[r0 : min(r0 + rows_per, h), 0:w].astype(np.float64)
            uv = np.stack([cc.ravel(), rr.ravel()], axis=-1)
            o, d = camera.ray((uv[:, None, :] + sub).reshape(-1, 2))
            d = d / np.linalg.norm(d, axis=1, keepdims=True)
            val = self.surface.first_hit(o - ORIGIN, d)
            out[r0 * w : r0 * w + len(uv)] = val.reshape(-1, k * k).mean(axis=1)
        return out.reshape(h, w).astype(np.float32)

    def write(self, outdir: str | Path, supersample: int = 3, progress: bool = False) -> dict:
        """Render and write the scene directory; returns the summary written to scene.json
        (see :func:`orthomvp.synthetic.writer.write_scene`)."""
        return write_scene(self, outdir, supersample, progress)


def make_city(
    size: int, spacing: float, gsd_ratio: float, seed: int, margin: float = 6.0
) -> CityScene:
    """A city of ``size`` x ``size`` posts ``spacing`` metres apart centred on :data:`ORIGIN`,
    seen from :data:`VIEW_ANGLES` at :data:`ALTITUDE` with ground sample distance
    ``gsd_ratio`` post spacings, its images ``margin`` pixels beyond the DEM (arguments checked by
    :func:`~orthomvp.synthetic.scene.make_scene`)."""
    rng = np.random.default_rng(seed)
    extent = size * spacing
    surface = make_city_surface(extent, spacing, rng)
    transform = Affine(spacing, 0, ORIGIN[0] - extent / 2, 0, -spacing, ORIGIN[1] + extent / 2)
    grid = Terrain(
        np.zeros((size, size)),
        transform,
        CRS.from_user_input(CITY_CRS),
        world=WorldFrame.MAP,
        name="city",
    )
    e, n = grid.pixel_to_crs(*grid.grid())
    terrain = grid.with_values(surface.height(e - ORIGIN[0], n - ORIGIN[1]))
    gsd = gsd_ratio * spacing
    views = tuple(ViewSpec(name, em, az, ALTITUDE * extent) for name, em, az in VIEW_ANGLES)
    cameras = {view.name: orbital_camera(terrain, view, gsd, margin) for view in views}
    facts = {
        "buildings": len(surface.buildings),
        "trees": len(surface.trees),
        "tallest_m": float(np.max(terrain.values) - np.min(terrain.values)),
    }
    return CityScene("city", surface, terrain, views, cameras, spacing, gsd, seed, facts)
