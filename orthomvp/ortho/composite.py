"""Mosaic composition: source priority, seamlines, feathered blending and the hole policy, on
per-view stacks of one window (a tile with its margin, or a whole grid), after the radiometric
balance of :mod:`orthomvp.ortho.balance`.

Every decision at a post depends only on the posts within :meth:`MosaicOptions.margin` of it,
and the sums behind them are exact integers, so a tile computed with that margin around it
gives the same result as the whole grid (the engine reads that margin; see
:mod:`orthomvp.engine.tile`). Off the grid counts as nothing: no post, no vote.

Seamlines. Each view gets a cost per post: its priority (:data:`PRIORITIES`, scaled to about
0..1), plus the share of its neighbours within :data:`SEAM_RADIUS` posts that it does not see
(seams keep away from occlusion boundaries and image edges), plus its disagreement with the
median of the views that see the post (seams avoid where one view differs from the others:
ghosts, moving objects, misregistration). Costs are quantised to 1/:data:`QUANT` and averaged
over the visible neighbours within :data:`SEAM_RADIUS`; each post is labelled with the visible
view of least cost. Blending: a view's weight at a post is the share of posts labelled with
it within ``blend // 2`` posts (a box), among views that see the post, so a straight seam
becomes a linear ramp ``blend`` posts wide (``blend`` = 0: hard seams). A view never
contributes where it does not see the post.

Trust. Before all that, each post keeps only the views it trusts most among those that see it
(:func:`trusted`): a view is doubtful at a post whose first hit landed in the last
:data:`~orthomvp.codes.DOUBT` posts of its epsilon (on sharp surface models those are as often
hidden or facing away as visible). Among the others a post takes the views farthest from their
own occlusion boundary: those whose eight neighbours of the post are all visible, else those
whose four nearest are, else the rest (pixels at a boundary straddle a wall or roof edge, and
the visibility rule's remaining misses all lie there). Never a doubtful view: a post only doubtful
views see stays empty (or is filled by the hole policy).

Holes (posts no trusted view sees) follow the hole policy of :mod:`orthomvp.ortho.holes`, which
flags every post with how it was filled or why it is empty (:class:`Flag`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from orthomvp.camera import Camera
from orthomvp.codes import DOUBT, Code
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.ortho.balance import BALANCES, Correction
from orthomvp.ortho.holes import FILL_ALIASES, HOLES, INPAINT_HALO, Flag, fill_holes
from orthomvp.ortho.support import (
    FEATHER_RADIUS,
    Support,
    fill_doubtful,
    heaviest,
    sharpen,
    shun,
)
from orthomvp.ortho.support import RADIUS as SUPPORT_RADIUS

PRIORITIES = ("emission", "gsd", "nadir", "order")
"""Which view a post prefers: smallest emission angle (surface normal to camera), finest
ground sample distance, smallest off-nadir angle (local vertical to camera), or the first
listed view."""

FILLS = tuple(FILL_ALIASES)
"""The deprecated ``fill`` option's values (:data:`~orthomvp.ortho.holes.FILL_ALIASES`): the
hole policies empty, behind and naive (:data:`~orthomvp.ortho.holes.HOLES`)."""

SEAM_RADIUS = 4
"""Posts around a post whose costs decide its label."""

QUANT = 1024
"""Steps per unit of cost (fixed point: sums are exact integers)."""

DISAGREE = 4.0
"""Relative difference ``|a - b| / (|a| + |b|)`` times this is the disagreement cost (capped
at 1): an eighth apart costs as much as the whole priority range."""

ORDER_STEP = 8
"""Cost between consecutive views under priority "order" (more than all other costs)."""

NETWORK_LAYERS = 8
"""Views up to which :func:`visible_median` sorts by a network of minima and maxima."""
TRUST_RADIUS = 1
"""A view is at its occlusion boundary where a post within this box radius is not visible in
it (:func:`trusted`)."""


FUSED_POSTS = 2_000_000
"""Posts of a mosaic from which it runs the numba kernels: :func:`compose`'s (``fused``) and
the visibility test's geometry (:attr:`orthomvp.occlusion.paths.Geometry.SEPARABLE_KERNEL`).
Loading them costs about 0.3 s a process. Four ngi-aerial frames, whole process, posts
of the tiles with views: 2.0 M (6 m) 1.32-1.38 s with them against 1.46-1.59 s without; 1.1 M
(8 m) 1.09-1.16 against 1.03-1.12 s; 0.51 M (12 m) 0.94-0.96 against 0.79-0.80 s."""


class BlendWarning(UserWarning):
    """A blend width wider than any overlap between two views (clamped)."""


@dataclass(frozen=True)
class MosaicOptions:
    """How views combine: ``priority`` (:data:`PRIORITIES`), ``seamlines`` (False: each post
    from its best view alone), ``blend`` width in posts (0: hard seams), ``balance`` (None or
    one of :data:`~orthomvp.ortho.balance.BALANCES`) with ``reference`` the 0-based view held
    fixed (None: the mean gain is 1 and the mean offset 0), and ``holes`` the hole policy
    (:data:`~orthomvp.ortho.holes.HOLES`). ``fill`` (:data:`FILLS`) is its deprecated
    former name (a DeprecationWarning; ``fill="none"`` is ``holes="empty"``, ``"any-view"``
    ``"behind"``). ``clear``: a blocked sample near an occlusion boundary takes its clear
    pixels only, and a doubtful fill those of a doubtful view
    (:func:`~orthomvp.ortho.support.sharpen`, :func:`~orthomvp.ortho.support.fill_doubtful`;
    fewer partial ghosts, a little further from the point radiance: docs/mosaics.md)."""

    priority: str = "emission"
    seamlines: bool = True
    blend: int = 8
    balance: str | None = None
    reference: int | None = None
    holes: str = "empty"
    fill: str | None = None
    clear: bool = True

    def __post_init__(self) -> None:
        if self.fill is not None:
            if self.fill not in FILLS:
                names = ", ".join(FILLS)
                raise InputError(f"mosaic fill must be one of {names}, not {self.fill!r}")
            holes = FILL_ALIASES[self.fill]
            if self.holes not in ("empty", holes):
                raise InputError(f"fill {self.fill!r} contradicts holes {self.holes!r}")
            warnings.warn(
                f"mosaic fill={self.fill!r} is deprecated: use holes={holes!r}",
                DeprecationWarning,
                stacklevel=3,
            )
            object.__setattr__(self, "holes", holes)
            object.__setattr__(self, "fill", None)
        for name, value, allowed in (
            ("priority", self.priority, PRIORITIES),
            ("holes", self.holes, HOLES),
            ("balance", self.balance, (None, *BALANCES)),
        ):
            if value not in allowed:
                names = ", ".join(a for a in allowed if a is not None)
                raise InputError(f"mosaic {name} must be one of {names}, not {value!r}")
        if not isinstance(self.clear, bool):
            raise InputError(f"mosaic clear must be True or False, not {self.clear!r}")
        if isinstance(self.blend, bool) or not isinstance(self.blend, int | np.integer):
            raise InputError(f"blend width must be a whole number of posts, got {self.blend!r}")
        if self.blend < 0:
            raise InputError(f"blend width must be at least 0 posts, got {self.blend}")
        if self.reference is not None and (isinstance(self.reference, bool) or self.reference < 0):
            raise InputError(f"balance reference must be a view index >= 0, got {self.reference}")

    @property
    def margin(self) -> int:
        """Posts around a post that its result depends on: the trust test
        (:data:`TRUST_RADIUS`, :data:`~orthomvp.ortho.support.RADIUS`), the label's cost
        average and its costs' neighbourhoods (2 :data:`SEAM_RADIUS`), the blend box
        (``blend // 2``), the feather's support test
        (:data:`~orthomvp.ortho.support.FEATHER_RADIUS`) and inpainting's
        (:data:`~orthomvp.ortho.holes.INPAINT_HALO`)."""
        seams = 2 * SEAM_RADIUS if self.seamlines else 0
        halo = INPAINT_HALO if self.holes == "inpaint" else 0
        labels = max(TRUST_RADIUS, SUPPORT_RADIUS) + seams + self.blend // 2
        return max(labels, FEATHER_RADIUS) + halo


@dataclass
class Composite:
    """A composed window: ``data`` (bands, rows, cols) float32, NaN where empty; ``source``
    (rows, cols) the 1-based view each post is labelled with, or where the feather's test
    moved the label's weight the view of largest weight (0: none); ``flags`` (rows, cols)
    :class:`Flag`; ``weights`` (views, rows, cols) float32, each view's share; ``resampled``
    (views, rows, cols) where a view's value is the blend of its clear pixels
    (:func:`~orthomvp.ortho.support.sharpen`; None: not tested)."""

    data: np.ndarray
    source: np.ndarray
    flags: np.ndarray
    weights: np.ndarray
    resampled: np.ndarray | None = None


def box_sum(a: np.ndarray, radius: int) -> np.ndarray:
    """Exact sums of integer array ``a`` (..., rows, cols) over the (2 radius + 1)^2 box
    around each post, zero beyond the array (int64). OpenCV's box filter: sums of integers
    come out exact in any order below 2^53 in float64, and below 2^24 in float32, where
    boolean and uint8 arrays are summed without a conversion (at most 255 (2 radius + 1)^2)."""
    a = np.asarray(a)
    k = 2 * radius + 1
    small = a.dtype in (np.bool_, np.uint8) and 255 * k * k < 1 << 24
    planes = a.reshape(-1, *a.shape[-2:])
    planes = np.ascontiguousarray(planes).view(np.uint8) if small else planes.astype(np.float64)
    depth = cv2.CV_32F if small else cv2.CV_64F
    out = np.empty(planes.shape, np.int64)
    for i, plane in enumerate(planes):
        out[i] = cv2.boxFilter(
            plane, depth, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT
        )
    return out.reshape(a.shape)


def visible_median(values: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """The median (bands, rows, cols) of ``values`` (views, bands, rows, cols) over the views
    ``visible`` (views, rows, cols) at each post, NaN where none is: ``np.nanmedian`` of the
    values with NaN where not visible, bit for bit, without its warnings (which cannot be
    silenced thread-safely). Up to :data:`NETWORK_LAYERS` views are sorted by an odd-even
    transposition network of elementwise minima and maxima (hidden values as +inf, last;
    3x faster than numpy's sort for 4 views), more by one sort along a contiguous axis."""
    k = len(values)
    hidden = np.where(visible[:, None], values, np.inf)
    n = np.count_nonzero(visible, axis=0)[None]  # (1, rows, cols): the same for every band
    lows, highs = np.maximum(n - 1, 0) // 2, n // 2
    if k > NETWORK_LAYERS:
        s = np.sort(np.moveaxis(hidden, 0, -1), axis=-1)
        n = np.broadcast_to(n, s.shape[:-1])
        low = np.take_along_axis(s, np.broadcast_to(lows, n.shape)[..., None], -1)[..., 0]
        high = np.take_along_axis(s, np.broadcast_to(highs, n.shape)[..., None], -1)[..., 0]
    else:
        layers = list(hidden)  # sorted in place, with one spare buffer: nothing is allocated
        spare = np.empty_like(layers[0])
        for i in range(k):
            for j in range(i % 2, k - 1, 2):
                a, b = layers[j], layers[j + 1]
                np.minimum(a, b, out=spare)
                np.maximum(a, b, out=b)
                layers[j], spare = spare, a
        low, high = layers[0].copy(), layers[0]  # the middle layers, at most k // 2:
        for j in range(1, k):  # (n - 1) // 2 into low, n // 2 into high (the first layer's)
            if j <= (k - 1) // 2:
                np.copyto(low, layers[j], where=np.broadcast_to(lows == j, low.shape))
            if j <= k // 2:
                np.copyto(high, layers[j], where=np.broadcast_to(highs == j, high.shape))
    with np.errstate(invalid="ignore", over="ignore"):  # (two huge values: an infinite sum)
        middle = (low + high).astype(values.dtype, copy=False)
        middle /= 2
    middle[np.broadcast_to(n == 0, middle.shape)] = np.nan
    return middle


def priority_cost(
    priority: str, emission: np.ndarray, gsd: np.ndarray, nadir: np.ndarray, usable: np.ndarray
) -> np.ndarray:
    """Cost (views, rows, cols) of each view's ``priority`` at each post: emission or
    off-nadir angle (degrees) / 90, GSD over the finest usable one at the post minus 1 (at
    most 1), or :data:`ORDER_STEP` times the view's index. ``usable`` (views, rows, cols)
    masks the views that can give the post."""
    if priority == "emission":
        return emission / 90.0
    if priority == "nadir":
        return nadir / 90.0
    if priority == "order":
        k = np.arange(len(usable), dtype=np.float64)[:, None, None]
        return np.broadcast_to(ORDER_STEP * k, usable.shape).astype(np.float64)
    g = np.where(usable, gsd, np.inf)
    finest = g.min(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.minimum(gsd / np.where(np.isfinite(finest), finest, 1.0) - 1.0, 1.0)


def disagreement(values: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Each view's disagreement (views, rows, cols) in 0..1 with the median of the views that
    see the post (mean over bands of :data:`DISAGREE` times the relative difference, capped)."""
    median = visible_median(values, visible)
    with np.errstate(all="ignore"):  # in place: |v - m| / (|v| + |m| + 1e-12), in that order
        rel = np.subtract(values, median)
        np.abs(rel, out=rel)
        scale = np.abs(values)
        scale += np.abs(median)
        scale += 1e-12
        rel /= scale
        rel *= DISAGREE
        np.fmin(rel, 1.0, out=rel)  # NaN (from infinite values) as 1
    return np.where(visible, rel.mean(axis=1), 1.0)


def doubtful(miss: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """Where a view's first hit (``miss``, posts; inf where the ray found nothing) lies within
    its epsilon ``eps`` but farther than ``eps`` - :data:`~orthomvp.codes.DOUBT` from the post."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(miss) & (miss > eps - DOUBT)


def trusted(
    visible: np.ndarray, doubt: np.ndarray | None = None, blocked: np.ndarray | None = None
) -> np.ndarray:
    """The views (views, rows, cols) a post may take among those ``visible``: never one in
    ``doubt``; those not ``blocked`` (their sample reaches an occluder in the image,
    :mod:`orthomvp.ortho.support`) where the post has one; among them, the views with all posts
    within :data:`TRUST_RADIUS` visible (off the grid counts as visible) where the post has
    one, else those with its four nearest neighbours visible, else the others."""
    sure = visible if doubt is None else visible & ~doubt
    box = np.ones((2 * TRUST_RADIUS + 1,) * 2, np.uint8)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    tier = np.zeros(visible.shape, np.uint8)
    for k, plane in enumerate(np.ascontiguousarray(visible).view(np.uint8)):
        # erosions of the view's visible posts, with every post off the grid visible
        four = cv2.erode(plane, cross, borderType=cv2.BORDER_CONSTANT, borderValue=1)
        every = cv2.erode(plane, box, borderType=cv2.BORDER_CONSTANT, borderValue=1)
        clear = 4 if blocked is None else np.where(blocked[k], 0, 4).astype(np.uint8)
        tier[k] = np.where(sure[k], 1 + four + every + clear, 0)
    return sure & (tier == tier.max(axis=0))


def labels(
    cost: np.ndarray,
    visible: np.ndarray,
    values: np.ndarray,
    seamlines: bool,
    *,
    fused: bool = False,
) -> np.ndarray:
    """The 0-based view of each post (-1 where none is ``visible``): least priority ``cost``,
    or with ``seamlines`` least seam cost (module docstring); ``fused``: with the numba
    kernels of :mod:`orthomvp.ortho.composite_kernel` (the same labels)."""
    if fused:
        from orthomvp.ortho import composite_kernel as kernel

        radius = SEAM_RADIUS if seamlines else None
        return kernel.labels(cost, visible, values, radius, QUANT, DISAGREE)
    if seamlines:
        inside = box_sum(np.ones(visible.shape[1:], np.uint8), SEAM_RADIUS)
        seen = box_sum(visible, SEAM_RADIUS)
        # in place: cost (NaN as 0) + (1 - seen / inside) + disagreement where visible, 0
        # elsewhere
        total = np.array(cost, dtype=np.float64)
        total[np.isnan(total)] = 0.0
        total += 1.0 - seen / inside
        total += disagreement(values, visible)
        total[~visible] = 0.0
        total *= QUANT
        q = np.rint(total, out=total).astype(np.int64)
        with np.errstate(invalid="ignore", divide="ignore"):
            cost = box_sum(q, SEAM_RADIUS) / seen
    cost = np.where(visible, cost, np.inf)
    best = np.argmin(cost, axis=0)
    return np.where(visible.any(axis=0), best, -1)


def nadir_angle(
    grid: Terrain, inner: tuple[slice, slice], camera: Camera, uv: np.ndarray
) -> np.ndarray:
    """Degrees between the local vertical and the direction to the camera at the posts
    ``inner`` of ``grid``, imaged at ``uv`` (NaN where the camera does not image the post)."""
    p = grid.world_points()[inner]
    d = camera.origins(uv) - p
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    cos = np.einsum("...i,...i->...", d, grid.up_vectors(p))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def compose(
    values: np.ndarray,
    codes: np.ndarray,
    emission: np.ndarray,
    gsd: np.ndarray,
    nadir: np.ndarray,
    options: MosaicOptions,
    correction: Correction | None = None,
    doubt: np.ndarray | None = None,
    *,
    slack: np.ndarray | None = None,
    blocked: np.ndarray | None = None,
    support: Support | None = None,
    resample: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
    fused: bool = False,
) -> Composite:
    """Compose a mosaic window from per-view ``values`` (views, bands, rows, cols) float32
    (each view's naive samples, NaN outside its image), visibility ``codes`` (views, rows,
    cols), and the views' ``emission`` and ``nadir`` angles (degrees) and ``gsd`` (metres) at
    each post, following ``options``, after ``correction``; ``doubt`` (views, rows, cols)
    marks the visible posts a view is doubtful at (:func:`doubtful`; None: none) and
    ``slack`` (views, rows, cols) its epsilon minus its miss there (posts), the margin by
    which :func:`orthomvp.ortho.holes.fill_holes` picks a doubtful view; ``blocked`` (views,
    rows, cols) where a view's sample reaches an occluder (:func:`trusted`), and ``support``
    tells it at the posts that blend several views (:func:`shun`; None: not done) and at the
    posts with weight near the view's occlusion boundary, where ``resample`` then gives the
    samples of the blocked views' clear pixels (:func:`~orthomvp.ortho.support.sharpen`) and
    of the doubtful views at posts only they see, by every hole policy but ``empty``
    (:func:`~orthomvp.ortho.support.fill_doubtful`; None: not done). ``fused``:
    labels and blend with the numba kernels of :mod:`orthomvp.ortho.composite_kernel` (the same
    result, bit for bit; about 3.5x faster, after a load of about 0.3 s a process)."""
    values = np.ascontiguousarray(values if correction is None else correction.apply(values))
    finite = np.isfinite(values).all(axis=1)
    visible = trusted((codes == Code.VISIBLE) & finite, doubt, blocked)
    cost = np.ascontiguousarray(priority_cost(options.priority, emission, gsd, nadir, visible))
    label = labels(cost, visible, values, options.seamlines, fused=fused)
    n, bands, rows, cols = values.shape
    if fused:
        from orthomvp.ortho.composite_kernel import blend

        weights, data = blend(label, visible, values, options.blend // 2)
    else:
        onehot = label[None] == np.arange(n)[:, None, None]
        if options.blend // 2:
            votes = box_sum(onehot, options.blend // 2) * visible
            votes = np.where(visible.any(axis=0), votes, 0)
        else:
            votes = onehot.astype(np.int64)
        total = votes.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            weights = (votes / np.where(total > 0, total, 1)).astype(np.float32)
        weights[:, total == 0] = onehot[:, total == 0]
        data = np.einsum("krc,kbrc->brc", weights, np.where(visible[:, None], values, 0))
        data = data.astype(np.float32)
        data[:, label < 0] = np.nan
    crisp, moved = None, None
    if support is not None:
        moved = shun(weights, data, values, blocked, support)
        if resample is not None and options.clear:
            crisp = sharpen(weights, data, values, support, resample, correction)
    seen = label >= 0
    cleared = None
    if resample is not None and doubt is not None and options.clear and options.holes != "empty":
        usable = (codes == Code.VISIBLE) & finite & doubt
        cleared = fill_doubtful(data, label, weights, usable, resample, correction)
    flags = fill_holes(
        data,
        label,
        weights,
        values=values,
        codes=codes,
        finite=finite,
        doubt=doubt,
        slack=slack,
        cost=cost,
        nadir=nadir,
        holes=options.holes,
    )
    flags[seen] = Flag.VISIBLE
    if cleared is not None:
        flags[cleared] = Flag.DOUBTFUL
    source = label if moved is None or not moved.any() else heaviest(label, weights, moved)
    return Composite(data, source.astype(np.int64) + 1, flags, weights, crisp)


def overlap_width(codes: np.ndarray, step: float = 1.0) -> float:
    """Width of the widest overlap of two images' footprints, posts: twice the largest distance
    from a post inside both images to one outside either, on a grid whose posts are ``step``
    posts apart (``codes`` (views, rows, cols); inside an image: any code but NODATA, so
    occlusion does not narrow it and a survey without ray casting gives the same width)."""
    inside = codes != Code.NODATA
    widest = 0.0
    for i in range(len(codes)):
        for j in range(i + 1, len(codes)):
            both = inside[i] & inside[j]
            if both.any():
                inner = np.pad(both, 1).astype(np.uint8)
                edt = cv2.distanceTransform(inner, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
                widest = max(widest, 2 * float(edt.max()) * step)
    return widest


def clamp_blend(blend: int, widest: float) -> int:
    """``blend``, or the ``widest`` overlap (posts, rounded down) with a
    :class:`BlendWarning` when it is wider than that."""
    if widest > 0 and blend > widest:
        clamped = int(widest)
        warnings.warn(
            f"blend width {blend} posts is wider than the widest overlap of two images "
            f"({widest:.0f} posts): blending over {clamped} posts",
            BlendWarning,
            stacklevel=3,
        )
        return clamped
    return blend


def seam_visibility(data: np.ndarray, source: np.ndarray) -> float:
    """How visible a mosaic's seams are: the median absolute difference (mean over bands)
    between 4-neighbour posts labelled with different views, over the same median between
    neighbours labelled with one view; 1 means seams cannot be told from texture. ``data``
    (bands, rows, cols) with NaN where empty, ``source`` (rows, cols) the 1-based view (0:
    none), as :class:`~orthomvp.ortho.orthophoto.Mosaic` and the source raster's band 1 give them.
    NaN when there is no seam or no pair within one view."""
    data = np.asarray(data, dtype=np.float64)
    source = np.asarray(source)
    if data.ndim != 3 or source.shape != data.shape[1:]:
        raise InputError(
            f"seam visibility needs data (bands, rows, cols) and source (rows, cols) of the same "
            f"grid, got {data.shape} and {source.shape}"
        )
    ok = np.isfinite(data).all(axis=0) & (source > 0)
    across, within = [], []
    for a, b in (
        ((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
        ((slice(1, None), slice(None)), (slice(None, -1), slice(None))),
    ):
        pair = ok[a] & ok[b]
        diff = np.abs(data[(slice(None), *a)] - data[(slice(None), *b)]).mean(axis=0)
        seam = source[a] != source[b]
        across.append(diff[pair & seam])
        within.append(diff[pair & ~seam])
    across, within = np.concatenate(across), np.concatenate(within)
    if not len(across) or not len(within):
        return float("nan")
    inside = float(np.median(within))
    return float(np.median(across)) / inside if inside > 0 else float("inf")
