"""The MVP fit through the engine, run: each tile of a :class:`~orthomvp.engine.fit_plan.FitPlan`
fitted from windows of the DEM and of the images (:func:`run_fit_tile`), and the run that
writes every output (:func:`run_fit`). The windows a tile needs, and their bound, are in
:mod:`orthomvp.engine.fit_plan`.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from rasterio.enums import Resampling

from orthomvp.codes import Code
from orthomvp.engine import heap
from orthomvp.engine.copies import Copies, image_copies
from orthomvp.engine.fit_plan import (
    RETRIES,
    FitJob,
    FitPlan,
    _grow,
)
from orthomvp.engine.grid import GDAL_CACHE, WindowT
from orthomvp.engine.median import Median
from orthomvp.engine.progress import Progress
from orthomvp.engine.run import (
    all_local,
    check_memory,
    check_views,
    executor,
    results,
    schedule,
)
from orthomvp.engine.tile import _has_cell, _timed
from orthomvp.engine.writer import (
    COMPRESSIONS,
    FORMATS,
    Layer,
    check_settings,
    output_files,
    plan_inputs,
)
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.datum import HeightShift
from orthomvp.io.output_checks import (
    API_FLAGS,
    Output,
    check_names,
    check_outputs,
    check_parent,
)
from orthomvp.mvp import fit_dem
from orthomvp.mvp.fit import nothing_fitted
from orthomvp.mvp.views import ViewWindow, covers, exact_masks, union, window_for
from orthomvp.occlusion.visibility import compute_visibility, occluder_caster
from orthomvp.validate import of_type


# ------------------------------------------------------------------------------ per tile
@dataclass
class FitTile:
    """A finished tile of the fit, on its ``window`` of the DEM grid: ``heights`` float32
    (NaN where unresolved), ``normals`` (3, rows, cols) float32 n_theta, n_phi and the tilt
    from the local vertical (degrees), ``cost`` float32, ``views`` uint8, ``uncertainty``
    (2, rows, cols) float32 sigma_h and the converged flag (NaN where unresolved); for the
    summary, ``fitted`` and ``converged`` counts, ``shift`` (heights minus the input) and
    ``sigma`` (the finite sigma_h) of the fitted posts as float64; per view the posts
    ``inside`` the image and those ``seen`` (visible or occluded), and ``twice`` the posts
    visible in 2 or more; ``refits``: times the
    tile was fitted again with grown image windows; ``seconds`` per phase."""

    index: int
    window: WindowT
    heights: np.ndarray
    normals: np.ndarray
    cost: np.ndarray
    views: np.ndarray
    uncertainty: np.ndarray
    fitted: int = 0
    converged: int = 0
    shift: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))
    inside: list[int] = field(default_factory=list)
    seen: list[int] = field(default_factory=list)
    twice: int = 0
    refits: int = 0
    seconds: dict[str, float] = field(default_factory=dict)


def empty_tile(plan: FitPlan, job: FitJob) -> FitTile:
    """The result of a tile with nothing fitted."""
    r0, r1, c0, c1 = job.window
    shape = (r1 - r0, c1 - c0)
    n = len(plan.views)
    return FitTile(
        job.index,
        job.window,
        np.full(shape, np.nan, np.float32),
        np.full((3, *shape), np.nan, np.float32),
        np.full(shape, np.nan, np.float32),
        np.zeros(shape, np.uint8),
        np.full((2, *shape), np.nan, np.float32),
        inside=[0] * n,
        seen=[0] * n,
    )


def run_fit_tile(plan: FitPlan, index: int, threads: int = 1, progress: bool = False) -> FitTile:
    """Fit tile ``index`` of ``plan`` with ``threads`` threads (``progress``: the fitter's
    own bar over its batches), inside :func:`orthomvp.engine.heap.tile_heap` as
    :func:`~orthomvp.engine.tile.run_tile`."""
    with heap.tile_heap(plan.tiles[index].dem_posts):
        return _run_fit_tile(plan, index, threads, progress)


def _sub(window: WindowT, within: WindowT) -> tuple[slice, slice]:
    """Slices of ``window`` in an array of ``within``."""
    r0, r1, c0, c1 = window
    return slice(r0 - within[0], r1 - within[0]), slice(c0 - within[2], c1 - within[2])


def _run_fit_tile(plan: FitPlan, index: int, threads: int, progress: bool) -> FitTile:
    job = plan.tiles[index]
    result = empty_tile(plan, job)
    if job.dem is None or job.fit is None:
        return result
    seconds = result.seconds
    with _timed(seconds, "read"):
        values = plan.dem.read(job.dem)
    ext = _grow(job.fit, 1, plan.grid.shape)
    assert ext is not None
    if not _has_cell(np.isfinite(values)) or not np.isfinite(values[_sub(ext, job.dem)]).any():
        return result
    window = plan.dem.window_terrain(job.dem, values)
    terrain = plan.dem.window_terrain(ext, values[_sub(ext, job.dem)])
    inner, fit = _sub(job.window, ext), _sub(job.fit, ext)
    with _timed(seconds, "mesh"):
        caster = occluder_caster(window, threads=threads)
    visible = np.zeros((len(job.views), *terrain.shape), bool)
    for i, k in enumerate(job.views):
        with _timed(seconds, "visibility"):
            vis = compute_visibility(
                terrain,
                plan.views[k].camera,
                eps=plan.eps,
                caster=caster,
                threads=threads,
                path=plan.visibility_path,
            )
        codes = vis.codes[inner]
        result.inside[k] = int((codes != Code.NODATA).sum())
        result.seen[k] = int(np.isin(codes, (Code.VISIBLE, Code.OCCLUDED)).sum())
        visible[i][fit] = vis.codes[fit] == Code.VISIBLE
        del vis
    del caster, window, values
    twice = visible.sum(axis=0) >= 2
    result.twice = int(twice[inner].sum())
    if not twice.any():
        return result
    images = list(job.images)
    geometry = plan.dem.geometry()
    while True:
        windows = [
            ViewWindow(w, (plan.views[k].width, plan.views[k].height), *plan.stats[k])
            for k, w in zip(job.views, images, strict=True)
        ]
        with _timed(seconds, "read"):
            crops = [
                plan.views[k].read(w, band=1)[0] for k, w in zip(job.views, images, strict=True)
            ]
        with _timed(seconds, "fit"):
            res = fit_dem(
                terrain,
                crops,
                [plan.views[k].camera for k in job.views],
                plan.options,
                visible=visible,
                eps=plan.eps,
                progress=progress,
                threads=threads,
                windows=windows,
                spacing=plan.spacing,
                origin=(ext[2], ext[0]),
                geometry=geometry,
                strict=False,
            )
        del crops
        grown = _regrow(plan, job, windows, res.extents, result.refits)
        if grown is None:
            break
        images = grown
        result.refits += 1
    _fill(plan, result, res, terrain, geometry, ext, inner)
    return result


def _regrow(
    plan: FitPlan,
    job: FitJob,
    windows: list[ViewWindow],
    extents: list[np.ndarray] | None,
    refits: int,
) -> list[WindowT] | None:
    """None when every sampled position lay where the windows are exact, else the image
    windows grown to hold them (whole images after :data:`RETRIES` refits)."""
    assert extents is not None
    out, grown = [], False
    for i, (k, view) in enumerate(zip(job.views, windows, strict=True)):
        camera, size = plan.views[k].camera, view.size
        masks = exact_masks(view, camera, plan.levels)
        window = view.window
        for level in range(plan.levels):
            box = extents[level][i]
            finite = not np.isnan(box).any()
            if covers(view, masks, level, tuple(box), finite):
                continue
            grown = True
            if not finite or refits >= RETRIES:
                window = (0, size[1], 0, size[0])
                break
            s = 1 << level
            zero = (box[0] * s, (box[1] + 1) * s, box[2] * s, (box[3] + 1) * s)
            window = union(window, window_for(zero, camera, size, plan.levels))
        out.append(window)
    return out if grown else None


def _fill(
    plan: FitPlan,
    result: FitTile,
    res: Any,
    terrain: Any,
    geometry: Any,
    ext: WindowT,
    inner: tuple[slice, slice],
) -> None:
    """The tile's arrays and counts from the fit ``res`` of the fit grid ``ext``."""
    heights = res.heights[inner]
    ok = np.isfinite(heights)
    c, r = terrain.grid()
    c, r = c[inner] + ext[2], r[inner] + ext[0]
    p = geometry.to_world(c, r, terrain.values[inner])
    up = geometry.up_vectors(p)
    normals = res.normals[inner]
    tilt = np.degrees(np.arccos(np.clip(np.sum(normals * up, axis=-1), -1, 1)))
    result.heights = heights.astype(np.float32)
    result.normals = np.stack([res.n_theta[inner], res.n_phi[inner], tilt]).astype(np.float32)
    result.cost = res.cost[inner].astype(np.float32)
    result.views = res.views[inner].astype(np.uint8)
    converged = res.converged[inner]
    result.uncertainty = np.stack([res.sigma_h[inner], np.where(ok, converged, np.nan)]).astype(
        np.float32
    )
    result.fitted = int(ok.sum())
    result.converged = int(converged.sum())
    result.shift = heights[ok] - res.initial[inner][ok]
    sigma = res.sigma_h[inner][ok]
    result.sigma = sigma[np.isfinite(sigma)]


