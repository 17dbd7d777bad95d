"""The mosaic's survey, before its tiles: every view's samples and codes on a decimated copy
of the output grid (at most :data:`SURVEY_POSTS` posts a side, so memory is bounded whatever
the grid), for the radiometric balance (overlap statistics,
:func:`orthomvp.mosaic.solve_balance`) and the widest overlap (the blend width is clamped to it,
with a :class:`~orthomvp.mosaic.BlendWarning`).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from orthomvp.engine.grid import grid_to_dem, output_grid
from orthomvp.engine.plan import Plan, _grid_spacing, _job, plan_tiles
from orthomvp.mosaic import clamp_blend, overlap_width, pair_stats, solve_balance

SURVEY_POSTS = 512
"""Posts along the longer side of the survey grid (at most)."""


def survey_plan(plan: Plan, progress: bool = False) -> tuple[Plan, int]:
    """The plan of the survey: the output grid decimated by a whole step (the posts every
    ``step`` posts, about; the grid itself when it fits), uncomposed; and the step."""
    assert plan.mosaic is not None
    rows, cols = plan.grid.shape
    step = max(1, math.ceil(max(rows, cols) / SURVEY_POSTS))
    grid, post_scale = plan.grid, plan.post_scale
    if step > 1:
        t = plan.grid.transform
        left, top = t * (0, 0)
        right, bottom = t * (cols, rows)
        res = (abs(t.a) * step, abs(t.e) * step)
        box = (min(left, right), min(top, bottom), max(left, right), max(top, bottom))
        grid = output_grid(plan.dem, res, box, plan.grid.crs)
        post_scale = _grid_spacing(grid, plan.dem) / plan.spacing
    to_dem = grid_to_dem(grid, plan.dem)
    jobs, *_ = plan_tiles(
        grid.tiles(plan.tile),
        lambda i, w: _job(plan.dem, to_dem, grid, plan.views, i, w, plan.occlusion),
        len(plan.views),
        progress,
    )
    plain = replace(plan.mosaic, seamlines=False, blend=0, balance=None, fill="none")
    coarse = replace(
        plan, grid=grid, tiles=tuple(jobs), post_scale=post_scale, mosaic=plain, correction=None
    )
    return coarse, step


def survey(plan: Plan, run: Any) -> Plan:
    """``plan`` ready to run: with the radiometric correction its options ask for, and the
    blend width clamped to the widest overlap (warning). ``run(plan, jobs)`` runs the survey
    plan's tiles (kind "stack") and yields their results."""
    options = plan.mosaic
    assert options is not None
    coarse, step = survey_plan(plan)
    n, bands = len(plan.views), plan.bands
    rows, cols = coarse.grid.shape
    values = np.full((n, bands, rows, cols), np.nan, np.float32)
    codes = np.zeros((n, rows, cols), np.uint8)
    for result in run(coarse, [job.index for job in coarse.tiles if job.views]):
        if result.stack is not None:
            r0, r1, c0, c1 = result.window
            values[:, :, r0:r1, c0:c1], codes[:, r0:r1, c0:c1] = result.stack
    correction = plan.correction
    if options.balance is not None:
        stats = pair_stats(values, codes)
        correction = solve_balance(stats, options.balance, options.reference)
    blend = clamp_blend(options.blend, overlap_width(codes, step))
    return replace(plan, mosaic=replace(options, blend=blend), correction=correction)
