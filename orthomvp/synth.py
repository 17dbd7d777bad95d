"""Synthetic scenes with exact ground truth: ``planar``, ``crater`` and ``hills``.

A scene is a tile on the Moon (sphere, R = 1737400 m) whose heights and albedo are analytic
functions of local coordinates ``(x, y)`` in metres (east, north of the tile centre, along the
equirectangular grid: ``x = R cos(lat0) (lon - lon0)``, ``y = R (lat - lat0)``). Images are
rendered by ray casting a mesh three times finer than the DEM, supersampled, with Lambertian
shading under a fixed sun. Visibility truth comes from marching each post's segment towards the
camera against the *analytic* surface, never from the mesh used elsewhere.

Written scene directory: ``dem.tif`` (heights above the sphere, the analytic truth at the posts),
``truth_radiance.tif``, for each camera ``NAME.tif`` (float32 image), ``NAME.tsai`` and
``NAME.visibility.tif`` (uint8 truth codes, see :data:`VIS_CODES`), and ``scene.json``.

:class:`SmallBody` is an analytic irregular small body (an asteroid-like shape model), with
its mesh, its DEM of radii on a lon/lat grid, and visibility truth marched against its radius.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import trimesh
from affine import Affine
from pyproj import CRS
from tqdm import tqdm

from orthomvp.camera import PinholeCamera, write_tsai
from orthomvp.errors import InputError
from orthomvp.mesh import terrain_mesh
from orthomvp.raster import atomic_path, write_geotiff
from orthomvp.raycast import RayCaster
from orthomvp.terrain import Terrain, unit_vector

MOON_RADIUS = 1737400.0
MOON_CRS = "+proj=longlat +R=1737400 +no_defs"
KINDS = ("planar", "crater", "hills")
VIS_CODES = {0: "no data / outside the image", 1: "visible", 2: "occluded", 3: "facing away"}
ALTITUDE = 110_000.0


@dataclass(frozen=True)
class ViewSpec:
    """A camera placement: emission angle from the vertical at the tile centre, azimuth of the
    camera as seen from the ground (degrees clockwise from north), and altitude in metres."""

    name: str
    emission: float
    azimuth: float
    altitude: float = ALTITUDE


@dataclass
class Scene:
    """An analytic scene: surface, albedo, geometry and cameras (not yet rendered)."""

    kind: str
    terrain: Terrain
    height: Callable[[np.ndarray, np.ndarray], np.ndarray]
    albedo: Callable[[np.ndarray, np.ndarray], np.ndarray]
    lon0: float
    lat0: float
    sun: np.ndarray
    cameras: dict[str, PinholeCamera]
    info: dict = field(default_factory=dict)
    _caster: RayCaster | None = None

    # ------------------------------------------------------------------ local coordinates
    def lonlat_to_local(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lon, lat) radians to local (x, y) metres."""
        dlon = (lon - self.lon0 + np.pi) % (2 * np.pi) - np.pi
        return MOON_RADIUS * np.cos(self.lat0) * dlon, MOON_RADIUS * (lat - self.lat0)

    def local_to_lonlat(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local (x, y) metres to (lon, lat) radians."""
        return self.lon0 + x / (MOON_RADIUS * np.cos(self.lat0)), self.lat0 + y / MOON_RADIUS

    def surface_point(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Body-fixed xyz (..., 3) of the analytic surface above local (x, y)."""
        lon, lat = self.local_to_lonlat(x, y)
        return (MOON_RADIUS + self.height(x, y))[..., None] * unit_vector(lon, lat)

    def surface_normal(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Unit outward normal (..., 3) of the analytic surface (central differences, 1 cm)."""
        e = 0.01
        dx = self.surface_point(x + e, y) - self.surface_point(x - e, y)
        dy = self.surface_point(x, y + e) - self.surface_point(x, y - e)
        n = np.cross(dx, dy)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def world_to_local(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body-fixed xyz to local (x, y) and height above the sphere."""
        rho = np.linalg.norm(xyz, axis=-1)
        lon = np.arctan2(xyz[..., 1], xyz[..., 0])
        lat = np.arcsin(np.clip(xyz[..., 2] / rho, -1, 1))
        x, y = self.lonlat_to_local(lon, lat)
        return x, y, rho - MOON_RADIUS

    def radiance(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Lambertian radiance at local (x, y): albedo * (0.25 + 0.75 max(0, n . sun))."""
        n = self.surface_normal(x, y)
        return self.albedo(x, y) * (0.25 + 0.75 * np.clip(n @ self.sun, 0, None))

    def post_local(self) -> tuple[np.ndarray, np.ndarray]:
        """Local (x, y) of every DEM post."""
        c, r = self.terrain.grid()
        lon, lat = self.terrain.pixel_to_lonlat(c, r)
        return self.lonlat_to_local(lon, lat)

    # ------------------------------------------------------------------------- the truth
    def visibility_truth(self, camera: PinholeCamera, step: float | None = None) -> np.ndarray:
        """Truth visibility codes (rows, cols) uint8 for one camera, by marching against the
        analytic surface: 0 outside the image, 3 facing away, 2 occluded, 1 visible.

        Each post's segment to the camera is sampled every ``step`` metres (default a quarter
        of the post spacing) until it rises above the highest point of the terrain.
        """
        x, y = self.post_local()
        p = self.surface_point(x, y)
        uv, depth = camera.project(p)
        w, h = camera.width, camera.height
        inside = (
            (depth > 0)
            & (uv[..., 0] >= -0.5)
            & (uv[..., 0] <= w - 0.5)
            & (uv[..., 1] >= -0.5)
            & (uv[..., 1] <= h - 0.5)
        )
        to_cam = camera.center - p
        facing = np.einsum("...i,...i->...", self.surface_normal(x, y), to_cam) > 0
        step = step or min(self.terrain.post_spacing()) / 4
        occluded = self._march(p, camera.center, step)
        codes = np.where(occluded, 2, 1).astype(np.uint8)
        codes[~facing] = 3
        codes[~inside] = 0
        return codes

    def _march(self, p: np.ndarray, centre: np.ndarray, step: float) -> np.ndarray:
        """True where the segment from surface point p to ``centre`` dips below the surface."""
        shape = p.shape[:-1]
        p = p.reshape(-1, 3)
        seg = centre - p
        length = np.linalg.norm(seg, axis=1)
        unit = seg / length[:, None]
        up = p / np.linalg.norm(p, axis=1, keepdims=True)
        sin_el = np.einsum("ij,ij->i", unit, up)
        _, _, h0 = self.world_to_local(p)
        top = float(self.info["max_height"]) + 1.0
        # distance along the segment after which it is above every terrain point
        reach = np.where(sin_el > 1e-3, (top - h0) / np.maximum(sin_el, 1e-3), length)
        reach = np.minimum(np.maximum(reach, 0), length)
        occluded = np.zeros(len(p), bool)
        s = step / 2
        active = np.flatnonzero(reach > s)
        while active.size:
            q = p[active] + s * unit[active]
            qx, qy, qh = self.world_to_local(q)
            below = qh < self.height(qx, qy) - 1e-6
            occluded[active[below]] = True
            keep = ~below & (reach[active] > s + step)
            active = active[keep]
            s += step
        return occluded.reshape(shape)

    # -------------------------------------------------------------------------- rendering
    def render(self, camera: PinholeCamera, supersample: int = 3) -> np.ndarray:
        """Render one image (rows, cols) float32 by ray casting a 3x finer mesh of the surface."""
        if self._caster is None:
            self._caster = RayCaster(terrain_mesh(self._fine))
        caster = self._caster
        w, h = camera.width, camera.height
        k = supersample
        offs = (np.arange(k) + 0.5) / k - 0.5
        out = np.zeros(h * w, np.float64)
        rows_per = max(1, 200_000 // (w * k * k))
        for r0 in range(0, h, rows_per):
            rr, cc = np.mgrid[r0 : min(r0 + rows_per, h), 0:w].astype(np.float64)
            uv = np.stack([cc.ravel(), rr.ravel()], axis=-1)
            sub = uv[:, None, None, :] + np.stack(np.meshgrid(offs, offs, indexing="xy"), -1)
            o, d = camera.ray(sub.reshape(-1, 2))
            hits = caster.first_hit(o, d)
            val = np.zeros(len(d))
            if hits.mask.any():
                hx, hy, _ = self.world_to_local(hits.points[hits.mask])
                val[hits.mask] = self.radiance(hx, hy)
            out[r0 * w : r0 * w + uv.shape[0]] = val.reshape(-1, k * k).mean(axis=1)
        return out.reshape(h, w).astype(np.float32)

    @cached_property
    def _fine(self) -> Terrain:
        """The surface sampled 3 times finer than the DEM, 60% of its size wider each side."""
        factor, margin = 3, 0.6
        t = self.terrain
        rows, cols = t.shape
        n_r, n_c = int(rows * (1 + 2 * margin) * factor), int(cols * (1 + 2 * margin) * factor)
        tr = t.transform
        corner_x, corner_y = tr.c - margin * cols * tr.a, tr.f - margin * rows * tr.e
        fine = Affine(tr.a / factor, 0, corner_x, 0, tr.e / factor, corner_y)
        ft = Terrain(np.zeros((n_r, n_c)), fine, t.crs)
        x, y = self.lonlat_to_local(*ft.pixel_to_lonlat(*ft.grid()))
        return ft.with_values(self.height(x, y))

    # ---------------------------------------------------------------------------- writing
    def write(self, outdir: str | Path, supersample: int = 3, progress: bool = False) -> dict:
        """Render and write the scene directory; returns the summary written to scene.json."""
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        t = self.terrain
        t.write(outdir / "dem.tif")
        x, y = self.post_local()
        write_geotiff(
            outdir / "truth_radiance.tif",
            self.radiance(x, y).astype(np.float32),
            t.transform,
            t.crs,
            nodata=np.nan,
        )
        views = {}
        bar = tqdm(
            self.cameras.items(),
            desc=f"rendering {self.kind}",
            unit="view",
            disable=not progress or None,
        )
        for name, cam in bar:
            image = self.render(cam, supersample)
            write_geotiff(outdir / f"{name}.tif", image, Affine.identity(), None)
            write_tsai(cam, outdir / f"{name}.tsai")
            vis = self.visibility_truth(cam)
            write_geotiff(outdir / f"{name}.visibility.tif", vis, t.transform, t.crs, nodata=None)
            counts = {VIS_CODES[k]: int((vis == k).sum()) for k in VIS_CODES}
            views[name] = {
                "image": f"{name}.tif",
                "camera": f"{name}.tsai",
                "visibility": f"{name}.visibility.tif",
                "emission_deg": self.info["emission"][name],
                "gsd_m": self.info["gsd"][name],
                "visibility_counts": counts,
            }
        summary = {
            "kind": self.kind,
            "body_radius_m": MOON_RADIUS,
            "crs": MOON_CRS,
            "dem": "dem.tif",
            "truth_heights": "dem.tif",
            "truth_radiance": "truth_radiance.tif",
            "size": list(t.shape),
            "post_spacing_m": self.info["spacing"],
            "centre_lonlat_deg": [np.degrees(self.lon0), np.degrees(self.lat0)],
            "sun": self.sun.tolist(),
            "seed": self.info["seed"],
            "views": views,
            **self.info.get("extra", {}),
        }
        with atomic_path(outdir / "scene.json") as tmp:
            tmp.write_text(json.dumps(summary, indent=2))
        return summary


# ------------------------------------------------------------------------------ building
def _texture(rng: np.random.Generator, spacing: float) -> Callable:
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


def _crater(extent: float, rng: np.random.Generator) -> tuple[Callable, dict]:
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


def _hills(extent: float, rng: np.random.Generator) -> tuple[Callable, dict]:
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


def _plane(lon0: float, lat0: float, rng: np.random.Generator) -> tuple[Callable, dict]:
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


VIEWS = {
    "planar": [
        ViewSpec("orbit1", 14.0, 180.0),
        ViewSpec("orbit2", 5.0, 180.0),
        ViewSpec("orbit3", 5.0, 0.0),
        ViewSpec("orbit4", 14.0, 0.0),
    ],
    "crater": [
        ViewSpec("oblique", 55.0, 200.0),
        ViewSpec("nadir", 3.0, 90.0),
        ViewSpec("fore", 18.0, 0.0),
        ViewSpec("aft", 18.0, 180.0),
    ],
    "hills": [
        ViewSpec("fore2", 22.0, 0.0),
        ViewSpec("fore1", 8.0, 0.0),
        ViewSpec("aft1", 8.0, 180.0),
        ViewSpec("aft2", 22.0, 180.0),
    ],
}
DEFAULTS = {"planar": (64, 40.0), "crater": (160, 40.0), "hills": (128, 30.0)}


def local_frame(lon: float, lat: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body-fixed unit vectors (up, east, north) at planetocentric ``lon``, ``lat`` (radians)."""
    up = unit_vector(np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64))
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    return up, east, np.cross(up, east)


def look_at(centre: np.ndarray, target: np.ndarray, north: np.ndarray) -> np.ndarray:
    """Camera-to-world rotation looking from ``centre`` at ``target`` with image rows running
    roughly southward (columns eastward for a nadir view): columns of R are the camera x (right),
    y (down) and z (forward) axes."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(-north, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def make_scene(
    kind: str,
    size: int | None = None,
    spacing: float | None = None,
    gsd_ratio: float = 0.8,
    seed: int = 0,
    lonlat_deg: tuple[float, float] = (3.6, 26.1),
) -> Scene:
    """Build an analytic scene of ``kind`` with ``size`` x ``size`` posts ``spacing`` metres
    apart, and cameras whose ground sample distance is ``gsd_ratio`` post spacings."""
    if kind not in KINDS:
        raise InputError(f"unknown scene kind {kind!r}; choose one of {', '.join(KINDS)}")
    d_size, d_spacing = DEFAULTS[kind]
    size = size or d_size
    spacing = spacing or d_spacing
    if size < 8 or spacing <= 0 or gsd_ratio <= 0:
        raise InputError("scene size must be >= 8 posts, spacing and GSD ratio positive")
    rng = np.random.default_rng(seed)
    lon0, lat0 = np.radians(lonlat_deg[0]), np.radians(lonlat_deg[1])
    extent = size * spacing
    if kind == "crater":
        height, extra = _crater(extent, rng)
    elif kind == "hills":
        height, extra = _hills(extent, rng)
    else:
        height, extra = _plane(lon0, lat0, rng)
    albedo = _texture(rng, spacing)
    # The DEM grid: geographic, centred on (lon0, lat0), posts `spacing` metres apart.
    dlon = np.degrees(spacing / (MOON_RADIUS * np.cos(lat0)))
    dlat = np.degrees(spacing / MOON_RADIUS)
    transform = Affine(
        dlon, 0, lonlat_deg[0] - dlon * size / 2, 0, -dlat, lonlat_deg[1] + dlat * size / 2
    )
    grid = Terrain(np.zeros((size, size)), transform, CRS.from_proj4(MOON_CRS), name=kind)
    e0, east, north = local_frame(lon0, lat0)
    sun_el, sun_az = np.radians(40.0), np.radians(120.0)
    sun = np.cos(sun_el) * (np.sin(sun_az) * east + np.cos(sun_az) * north) + np.sin(sun_el) * e0
    scene = Scene(kind, grid, height, albedo, lon0, lat0, sun, {})
    terrain = scene.terrain = grid.with_values(height(*scene.post_local()))
    scene.info.update(
        spacing=spacing,
        seed=seed,
        max_height=float(np.max(scene._fine.values)),
        emission={},
        gsd={},
        extra=extra,
    )
    gsd = gsd_ratio * spacing
    for view in VIEWS[kind]:
        scene.cameras[view.name] = orbital_camera(terrain, view, gsd)
        scene.info["emission"][view.name] = view.emission
        scene.info["gsd"][view.name] = gsd
    return scene


def orbital_camera(
    terrain: Terrain, view: ViewSpec, gsd: float, margin: float = 6.0
) -> PinholeCamera:
    """A pinhole camera placed as ``view`` says over the centre of a body-frame ``terrain``,
    looking at that centre (at the median height), with ground sample distance ``gsd`` metres
    there and an image just large enough (plus ``margin`` pixels) to hold the whole DEM."""
    rows, cols = terrain.shape
    up, east, north = local_frame(
        *terrain.pixel_to_lonlat(np.array((cols - 1) / 2), np.array((rows - 1) / 2))
    )
    heights = terrain.values[terrain.valid]
    target = (terrain.radii[0] + float(np.median(heights))) * up
    corners = terrain.to_world(
        np.array([0, cols - 1, 0, cols - 1] * 2, float),
        np.array([0, 0, rows - 1, rows - 1] * 2, float),
        np.repeat([heights.min(), heights.max()], 4),
    )
    em, az = np.radians(view.emission), np.radians(view.azimuth)
    horiz = np.sin(az) * east + np.cos(az) * north
    # `altitude` above the target, seen from the target at emission angle `em`
    dist = view.altitude / np.cos(em)
    centre = target + dist * (np.sin(em) * horiz + np.cos(em) * up)
    rot = look_at(centre, target, north)
    f = dist / gsd
    uv, _ = PinholeCamera(f, f, 0.0, 0.0, centre, rot).project(corners)
    lo, hi = uv.min(axis=0) - margin, uv.max(axis=0) + margin
    width, height = (int(np.ceil(v)) for v in hi - lo)
    return PinholeCamera(f, f, -lo[0], -lo[1], centre, rot, width=width, height=height)


# ------------------------------------------------------------------------------ small body
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

    def visibility_truth(
        self, terrain: Terrain, camera: PinholeCamera, step: float | None = None
    ) -> np.ndarray:
        """Truth visibility codes (rows, cols) uint8 of the posts of a lon/lat ``terrain`` grid
        (placed on the analytic surface) for ``camera``: 0 outside the image, 3 facing away
        (analytic normal), 2 occluded, 1 visible. Each post's segment to the camera is sampled
        every ``step`` metres (default a quarter of the post spacing) against the analytic
        radius, until it leaves the sphere of :attr:`max_radius`."""
        p = self.surface_point(*terrain.pixel_to_lonlat(*terrain.grid()))
        uv, depth = camera.project(p)
        inside = (
            (depth > 0)
            & (uv[..., 0] >= -0.5)
            & (uv[..., 0] <= camera.width - 0.5)
            & (uv[..., 1] >= -0.5)
            & (uv[..., 1] <= camera.height - 0.5)
        )
        lon, lat = terrain.pixel_to_lonlat(*terrain.grid())
        facing = np.einsum("...i,...i->...", self.surface_normal(lon, lat), camera.center - p) > 0
        step = step or min(terrain.post_spacing()) / 4
        codes = np.zeros(terrain.shape, np.uint8)
        cast = inside & facing
        codes[cast] = np.where(self._march(p[cast], camera.center, step), 2, 1)
        codes[inside & ~facing] = 3
        return codes

    def _march(self, p: np.ndarray, centre: np.ndarray, step: float) -> np.ndarray:
        """True where the segment from surface point p (n, 3) to ``centre`` dips below the
        surface (a sample closer to the body centre than the radius in its direction)."""
        seg = centre - p
        length = np.linalg.norm(seg, axis=1)
        unit = seg / length[:, None]
        # distance along the segment at which it leaves the sphere of max_radius for good
        b = np.einsum("ij,ij->i", p, unit)
        leave = -b + np.sqrt(
            np.maximum(b * b - np.einsum("ij,ij->i", p, p) + self.max_radius**2, 0)
        )
        reach = np.minimum(leave, length)
        occluded = np.zeros(len(p), bool)
        s = step / 2
        active = np.flatnonzero(reach > s)
        while active.size:
            q = p[active] + s * unit[active]
            rho = np.linalg.norm(q, axis=1)
            below = rho < self.radius_along(q / rho[:, None]) - 1e-6
            occluded[active[below]] = True
            active = active[~below & (reach[active] > s + step)]
            s += step
        return occluded


def small_body(seed: int = 0, subdivisions: int = 5) -> trimesh.Trimesh:
    """The mesh of :meth:`SmallBody.from_seed` (``seed``): see :meth:`SmallBody.mesh`."""
    return SmallBody.from_seed(seed).mesh(subdivisions)