# ------------------------------------------------------------------------------ outputs
@dataclass(frozen=True)
class FitOutputs:
    """What a fit writes, on the DEM's grid: ``heights`` (float32, NaN where fewer than 2
    views see a post) and, when given, ``normals`` (3 bands float32: n_theta_deg, n_phi_deg,
    tilt_deg), ``cost`` (float32, eq. 20), ``views`` (uint8, views used) and ``uncertainty``
    (2 bands float32: sigma_h_m, converged 0/1), NaN where unresolved; ``format``,
    ``compress``, ``blocksize``, ``overwrite`` and ``replace_input`` as for
    :class:`~orthomvp.engine.Outputs` (the same rules)."""

    heights: str | Path
    normals: str | Path | None = None
    cost: str | Path | None = None
    views: str | Path | None = None
    uncertainty: str | Path | None = None
    format: str = "cog"
    compress: str = "zstd"
    blocksize: int = 512
    overwrite: bool = False
    replace_input: bool = False

    def __post_init__(self) -> None:
        for name in ("heights", "normals", "cost", "views", "uncertainty"):
            kinds = (str, os.PathLike) if name == "heights" else (str, os.PathLike, type(None))
            of_type(getattr(self, name), kinds, f"output {name}")
        check_settings(self)
        check_names(self.outputs())
        for out in self.outputs():
            if out.path is not None:
                check_parent(out.path, f"{out.path}: {out.option}")
        for name, value, allowed in (
            ("format", self.format, FORMATS),
            ("compression", self.compress, COMPRESSIONS),
        ):
            if value not in allowed:
                raise InputError(
                    f"output {name} must be one of {', '.join(allowed)}, not {value!r}"
                )

    def outputs(self) -> list[Output]:
        """The outputs, for :mod:`orthomvp.io.output_checks`."""
        names = ("heights", "normals", "cost", "views", "uncertainty")
        paths = [(name, getattr(self, name)) for name in names]
        return [Output(name, None if path is None else Path(path)) for name, path in paths]

    def check(self, inputs: Sequence[tuple[str, Path | str]]) -> None:
        """As :meth:`orthomvp.engine.Outputs.check`."""
        check_outputs(self.outputs(), inputs, self.overwrite, self.replace_input, API_FLAGS)

    def layers(self) -> list[Layer]:
        """The files to write."""
        f32, avg, near = "float32", Resampling.average, Resampling.nearest
        specs = [
            ("heights", 1, f32, np.nan, avg, ()),
            ("normals", 3, f32, np.nan, near, ("n_theta_deg", "n_phi_deg", "tilt_deg")),
            ("cost", 1, f32, np.nan, avg, ()),
            ("views", 1, "uint8", None, near, ()),
            ("uncertainty", 2, f32, np.nan, near, ("sigma_h_m", "converged")),
        ]
        return [
            Layer(Path(path), n, dtype, nodata, resampling, _getter(name), names)
            for name, n, dtype, nodata, resampling, names in specs
            if (path := getattr(self, name)) is not None
        ]


