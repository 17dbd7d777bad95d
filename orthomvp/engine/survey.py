"""The mosaic's survey, before its tiles, on a decimated copy of the output grid (at most
:data:`SURVEY_POSTS` posts a side, so memory is bounded whatever the grid): every view's samples
and codes for the radiometric balance (overlap statistics,
:func:`orthomvp.ortho.balance.solve_balance`), and the widest overlap of the images' footprints
(the blend width is clamped to it, with a
:class:`~orthomvp.ortho.composite.BlendWarning`). Without a balance only the footprints are needed:
the survey then casts no rays and samples no image.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from orthomvp.engine.grid import grid_to_dem, output_grid
from orthomvp.engine.grid_choice import grid_spacing
from orthomvp.engine.plan import Plan, TileJob, _jobs
from orthomvp.ortho.balance import pair_stats, solve_balance
from orthomvp.ortho.composite import clamp_blend, overlap_width

SURVEY_POSTS = 512
"""Posts along the longer side of the survey grid for a balance (at most)."""

FOOTPRINT_POSTS = 128
"""Posts along the longer side of the survey grid without a balance (at most): the widest
overlap is then known to within one step of the survey grid, under 1% of the grid's side."""


def survey_plan(plan: Plan, progress: bool = False) -> tuple[Plan, int]:
    """The plan of the survey: the output grid decimated by a whole step (the posts every
    ``step`` posts, about; the grid itself when it fits), uncomposed, without occlusion unless
    the balance needs it; and the step."""
    assert plan.mosaic is not None
    balance = plan.mosaic.balance is not None
    rows, cols = plan.grid.shape
    step = max(1, math.ceil(max(rows, cols) / (SURVEY_POSTS if balance else FOOTPRINT_POSTS)))
    grid, post_scale = plan.grid, plan.post_scale
    if step > 1:
        t = plan.grid.transform
        left, top = t @ (0, 0)
        right, bottom = t @ (cols, rows)
        res = (abs(t.a) * step, abs(t.e) * step)
        box = (min(left, right), min(top, bottom), max(left, right), max(top, bottom))
        grid = output_grid(plan.dem, res, box, plan.grid.crs)
        post_scale = grid_spacing(grid, plan.dem) / plan.spacing
    to_dem = grid_to_dem(grid, plan.dem)
    plain = replace(plan.mosaic, seamlines=False, blend=0, balance=None, holes="empty")
    jobs, *_ = _jobs(
        plan.dem,
        to_dem,
        grid,
        plan.views,
        grid.tiles(plan.tile),
        plan.occlusion,
        plain.margin,
        progress=progress,
    )
    coarse = replace(
        plan,
        grid=grid,
        tiles=tuple(_without(job, plan.left_out) for job in jobs),
        post_scale=post_scale,
        mosaic=plain,
        correction=None,
        occlusion=plan.occlusion and balance,
    )
    return coarse, step


def _without(job: TileJob, left_out: tuple[int, ...]) -> TileJob:
    """``job`` without the views ``left_out`` (the plan's, which see no post of its grid)."""
    keep = [i for i, k in enumerate(job.views) if k not in left_out]
    if len(keep) == len(job.views):
        return job
    if not keep:
        return replace(job, views=(), dem=None, image_windows=())
    views = tuple(job.views[i] for i in keep)
    return replace(job, views=views, image_windows=tuple(job.image_windows[i] for i in keep))


def survey(plan: Plan, run: Any) -> Plan:
    """``plan`` ready to run: with the radiometric correction its options ask for, and the
    blend width clamped to the widest overlap (warning). ``run(plan, jobs, kinds)`` runs the
    survey plan's tiles for the outputs ``kinds`` (samples and codes, "stack", for a balance;
    else the codes alone, "visibility") and yields their results."""
    options = plan.mosaic
    assert options is not None
    coarse, step = survey_plan(plan)
    n, bands = len(plan.views), plan.bands
    rows, cols = coarse.grid.shape
    balance = options.balance is not None
    values = np.full((n, bands, rows, cols), np.nan, np.float32) if balance else None
    codes = np.zeros((n, rows, cols), np.uint8)
    kinds = frozenset({"stack" if balance else "visibility"})
    for result in run(coarse, [job.index for job in coarse.tiles if job.views], kinds):
        r0, r1, c0, c1 = result.window
        if values is not None and result.stack is not None:
            values[:, :, r0:r1, c0:c1], codes[:, r0:r1, c0:c1] = result.stack
        elif result.codes is not None:
            codes[:, r0:r1, c0:c1] = result.codes
    correction = plan.correction
    if balance:
        stats = pair_stats(values, codes)
        correction = solve_balance(
            stats, options.balance, options.reference, left_out=plan.left_out
        )
    blend = clamp_blend(options.blend, overlap_width(codes, step))
    return replace(plan, mosaic=replace(options, blend=blend), correction=correction)
