"""A synthetic lunar scene with exact truth: an analytic surface, its DEM and orbital cameras.

Heights and albedo are analytic (:mod:`orthomvp.synthetic.kinds`); the DEM holds the true
heights at its posts; images are rendered on demand; visibility truth is marched against the
analytic surface (:mod:`orthomvp.synthetic.truth`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from affine import Affine
from pyproj import CRS

from orthomvp.camera import Camera
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.preflight import check_memory, count_text
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.synthetic.cameras import VIEWS, ViewSpec, orbital_camera
from orthomvp.synthetic.city import CityScene, make_city
from orthomvp.synthetic.kinds import DEFAULTS, KINDS, relief, texture
from orthomvp.synthetic.linescan import VIEWS as LINESCAN_VIEWS
from orthomvp.synthetic.linescan import orbital_line_scanner
from orthomvp.synthetic.rendering import fine_terrain, render_image
from orthomvp.synthetic.surface import MOON_CRS, MOON_RADIUS, LocalSurface, local_frame
from orthomvp.synthetic.truth import visibility_truth
from orthomvp.synthetic.writer import write_scene
from orthomvp.validate import number

SPACING_RANGE = (0.01, 10_000.0)
"""Post spacings a scene may have, metres: finer ones lose the analytic surface in float64
rounding at lunar radius (and the truth marcher's steps with it), coarser ones wrap the tile
around the Moon."""
GSD_RATIO_RANGE = (0.05, 20.0)
"""Image ground sample distance over post spacing that a scene may have."""
SCENE_BYTES_PER_POST = 20_000
"""Peak memory of making and writing a scene per DEM post (the finer rendering surface, its
mesh and ray caster, the truth marcher; about 17,000 measured), bytes."""
IMAGE_BYTES_PER_PIXEL = 100
"""Memory of the rendered images per pixel (4 views), bytes."""
SENSORS = ("frame", "linescan")
"""The sensors a scene's views may have."""
SUN_ELEVATION = 40.0
"""Sun elevation above the horizon at the tile centre, degrees."""
SUN_AZIMUTH = 120.0
"""Sun azimuth at the tile centre, degrees clockwise from north."""


@dataclass(frozen=True, eq=False)
class Scene:
    """An analytic scene of ``kind``, complete but not rendered: the ``surface``, the DEM
    ``terrain`` (geographic, heights above the sphere: the true heights at its posts), the
    ``views`` and their ``cameras`` (by view name, with image sizes) of ground sample distance
    ``gsd`` metres, the DEM's post ``spacing`` in metres, the ``seed``, and the ``facts`` of
    the kind that the summary records (crater radius, plane normal, ...), and the ``sensor`` of
    its views (:data:`SENSORS`)."""

    kind: str
    surface: LocalSurface
    terrain: Terrain
    views: tuple[ViewSpec, ...]
    cameras: dict[str, Camera]
    spacing: float
    gsd: float
    seed: int
    facts: dict
    sensor: str = "frame"

    def post_local(self) -> tuple[np.ndarray, np.ndarray]:
        """Local (x, y) metres of every DEM post, each (rows, cols)."""
        return self.surface.lonlat_to_local(*self.terrain.pixel_to_lonlat(*self.terrain.grid()))

    @cached_property
    def fine(self) -> Terrain:
        """The surface sampled finer and wider than the DEM, which the images are rendered on."""
        return fine_terrain(self.surface, self.terrain)

    @cached_property
    def max_radius(self) -> float:
        """Metres from the body centre beyond which no surface point lies: 1 m above the
        highest point of :attr:`fine`."""
        return MOON_RADIUS + float(np.max(self.fine.values)) + 1.0

    @cached_property
    def _caster(self) -> RayCaster:
        return RayCaster(terrain_mesh(self.fine))

    def frame_facts(self) -> dict:
        """The summary's facts about the frame: body radius, CRS, tile centre."""
        return {
            "body_radius_m": MOON_RADIUS,
            "crs": MOON_CRS,
            "centre_lonlat_deg": [np.degrees(self.surface.lon0), np.degrees(self.surface.lat0)],
        }

    def visibility_truth(self, camera: Camera, step: float | None = None) -> np.ndarray:
        """Truth visibility codes (rows, cols) uint8 of the DEM posts for ``camera``, marched
        against the analytic surface every ``step`` metres (default a quarter of the post
        spacing); see :func:`orthomvp.synthetic.truth.visibility_truth`."""
        x, y = self.post_local()
        return visibility_truth(
            camera,
            self.surface.surface_point(x, y),
            self.surface.surface_normal(x, y),
            self.surface.below,
            self.max_radius,
            step or min(self.terrain.post_spacing()) / 4,
        )

    def render(self, camera: Camera, supersample: int = 3) -> np.ndarray:
        """One image (rows, cols) float32 of ``camera``: see
        :func:`orthomvp.synthetic.rendering.render_image`."""
        return render_image(self.surface, self._caster, camera, supersample)

    def write(self, outdir: str | Path, supersample: int = 3, progress: bool = False) -> dict:
        """Render and write the scene directory; returns the summary written to scene.json
        (see :func:`orthomvp.synthetic.writer.write_scene`)."""
        return write_scene(self, outdir, supersample, progress)


def make_scene(
    kind: str,
    size: int | None = None,
    spacing: float | None = None,
    gsd_ratio: float | None = None,
    seed: int = 0,
    lonlat_deg: tuple[float, float] = (3.6, 26.1),
    *,
    sensor: str = "frame",
    image_margin: float = 6.0,
) -> Scene | CityScene:
    """An analytic scene of ``kind`` (one of :data:`~orthomvp.synthetic.kinds.KINDS`) with
    ``size`` x ``size`` posts ``spacing`` metres apart (defaults per kind), centred on
    ``lonlat_deg`` (degrees), and cameras whose ground sample distance is ``gsd_ratio`` post
    spacings (default per kind). The same arguments give the same scene. ``sensor``:
    ``frame`` (the kind's pinhole views) or ``linescan`` (the line scanners of
    :data:`orthomvp.synthetic.linescan.VIEWS`; lunar kinds only). ``city`` is a
    :class:`~orthomvp.synthetic.city.CityScene` in its own projected CRS (``lonlat_deg`` does
    not apply). ``image_margin``: pixels of each image beyond the DEM's projection on every
    side (room for a fit's window at the outermost posts).

    Ranges (InputError outside them, and for a scene too large for the memory): ``size`` an
    integer >= 8, ``spacing`` :data:`SPACING_RANGE` metres, ``gsd_ratio``
    :data:`GSD_RATIO_RANGE`, ``seed`` an integer >= 0; None takes the kind's default."""
    if kind not in KINDS:
        raise InputError(f"unknown scene kind {kind!r}; choose one of {', '.join(KINDS)}")
    if sensor not in SENSORS:
        raise InputError(f"unknown sensor {sensor!r}; choose one of {', '.join(SENSORS)}")
    d_size, d_spacing, d_ratio = DEFAULTS[kind]
    size = d_size if size is None else number(size, "scene size (posts)", minimum=8, integer=True)
    lo, hi = SPACING_RANGE
    spacing = (
        d_spacing
        if spacing is None
        else number(spacing, "post spacing (metres)", minimum=lo, maximum=hi)
    )
    lo, hi = GSD_RATIO_RANGE
    gsd_ratio = (
        d_ratio if gsd_ratio is None else number(gsd_ratio, "GSD ratio", minimum=lo, maximum=hi)
    )
    seed = number(seed, "seed", minimum=0, integer=True)
    margin = number(image_margin, "image margin (pixels)", minimum=0)
    check_scene_memory(size, gsd_ratio)
    if kind == "city":
        if sensor != "frame":
            raise InputError("the city scene has frame cameras only (--sensor frame)")
        return make_city(size, spacing, gsd_ratio, seed, margin)
    rng = np.random.default_rng(seed)
    lon0, lat0 = np.radians(lonlat_deg[0]), np.radians(lonlat_deg[1])
    height, facts = relief(kind, size * spacing, lon0, lat0, rng)
    surface = LocalSurface(lon0, lat0, height, texture(rng, spacing), sun_direction(lon0, lat0))
    # the DEM grid: geographic, centred on (lon0, lat0), posts `spacing` metres apart
    dlon = np.degrees(spacing / (MOON_RADIUS * np.cos(lat0)))
    dlat = np.degrees(spacing / MOON_RADIUS)
    transform = Affine(
        dlon, 0, lonlat_deg[0] - dlon * size / 2, 0, -dlat, lonlat_deg[1] + dlat * size / 2
    )
    grid = Terrain(np.zeros((size, size)), transform, CRS.from_proj4(MOON_CRS), name=kind)
    x, y = surface.lonlat_to_local(*grid.pixel_to_lonlat(*grid.grid()))
    terrain = grid.with_values(height(x, y))
    gsd = gsd_ratio * spacing
    if sensor == "linescan":
        views = LINESCAN_VIEWS
        cameras = {v.name: orbital_line_scanner(terrain, v, gsd, margin) for v in views}
    else:
        views = VIEWS[kind]
        cameras = {view.name: orbital_camera(terrain, view, gsd, margin) for view in views}
    return Scene(kind, surface, terrain, views, cameras, spacing, gsd, seed, facts, sensor)


def sun_direction(lon0: float, lat0: float) -> np.ndarray:
    """Body-fixed unit vector towards the sun from the tile centre ``lon0``, ``lat0``
    (radians), at :data:`SUN_ELEVATION` and :data:`SUN_AZIMUTH`."""
    up, east, north = local_frame(lon0, lat0)
    el, az = np.radians(SUN_ELEVATION), np.radians(SUN_AZIMUTH)
    return np.cos(el) * (np.sin(az) * east + np.cos(az) * north) + np.sin(el) * up


def check_scene_memory(size: int, gsd_ratio: float, advice: str = "choose a smaller size") -> None:
    """InputError, before any work, when a scene of ``size`` x ``size`` posts with images of
    ``gsd_ratio`` cannot fit in memory."""
    posts = float(size) * size
    check_memory(
        f"this scene is {count_text(posts)} posts ({size:,} x {size:,})",
        posts * (SCENE_BYTES_PER_POST + IMAGE_BYTES_PER_PIXEL / gsd_ratio**2),
        advice,
    )
