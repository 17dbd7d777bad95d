"""The truth-free check (:mod:`orthomvp.quality.check`) through the engine, run: each tile of a
:class:`~orthomvp.engine.check_plan.CheckPlan` classifies its posts and ``window // 2`` around
them for every view, samples the naive values, and tallies the NCC of every ordered pair of
views at its own posts (:func:`run_check_tile`); :func:`run_check` merges the tallies, which
are exact integers but for the histogram medians (:mod:`orthomvp.engine.ncc`), so the result
does not depend on the tiles or on what ran them.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from orthomvp.codes import Code, classify
from orthomvp.engine import heap
from orthomvp.engine.check_plan import CheckPlan
from orthomvp.engine.copies import Copies, image_copies
from orthomvp.engine.ncc import MISS_BINS, ROW_EDGES, NccTally, check_row, local_ncc
from orthomvp.engine.plan import grow
from orthomvp.engine.progress import Progress
from orthomvp.engine.run import (
    all_local,
    check_memory,
    check_views,
    executor,
    results,
    schedule,
)
from orthomvp.engine.tile import (
    _grid_tile,
    _has_cell,
    _visibility,
    sample_view,
)
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.vectors import finite_rows
from orthomvp.occlusion.visibility import occluder_caster
from orthomvp.validate import of_type

CLASSES = ("visible", "occluded")
"""The classes of posts scored, in the order of the rows: visible in both views; called
occluded by the first view and visible in the other (the first view's naive value)."""

Key = tuple[int, int, int, int]
"""(epsilon index, view, other view, class index), views 0-based."""


@dataclass
class CheckResult:
    """The check: ``rows`` (dicts with :data:`orthomvp.quality.check.CSV_FIELDS`), the 1-based
    ``pairs`` of views that overlap and those (``apart``) that do not, and the view
    ``names``."""

    rows: list[dict]
    pairs: list[tuple[int, int]]
    apart: list[tuple[int, int]] = field(default_factory=list)
    names: list[str] = field(default_factory=list)

    def pooled(self, eps: float, cls: str) -> dict:
        """The pooled row over all pairs and miss distances for ``eps`` and class ``cls``
        (one of :data:`CLASSES`); InputError naming the epsilons checked when there is none."""
        if cls not in CLASSES:
            raise InputError(f"class must be one of {', '.join(CLASSES)}, not {cls!r}")
        for r in self.rows:
            if (
                r["view"] == "all"
                and r["eps"] == eps
                and r["class"] == cls
                and r["miss_from"] == 0
                and r["miss_to"] == np.inf
            ):
                return r
        checked = sorted({r["eps"] for r in self.rows if r["view"] == "all"})
        raise InputError(
            f"no pooled row for eps {eps}: the check has eps "
            + (", ".join(f"{e:g}" for e in checked) or "none (no pair of views overlaps)")
        )


def no_overlap(views: int, window: int) -> str:
    """The error when no pair of the ``views`` shares a ``window`` x ``window`` box of posts."""
    return (
        f"no two of the {views} views overlap: no pair sees a {window} x {window} window of "
        "the same posts"
    )


# ------------------------------------------------------------------------------ per tile
@dataclass
class CheckTile:
    """A checked tile: per view the posts of the tile ``inside`` the image and those ``seen``
    (visible or occluded); ``overlap`` per pair (a, b), a < b, the tile's posts that both
    see and both image with a value; ``tallies`` the NCC at the tile's posts per
    :data:`Key`."""

    index: int
    inside: list[int]
    seen: list[int]
    overlap: dict[tuple[int, int], int] = field(default_factory=dict)
    tallies: dict[Key, NccTally] = field(default_factory=dict)


def run_check_tile(plan: CheckPlan, index: int, threads: int = 1) -> CheckTile:
    """Check tile ``index`` of ``plan`` with ``threads`` threads for ray casting and
    visibility, inside :func:`orthomvp.engine.heap.tile_heap` as
    :func:`~orthomvp.engine.tile.run_tile`."""
    with heap.tile_heap(plan.tiles[index].dem_posts):
        return _run_check_tile(plan, index, threads)


def _run_check_tile(plan: CheckPlan, index: int, threads: int) -> CheckTile:
    base, job = plan.base, plan.tiles[index]
    n = len(plan.views)
    result = CheckTile(index, [0] * n, [0] * n)
    if not job.views:
        return result
    values = base.dem.read(job.dem)
    if not _has_cell(np.isfinite(values)):
        return result
    window = base.dem.window_terrain(job.dem, values)
    ext = grow(job.window, plan.margin, base.grid.shape)
    grid, inner = _grid_tile(base, job, window, ext)
    if grid is None:
        return result
    r0, r1, c0, c1 = job.window
    core = (slice(r0 - ext[0], r1 - ext[0]), slice(c0 - ext[2], c1 - ext[2]))
    caster = occluder_caster(window, threads=threads)
    codes, miss, naive = {}, {}, {}
    for k in job.views:
        fields = frozenset({"miss"})
        vis = _visibility(base, grid, k, caster, window, threads, fields, plan.visibility_path)
        code, uv = vis.codes[inner], vis.uv[inner]
        inside = finite_rows(uv)
        value = np.full(code.shape, np.nan, np.float32)
        if inside.any():
            value[inside] = np.mean(sample_view(plan.views[k], uv[inside], "bilinear"), axis=0)
        result.inside[k] = int((code[core] != Code.NODATA).sum())
        result.seen[k] = int(np.isin(code[core], (Code.VISIBLE, Code.OCCLUDED)).sum())
        m = vis.miss[inner]
        codes[k], miss[k], naive[k] = code, np.where(np.isposinf(m), 0.0, m), value  # inf: no hit
    pairs = [(a, b) for i, a in enumerate(job.views) for b in job.views[i + 1 :]]
    usable = {
        k: np.isin(codes[k], (Code.VISIBLE, Code.OCCLUDED)) & np.isfinite(naive[k])
        for k in job.views
    }
    result.overlap = {(a, b): int((usable[a] & usable[b])[core].sum()) for a, b in pairs}
    for e, eps in enumerate(plan.eps_values):
        _tally_eps(plan, result.tallies, e, eps, pairs, codes, miss, naive, core)
    return result


def _tally_eps(
    plan: CheckPlan,
    tallies: dict[Key, NccTally],
    e: int,
    eps: float,
    pairs: list[tuple[int, int]],
    codes: dict[int, np.ndarray],
    miss: dict[int, np.ndarray],
    naive: dict[int, np.ndarray],
    core: tuple[slice, slice],
) -> None:
    """Add the tallies of epsilon number ``e`` (``eps``, DEM posts) of every ordered pair to
    ``tallies``: each view's posts reclassified by their miss distance, the NCC maps on the
    grown tile, the tallies at its ``core`` posts."""
    code_e, ortho = {}, {}
    for k, code in codes.items():
        c = code.copy()
        cast = ~np.isnan(miss[k])
        c[cast] = classify(miss[k][cast], eps)
        code_e[k] = c
        ortho[k] = np.where(c == Code.VISIBLE, naive[k], np.nan)
    for a, b in pairs:
        both = None
        for x, y in ((a, b), (b, a)):
            seen_y = code_e[y][core] == Code.VISIBLE
            for c, wanted in enumerate((Code.VISIBLE, Code.OCCLUDED)):
                mask = (code_e[x][core] == wanted) & seen_y
                if not mask.any():
                    continue
                if wanted == Code.VISIBLE:
                    if both is None:
                        both = local_ncc(ortho[a], ortho[b], plan.window)[core]
                    ncc = both
                else:
                    ncc = local_ncc(naive[x], ortho[y], plan.window)[core]
                _add(tallies, (e, x, y, c), NccTally.of(miss[x][core][mask], ncc[mask]))


def _add(tallies: dict[Key, NccTally], key: Key, tally: NccTally) -> None:
    tallies[key] = tallies[key].merge(tally) if key in tallies else tally


# ------------------------------------------------------------------------------ the run
def tally_rows(eps: float, view: str, other: str, cls: str, tally: NccTally) -> list[dict]:
    """The rows of one tally: one per miss bin, then one over all bins."""
    bins = len(MISS_BINS) - 1
    return [
        check_row(eps, (view, other), cls, edges, tally.summary(k if k < bins else None))
        for k, edges in enumerate(ROW_EDGES)
    ]


def check_rows(
    eps_values: tuple[float, ...],
    pairs: list[tuple[int, int]],
    names: tuple[str, ...],
    tallies: dict[Key, NccTally],
) -> list[dict]:
    """Every row of the check: per epsilon, per overlapping pair (0-based) both ways, per
    class; then the pooled rows (view ``all``) of each class over those pairs."""
    out: list[dict] = []
    for e, eps in enumerate(eps_values):
        pooled = {cls: NccTally.empty() for cls in CLASSES}
        for a, b in pairs:
            for x, y in ((a, b), (b, a)):
                for c, cls in enumerate(CLASSES):
                    tally = tallies.get((e, x, y, c)) or NccTally.empty()
                    pooled[cls] = pooled[cls].merge(tally)
                    out += tally_rows(eps, names[x], names[y], cls, tally)
        for cls in CLASSES:
            out += tally_rows(eps, "all", "all", cls, pooled[cls])
    return out


@contextlib.contextmanager
def _copies(plan: CheckPlan, client: Any, jobs: list[int]) -> Iterator[CheckPlan]:
    """``plan`` with the copies of the images its tiles ``jobs`` read again
    (:func:`~orthomvp.engine.copies.image_copies`; in the temporary folder unless it is in
    memory, as a check writes no raster and the images' folder is the user's) for the block."""
    with image_copies(plan.base, None, local=all_local(client), jobs=jobs) as base:
        yield plan if base is plan.base else replace(plan, base=base)


def run_check(
    plan: CheckPlan,
    *,
    threads: int | None = None,
    processes: int | None = None,
    client: Any = None,
    progress: bool | None = None,
    inflight: int | None = None,
) -> CheckResult:
    """Run every tile of ``plan`` and return the check (as
    :func:`orthomvp.quality.check.check_views` gives it in memory, medians within
    :data:`~orthomvp.engine.ncc.MEDIAN_BOUND`).

    Tiles run in ``threads`` threads (default one per core), or ``processes`` worker processes, or
    on the Dask ``client``, at most ``inflight`` (default the workers; see
    :func:`~orthomvp.engine.run.results`) at a time; ``progress`` (progress and the plan's summary
    on stderr) defaults to the plan's (:func:`~orthomvp.engine.plan_check`'s). A pair of views
    overlaps when both see at least ``window`` x ``window`` of the same posts. Raises InputError
    before any work when the expected peak memory exceeds what is available, GeometryError when
    no pair overlaps or a view sees only posts facing away, WorkerError when a worker dies."""
    of_type(plan, CheckPlan, "plan", " (from plan_check)")
    progress = plan.progress if progress is None else progress
    sched = schedule(plan.tiles, threads, processes, client, inflight)
    workers, jobs, at_once, inner = sched.workers, sched.jobs, sched.at_once, sched.inner
    peak = check_memory(plan, plan.peak_memory(at_once, sched.processes), at_once)
    n = len(plan.views)
    inside, seen = [0] * n, [0] * n
    overlap: dict[tuple[int, int], int] = {}
    tallies: dict[Key, NccTally] = {}
    with (
        _copies(plan, client, jobs) as plan,
        Progress("checking tiles", progress, len(plan.tiles)) as bar,
        executor(plan, run_check_tile, workers, processes, client) as (submit, wait),
        contextlib.closing(Copies(plan, jobs)) as copies,
    ):
        bar.note(plan.summary(peak, at_once))
        bar.update(len(plan.tiles) - len(jobs))
        for result in results(submit, wait, jobs, (inner,), sched.limit, copies):
            inside = [a + b for a, b in zip(inside, result.inside, strict=True)]
            seen = [a + b for a, b in zip(seen, result.seen, strict=True)]
            for pair, count in result.overlap.items():
                overlap[pair] = overlap.get(pair, 0) + count
            for key, tally in result.tallies.items():
                _add(tallies, key, tally)
            bar.update()
    # views inside some tile that saw only posts facing away (views that no tile with
    # another view holds overlap nothing: their pairs are apart)
    tried = [k for k, count in enumerate(inside) if count]
    check_views([plan.views[k] for k in tried], [1] * len(tried), [seen[k] for k in tried])
    every = [(a, b) for a in range(n) for b in range(a + 1, n)]
    pairs = [p for p in every if overlap.get(p, 0) >= plan.window * plan.window]
    if not pairs:
        raise GeometryError(no_overlap(n, plan.window))
    apart = [p for p in every if p not in pairs]
    return CheckResult(
        check_rows(plan.eps_values, pairs, plan.names, tallies),
        [(a + 1, b + 1) for a, b in pairs],
        [(a + 1, b + 1) for a, b in apart],
        list(plan.names),
    )