def _getter(name: str) -> Any:
    return lambda result: getattr(result, name)


@dataclass
class FitReport:
    """What a fit did: tiles run and skipped, wall-clock seconds, the workers' seconds per
    phase (read, mesh, visibility, fit) and the writer's (write); the DEM's ``posts``, those
    ``fitted`` and ``converged``; the change of the fitted heights from the input (median
    and RMS) and the median 1-sigma uncertainty; ``refits``: tiles fitted again with grown
    image windows."""

    tiles_run: int = 0
    tiles_skipped: int = 0
    seconds: float = 0.0
    phases: dict[str, float] = field(default_factory=dict)
    posts: int = 0
    fitted: int = 0
    converged: int = 0
    median_shift: float = math.nan
    rms_shift: float = math.nan
    median_sigma: float = math.nan
    refits: int = 0
    input_heights: str = ""
    """What the input heights are where the DEM's were shifted for the cameras (the output
    holds such heights too), else empty."""

    def line(self, output: str | Path) -> str:
        """The one-line summary that ``orthomvp fit`` prints: the change is fitted minus input
        height over the fitted posts, the uncertainty the fitted planes' 1-sigma height
        uncertainty (see :mod:`orthomvp.mvp.fit`), both in metres."""
        return (
            f"wrote {output}: {self.fitted:,} of {self.posts:,} posts fitted "
            f"({self.converged:,} converged); height change, fitted - input"
            f"{f' ({self.input_heights})' if self.input_heights else ''}: median "
            f"{self.median_shift:+.2f} m, RMS {self.rms_shift:.2f} m; median 1-sigma height "
            f"uncertainty {self.median_sigma:.2f} m (from the plane fit's covariance and "
            "residual: its noise, not its bias)"
        )


