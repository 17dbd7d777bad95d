"""A truth-free consistency check of the visibility flags, for users' own data.

For every ordered pair of overlapping views (A, B) and every epsilon (DEM posts), the local
normalised cross-correlation (NCC, a ``window`` x ``window`` box of posts) between orthophotos
on the DEM grid is scored at two classes of posts, binned by A's first-hit miss distance
(:attr:`orthomvp.occlusion.visibility.Visibility.miss`, DEM posts; a ray that hits nothing counts
as 0):

- ``visible``: posts visible in A and in B; NCC of A's and B's occlusion-aware orthophotos;
- ``occluded``: posts A calls occluded and B visible; NCC of A's *naive* orthophoto (what A
  would paint there) with B's occlusion-aware one.

Where the flags are right, ``visible`` correlates highly (the same ground seen twice) and
``occluded`` poorly (A's value there is the occluder's); a ``visible`` NCC that falls with the
miss distance says that epsilon lets partial ghosts through. Windows count only posts where both
orthophotos have values, and need at least half the window; multi-band images are averaged
over their bands. Rows with view ``all`` pool every pair.

Two ways to run it: :func:`check_views` on a DEM and images in memory (small data; exact
medians), and :func:`orthomvp.engine.plan_check` / :func:`orthomvp.engine.run_check` from files,
tile by tile in bounded memory through the engine (what ``orthomvp check`` runs): the same
counts and means, medians from a histogram within
:data:`orthomvp.engine.ncc.MEDIAN_BOUND` (0.00025). :func:`save` writes either result.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera import Camera, as_image, check_image
from orthomvp.codes import Code, classify
from orthomvp.engine.check import CheckResult, no_overlap
from orthomvp.engine.check_plan import DEFAULT_EPS, check_options
from orthomvp.engine.ncc import MISS_BINS, ROW_EDGES, check_row, local_ncc
from orthomvp.errors import GeometryError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.preflight import check_memory, count_text
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import (
    VISIBILITY_BYTES_PER_POST,
    compute_visibility,
    occluder_caster,
)
from orthomvp.ortho.orthophoto import sample_image
from orthomvp.present.figures import save_with_table
from orthomvp.validate import of_type

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "CSV_FIELDS",
    "DEFAULT_EPS",
    "MISS_BINS",
    "CheckResult",
    "check_views",
    "local_ncc",
    "plot",
    "save",
]

CHECK_BYTES_PER_POST = 200
"""Memory per post beyond the visibility: NCC maps and their box sums, bytes."""
VIEW_BYTES_PER_POST = 16
"""Memory per post and view kept across the check: miss, codes, naive value, bytes."""
CSV_FIELDS = (
    "eps",
    "view",
    "other",
    "class",
    "miss_from",
    "miss_to",
    "posts",
    "scored",
    "ncc_mean",
    "ncc_median",
)


def check_views(
    terrain: Terrain,
    views: list[tuple[np.ndarray, Camera]],
    *,
    eps_values: tuple[float, ...] = DEFAULT_EPS,
    window: int = 7,
    names: list[str] | None = None,
    caster: RayCaster | None = None,
    progress: bool = False,
) -> CheckResult:
    """Check the visibility flags of (image, camera) ``views`` (at least two; images (bands,
    rows, cols) or (rows, cols), cameras with or without image size) on ``terrain`` for every
    epsilon of ``eps_values`` (DEM posts, > 0), with an odd ``window`` (3..51 posts); see the
    module docstring. ``names`` label the views (default 1, 2, ...); ``caster`` reuses a ray
    caster on this terrain's occluder surface. GeometryError when no two views overlap (share
    at least a window of posts inside both images and facing both)."""
    of_type(terrain, Terrain, "terrain")
    count = len(views) if isinstance(views, (list, tuple)) else 0
    eps_values, window, labels = check_options(count, eps_values, window, names)
    names = list(labels)
    rows, cols = terrain.shape
    posts = float(rows) * cols
    check_memory(
        f"this grid is {count_text(posts)} posts ({cols:,} x {rows:,}) for {len(views)} views",
        posts
        * (VISIBILITY_BYTES_PER_POST + CHECK_BYTES_PER_POST + VIEW_BYTES_PER_POST * len(views)),
        "use a smaller or coarser DEM",
    )
    caster = caster or occluder_caster(terrain)
    miss, naive, base = [], [], []
    for k, (image, camera) in enumerate(views):
        image = as_image(image, f"view {names[k]}")
        camera = check_image(image, camera, f"view {names[k]}")
        vis = compute_visibility(terrain, camera, caster=caster, progress=progress)
        m = vis.miss.copy()
        m[np.isposinf(m)] = 0.0  # nothing in the way
        miss.append(m)
        base.append(vis.codes)
        naive.append(np.mean(sample_image(image, vis.uv), axis=0))
    seen = [np.isin(c, (Code.VISIBLE, Code.OCCLUDED)) for c in base]
    pairs, apart = [], []
    for a in range(len(views)):
        for b in range(a + 1, len(views)):
            both = int((seen[a] & seen[b] & np.isfinite(naive[a]) & np.isfinite(naive[b])).sum())
            (pairs if both >= window * window else apart).append((a, b))
    if not pairs:
        raise GeometryError(no_overlap(len(views), window))
    out: list[dict] = []
    for eps in eps_values:
        codes = []
        for m, c in zip(miss, base, strict=True):
            c = c.copy()
            cast = ~np.isnan(m)
            c[cast] = classify(m[cast], eps)
            codes.append(c)
        ortho = [np.where(c == Code.VISIBLE, n, np.nan) for c, n in zip(codes, naive, strict=True)]
        pooled: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {"visible": [], "occluded": []}
        for a, b in pairs:
            both = local_ncc(ortho[a], ortho[b], window)
            for x, y in ((a, b), (b, a)):
                vis_b = codes[y] == Code.VISIBLE
                classes = {
                    "visible": ((codes[x] == Code.VISIBLE) & vis_b, both),
                    "occluded": (
                        (codes[x] == Code.OCCLUDED) & vis_b,
                        local_ncc(naive[x], ortho[y], window),
                    ),
                }
                for cls, (mask, ncc) in classes.items():
                    pooled[cls].append((miss[x][mask], ncc[mask]))
                    out += _rows(eps, names[x], names[y], cls, miss[x][mask], ncc[mask])
        for cls, parts in pooled.items():
            d = np.concatenate([p[0] for p in parts])
            v = np.concatenate([p[1] for p in parts])
            out += _rows(eps, "all", "all", cls, d, v)
    to_names = [(a + 1, b + 1) for a, b in pairs]
    return CheckResult(out, to_names, [(a + 1, b + 1) for a, b in apart], names)


def _rows(
    eps: float, view: str, other: str, cls: str, miss: np.ndarray, ncc: np.ndarray
) -> list[dict]:
    """One row per miss bin and one over all bins."""
    out = []
    for lo, hi in ROW_EDGES:
        sel = (miss >= lo) & (miss < hi)
        v = ncc[sel]
        v = v[np.isfinite(v)]
        median = float(np.median(v)) if v.size else np.nan
        figures = (int(sel.sum()), int(v.size), float(v.mean()) if v.size else np.nan, median)
        out.append(check_row(eps, (view, other), cls, (lo, hi), figures))
    return out


def save(
    result: CheckResult, table: str | Path, figure: str | Path, *, overwrite: bool = False
) -> None:
    """Write the check's rows as CSV (``table``) and its :func:`plot` (``figure``, PNG or
    another format matplotlib writes, by the suffix), atomically as a set; files that exist
    are refused unless ``overwrite``."""
    save_with_table(plot(result), figure, result.rows, CSV_FIELDS, table, overwrite=overwrite)


def plot(result: CheckResult) -> Figure:
    """Median NCC against the miss-distance bin, one panel per epsilon, pooled over the
    pairs: posts visible in both views and posts called occluded (naive value)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eps_values = sorted({r["eps"] for r in result.rows})
    fig, axes = plt.subplots(
        1,
        len(eps_values),
        figsize=(3.2 * len(eps_values) + 1, 3.6),
        sharey=True,
        squeeze=False,
        constrained_layout=True,
    )
    labels = [f"{lo:g}-{hi:g}" for lo, hi in zip(MISS_BINS[:-1], MISS_BINS[1:], strict=True)]
    for ax, eps in zip(axes[0], eps_values, strict=True):
        # occluded in its code colour; visible dark grey (its light grey would not show on white)
        occluded = tuple(v / 255 for v in Code.OCCLUDED.rgb)
        for cls, colour in (("visible", "0.3"), ("occluded", occluded)):
            rows = [
                r
                for r in result.rows
                if r["view"] == "all"
                and r["eps"] == eps
                and r["class"] == cls
                and not (r["miss_from"] == 0 and r["miss_to"] == np.inf)
            ]
            y = [r["ncc_median"] if r["scored"] else np.nan for r in rows]
            ax.plot(range(len(rows)), y, marker="o", color=colour, label=cls)
        ax.set_xticks(range(len(labels)), labels, rotation=45, fontsize=7)
        ax.set_title(f"eps {eps:g} posts")
        ax.set_xlabel("first-hit miss (DEM posts)")
        ax.grid(True, alpha=0.3)
        ax.set_ylim(-1, 1)
    axes[0][0].set_ylabel("median local NCC")
    axes[0][0].legend(fontsize=8)
    return fig
