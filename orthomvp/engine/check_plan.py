"""Planning the truth-free check (:mod:`orthomvp.quality.check`) through the engine: tiles of the
DEM's own grid, each of which computes every view's visibility and naive samples on its posts plus
``window // 2`` posts around them (the NCC box's reach), with the occluder halo of that grown
window, so that its NCC values are the whole grid's (see :mod:`orthomvp.engine.ncc`).

Only tiles that two views or more may see are run: a tile seen by one view holds no pair.
The check works on the DEM's grid because its windows and miss distances are in DEM posts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

from orthomvp.camera import Camera
from orthomvp.codes import WorldFrame
from orthomvp.engine.arguments import dem_path, dem_reading, view_pairs
from orthomvp.engine.images import ImageSource, image_source
from orthomvp.engine.plan import SAMPLE_BUDGET_PIXELS, Plan, TileJob, tile_grid
from orthomvp.engine.tiling import (
    MESH_BYTES,
    TILE_BYTES,
    VIEW_BYTES,
    WINDOW_BYTES,
    check_tile,
    largest_dem_window,
    peak_bytes,
)
from orthomvp.errors import InputError
from orthomvp.geometry.datum import HeightOptions
from orthomvp.occlusion.paths import Rays, VisibilityPath
from orthomvp.validate import number

DEFAULT_EPS = (1.0, 2.0, 4.0, 8.0)
"""Epsilons checked by default, DEM posts."""

# Bytes of memory per post of a tile grown by the NCC margin, beyond those of an orthophoto
# tile (plan.py), rounded up from the peak resident set size of runs of the scale scene
# (orthomvp.engine.scale, 2048 x 2048 posts, tiles of 1024, one thread): 70 B per post more
# than the orthophoto of the same tiles with 2 views, and 21 B per post for each further view.
# Per view: the codes, miss distances and naive values kept across the epsilons, and each
# epsilon's codes and orthophoto; the NCC maps of one pair with their box sums.
CHECK_VIEW_BYTES = 25
NCC_BYTES = 120


@dataclass(frozen=True)
class CheckPlan:
    """Everything a worker needs to check tiles: ``base``, the plan of the DEM grid, views and
    tiles (each tile's views and DEM window cover the tile grown by :attr:`margin`); the
    ``eps_values`` (DEM posts) and NCC ``window`` (posts, odd) to check, and the views'
    ``names``."""

    base: Plan
    eps_values: tuple[float, ...]
    window: int
    names: tuple[str, ...]

    @property
    def progress(self) -> bool:
        """Whether a run reports progress unless told otherwise (the planner's)."""
        return self.base.progress

    @property
    def tiles(self) -> tuple[TileJob, ...]:
        return self.base.tiles

    @property
    def tile(self) -> int:
        return self.base.tile

    @property
    def views(self) -> tuple[ImageSource, ...]:
        return self.base.views

    @property
    def margin(self) -> int:
        """Posts computed around every tile: the NCC box's reach."""
        return self.window // 2

    @cached_property
    def visibility_path(self) -> VisibilityPath:
        """The way of every tile's visibility test: the base plan's, with every ray cast on the
        whole occluder mesh (the check measures every miss)."""
        return replace(self.base.visibility_path, rays=Rays.WHOLE_MESH)

    def tile_bytes(self, job: TileJob) -> int:
        """Expected peak memory of one tile in a worker, bytes (the constants above and
        those of :mod:`orthomvp.engine.plan`)."""
        r0, r1, c0, c1 = job.window
        ext = (r1 - r0 + 2 + 2 * self.margin) * (c1 - c0 + 2 + 2 * self.margin)
        pixels = max((min(p, SAMPLE_BUDGET_PIXELS) for p in job.image_pixels), default=0)
        bands = max((self.views[k].bands for k in job.views), default=0)
        views = (VIEW_BYTES + CHECK_VIEW_BYTES) * ext * len(job.views)
        return (
            (WINDOW_BYTES + MESH_BYTES) * job.dem_posts
            + (TILE_BYTES + NCC_BYTES) * ext
            + views
            + 8 * bands * pixels
        )

    def peak_memory(self, workers: int, processes: int = 0) -> int:
        """Expected peak memory of a run with ``workers`` tiles at a time and ``processes``
        worker processes besides this one, bytes."""
        return peak_bytes((self.tile_bytes(job) for job in self.tiles), workers, processes)

    def summary(self, peak: int, workers: int) -> str:
        """One line: grid, tiles, images, epsilons, the NCC margin, the occluder halo, the
        largest DEM window and the expected ``peak`` memory (bytes) with ``workers`` tiles."""
        rows, cols = self.base.grid.shape
        run = [job for job in self.tiles if job.views]
        window = largest_dem_window(run)
        return (
            f"orthomvp: plan: check {cols:,} x {rows:,} posts, {len(run)} of {len(self.tiles)} "
            f"tiles of {self.tile} x {self.tile} to run, {len(self.views)} images, "
            f"{len(self.eps_values)} epsilon(s), {self.window} x {self.window} NCC windows "
            f"({self.margin} posts around each tile), occluder halo up to "
            f"{max(self.base.reach, default=0.0):.0f} DEM posts{window}; expected peak memory "
            f"{peak / 2**30:.2f} GiB with {workers} tile(s) at a time"
        )


def check_options(
    views: int, eps_values: Sequence[float], window: int, names: Sequence[str] | None
) -> tuple[tuple[float, ...], int, tuple[str, ...]]:
    """The check's options for ``views`` views, checked: the epsilons (DEM posts, > 0, at
    least one), the odd ``window`` (3..51 posts) and the views' ``names`` (default 1, 2, ...,
    one per view); InputError otherwise."""
    if views < 2:
        raise InputError("the check needs a list of at least two (image, camera) views")
    if isinstance(eps_values, str) or not isinstance(eps_values, Sequence):
        raise InputError(f"eps_values must be a list of numbers, got {eps_values!r:.40}")
    eps = tuple(number(e, "an epsilon (DEM posts)", minimum=0, min_open=True) for e in eps_values)
    if not eps:
        raise InputError("the check needs at least one epsilon")
    window = number(window, "window (posts)", minimum=3, maximum=51, integer=True)
    if window % 2 == 0:
        raise InputError(f"window (posts) must be odd, got {window}")
    if names is not None and (isinstance(names, str) or not isinstance(names, Sequence)):
        raise InputError(f"names must be a list of strings, one per view, got {names!r:.40}")
    labels = tuple(str(k) for k in range(1, views + 1)) if names is None else tuple(names)
    if len(labels) != views:
        raise InputError(f"got {len(labels)} names for {views} views")
    return eps, window, labels


def plan_check(
    dem: str | Path,
    views: Sequence[tuple[str | Path, str | Path | Camera]],
    *,
    eps_values: Sequence[float] = DEFAULT_EPS,
    window: int = 7,
    names: Sequence[str] | None = None,
    tile: int | None = None,
    dem_crs: object | None = None,
    radius_values: bool = False,
    world: WorldFrame | str = "auto",
    progress: bool = True,
    vertical_datum: str = "auto",
    height_offset: float | None = None,
) -> CheckPlan:
    """Plan the truth-free check (:func:`orthomvp.quality.check.check_views`) of ``views`` ((image
    path, camera or camera path) pairs, at least 2, any band counts) on the DEM at path
    ``dem``, in tiles of ``tile`` x ``tile`` posts of the DEM's grid (default
    :func:`~orthomvp.engine.tiling.auto_tile`): every epsilon of
    ``eps_values`` (DEM posts), NCC boxes of ``window`` posts (odd, 3..51), views labelled
    ``names`` (default 1, 2, ...). ``dem_crs``, ``radius_values``, ``world``,
    ``vertical_datum`` and ``height_offset`` as for :func:`~orthomvp.engine.plan_ortho`.

    ``progress``: progress bars (or log lines) and notes on stderr, here and, by default, in
    :func:`~orthomvp.engine.run_check`; False prints nothing.

    Reads the DEM once in blocks and the images' headers. Raises InputError for bad options,
    GeometryError when an image sees none of the DEM; warns
    (:class:`~orthomvp.engine.HaloWarning`) when a camera's occluder halo is larger than the
    DEM.
    """
    dem = dem_path(dem)
    pairs = view_pairs(views, minimum=0)  # check_options says how many it needs
    tile = check_tile(tile)
    dem_reading(
        radius_values=radius_values,
        world=world,
        progress=progress,
        vertical_datum=vertical_datum,
        height_offset=height_offset,
        dem_crs=dem_crs,
    )
    eps, window, labels = check_options(len(pairs), eps_values, window, names)
    sources = tuple(image_source(image, camera) for image, camera in pairs)
    source, sources, grid, jobs, reach, elevation, tile, left_out = tile_grid(
        dem,
        sources,
        tile=tile,
        occlusion=True,
        margin=window // 2,
        dem_crs=dem_crs,
        radius_values=radius_values,
        world=world,
        progress=progress,
        heights=HeightOptions(vertical_datum, height_offset),
    )
    jobs = [
        job if len(job.views) > 1 else replace(job, views=(), dem=None, image_windows=())
        for job in jobs
    ]
    base = Plan(
        source,
        grid,
        sources,
        tuple(jobs),
        tile,
        True,
        None,
        "bilinear",
        source.post_spacing(),
        1.0,
        tuple(reach),
        tuple(elevation),
        progress=progress,
        left_out=left_out,
    )
    return CheckPlan(base, eps, window, labels)