def run_fit(
    plan: FitPlan,
    outputs: FitOutputs,
    *,
    threads: int | None = None,
    processes: int | None = None,
    client: Any = None,
    progress: bool | None = None,
    inflight: int | None = None,
) -> FitReport:
    """Fit every tile of ``plan`` and write ``outputs`` (all of them, or none).

    Tiles run in ``threads`` threads (default one per core), or ``processes`` worker processes, or
    on the Dask ``client``, at most ``inflight`` (default the workers; see
    :func:`~orthomvp.engine.run.results`) at a time; with fewer tiles than threads each tile fits
    with several threads (and, alone, shows the fitter's own progress). ``progress``: progress and
    the plan's summary on stderr; default as the plan was made (:func:`plan_fit`'s). Raises
    InputError before any work when the expected peak memory exceeds what is available,
    GeometryError (writing nothing) when no post is visible in 2 or more images or an image sees
    only posts facing away, WorkerError (writing nothing) when a worker dies."""
    of_type(plan, FitPlan, "plan", " (from plan_fit)")
    of_type(outputs, FitOutputs, "outputs", " (FitOutputs(heights=...))")
    outputs.check(plan_inputs(plan))
    progress = plan.progress if progress is None else progress
    sched = schedule(plan.tiles, threads, processes, client, inflight)
    workers, jobs, at_once, inner = sched.workers, sched.jobs, sched.at_once, sched.inner
    need = plan.peak_memory(at_once, sched.processes, inner)
    largest = max((plan.tile_bytes(job, inner) for job in plan.tiles), default=0)
    advice = (  # (patches come a batch of posts at a time: smaller tiles do not shrink them)
        f"choose a smaller --hwin (every post's patch holds {2 * plan.options.hwin + 1} squared "
        "samples of each image) or fewer threads/processes"
        if 2 * plan.patch_bytes(inner) > largest
        else "use smaller tiles or fewer threads/processes"
    )
    peak = check_memory(plan, need, at_once, advice)
    start = time.perf_counter()
    rows, cols = plan.grid.shape
    report = FitReport(posts=rows * cols, input_heights=_input_heights(plan.dem.shift))
    inside, seen = [0] * len(plan.views), [0] * len(plan.views)
    twice = 0
    squares = 0.0
    folder = Path(outputs.heights).parent
    heights_grid = replace(plan.grid, crs=plan.dem.heights_crs())  # the heights' vertical datum
    with (
        image_copies(plan, Path(outputs.heights), local=all_local(client), jobs=jobs) as plan,
        Progress("fitting tiles", progress, len(plan.tiles)) as bar,
        executor(plan, run_fit_tile, workers, processes, client) as (submit, wait),
        contextlib.closing(Copies(plan, jobs)) as copies,
        Median(folder=folder) as shifts,
        Median(folder=folder) as sigmas,
    ):
        bar.note(plan.summary(peak, at_once))
        local = client is None and not processes  # the fitter's own bar shows in this process
        args = (inner, bool(progress and local and at_once == 1))
        with (
            rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE),
            output_files(heights_grid, outputs.layers(), outputs) as writer,
        ):
            for job in plan.tiles:
                if not job.views:
                    writer.write(empty_tile(plan, job))
                    report.tiles_skipped += 1
                    bar.update()
            for result in results(submit, wait, jobs, args, sched.limit, copies):
                t0 = time.perf_counter()
                writer.write(result)
                report.phases["write"] = report.phases.get("write", 0.0) + (
                    time.perf_counter() - t0
                )
                report.tiles_run += 1
                for phase, seconds in result.seconds.items():
                    report.phases[phase] = report.phases.get(phase, 0.0) + seconds
                report.fitted += result.fitted
                report.converged += result.converged
                report.refits += result.refits
                squares += float(np.sum(result.shift**2))
                shifts.add(result.shift)
                sigmas.add(result.sigma)
                inside = [a + b for a, b in zip(inside, result.inside, strict=True)]
                seen = [a + b for a, b in zip(seen, result.seen, strict=True)]
                twice += result.twice
                bar.update()
            # views seen in some tile, only facing away (views that no tile fits are not
            # known to be inside: the plan checked that each one sees the DEM)
            tried = [k for k, n in enumerate(inside) if n]
            check_views([plan.views[k] for k in tried], [1] * len(tried), [seen[k] for k in tried])
            if not report.fitted:
                raise GeometryError(nothing_fitted(twice, plan.options.hwin, plan.levels))
        report.median_shift = shifts.value()
        report.median_sigma = sigmas.value()
    report.rms_shift = math.sqrt(squares / report.fitted)
    report.seconds = time.perf_counter() - start
    return report


def _input_heights(shift: HeightShift | None) -> str:
    """:attr:`FitReport.input_heights` for a DEM read with ``shift``."""
    if shift is None:
        return ""
    parts = (["the geoid undulation"] if shift.wkt else []) + (
        [f"{shift.offset:+g} m"] if shift.offset else []
    )
    moved = " and ".join(parts) or "+0 m"
    return f"the DEM's heights moved by {moved} for the cameras, as the output holds them"
