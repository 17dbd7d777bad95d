"""Whether a view's sample at a post reaches an occluder in the image: the mosaic's margin in
image space from the occlusion boundary.

A post's value from a view is a bilinear sample of the four pixels around its image position,
and each pixel integrates its own footprint: the sample reaches about 1.5 pixels around the
position. A post whose own ray is clear can still have an occluder (a roof edge, a wall top,
a crown) within that reach in the image, just beside its line of sight: part of its value is
then the occluder's (a partial ghost), most often at wall feet, where the visible ground
starts just past a roof edge's shadow. The test casts the rays through the four points
:data:`OFFSET` pixels diagonally from the post's position on the occluder surface the
visibility test casts on, and calls the sample blocked where one of them first hits the surface
nearer the camera than the post and farther from it than :data:`REACH` times the ground the
offset spans there (:data:`OFFSET` pixels of the GSD facing the camera over the cosine of the
off-nadir angle: level ground, not the surface model's slope, which is steep at every wall
foot): the post's own ground, or a wall rising at its foot, stays nearer. Only posts near the
view's own occlusion boundary (:data:`RADIUS`) that another view sees too are tested
(:func:`candidates`).

The mosaic (:func:`orthomvp.ortho.composite.trusted`) then prefers, among the views it trusts
at a post, those whose sample is not blocked; where every view's is, it takes them as before,
so no post is lost. After labelling, :func:`shun` also tests the views that share a post's
blend within :data:`FEATHER_RADIUS` of their occlusion boundary and moves a blocked view's
weight to the others there (the seamlines stay). Where a view with weight within
:data:`RADIUS` of its boundary is still blocked, :func:`sharpen` takes the bilinear blend of
its clear pixels only (:func:`clear_taps`: the pixels whose centre ray, and the test's ray
beyond them, reach no occluder). :class:`Support` asks the test once per post and view.
Rays that the DEM's heights prove clear are not cast, and the others are cast on a mesh of
the cells they pass over (:meth:`~orthomvp.occlusion.occluders.Occluders.clear`,
``cast_from``). Measured against the city's exact geometry in docs/mosaics.md.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import cv2
import numpy as np

from orthomvp.occlusion.occluders import Occluders

if TYPE_CHECKING:
    from orthomvp.camera import Camera
    from orthomvp.geometry.terrain import Terrain
    from orthomvp.occlusion.raycast import RayCaster
    from orthomvp.ortho.balance import Correction

RADIUS = 3
"""Box radius, posts: a view's sample is tested only at posts with a post within it that the
view does not see (near its own occlusion boundary). Tested everywhere, the demotions cut
seamlines into pieces on smooth terrain (blended seams on the crater 1.38 against 1.2), and the
rays cost 3.4 times the whole ngi-aerial mosaic."""

FEATHER_RADIUS = 15
"""Box radius, posts: :func:`shun` tests the views that share a post's blend only where they
do not see some post within it (on the 160-post city, the blend posts whose partial ghosts it
removes lie 4 to 14 posts from the view's occlusion boundary; the mosaic's default margin, 15
posts, then needs no growth). At every blend post, ngi-aerial's mosaic would test about ten
times as many posts (0.5 M against 49 k), mostly on open ground, and take 6 s more."""

OFFSET = 1.5
"""Pixels from a post's image position, along each image axis, of the four support rays (the
bilinear taps' pixels reach 1.5 pixels; on the city 1.5 leaves fewer partial ghosts than 1 or
2)."""

DIRECTIONS = ((-1, -1), (1, -1), (-1, 1), (1, 1))
"""Directions of the support rays in the image (u, v), :data:`OFFSET` pixels along each axis
(the four axis directions as well change nothing on the city)."""

REACH = 2.0
"""Multiple of the ground that :data:`OFFSET` pixels span at a post beyond which a support
ray's first hit nearer the camera than the post is an occluder (on the city, 0.5 m posts and
0.25 m pixels: about 2 posts)."""


PostSamples = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""A view's image positions (n, 2) and ground sample distances (n,) at posts (rows, cols) (n,)
of a window: :func:`window_samples` of whole-window arrays, or what a mosaic tile keeps
(:meth:`orthomvp.engine.support_samples.SupportSamples.at`)."""


def window_samples(uv: np.ndarray, gsd: np.ndarray) -> PostSamples:
    """The :data:`PostSamples` of image positions ``uv`` (rows, cols, 2) and ground sample
    distances ``gsd`` (rows, cols) of a whole window."""
    return lambda rows, cols: (uv[rows, cols], gsd[rows, cols])


def blocked(
    grid: Terrain,
    inner: tuple[slice, slice],
    camera: Camera,
    samples: PostSamples,
    emission: np.ndarray,
    test: np.ndarray,
    caster: RayCaster | Occluders,
) -> np.ndarray:
    """Where (rows, cols) the sample of ``camera`` at the posts ``inner`` of ``grid`` (image
    positions and ground sample distances, metres, of ``samples``, and emission angles
    ``emission`` (rows, cols) degrees of :class:`~orthomvp.occlusion.visibility.Visibility`)
    reaches an occluder (module docstring), tested at the posts ``test`` (rows, cols) only
    (False elsewhere); ``caster`` casts on the occluder surface (world frame, metres)."""
    out = np.zeros(test.shape, bool)
    if not test.any():
        return out
    rows, cols = np.nonzero(test)
    uv, gsd = samples(rows, cols)
    shifts = OFFSET * np.array(DIRECTIONS, np.float64)  # all four rays of a post in one cast
    at = uv[None] + shifts[:, None]
    far = _occluders(grid, inner, camera, rows, cols, at, gsd, emission, caster).any(axis=0)
    out[rows[far], cols[far]] = True
    return out


def clear_taps(
    grid: Terrain,
    inner: tuple[slice, slice],
    camera: Camera,
    samples: PostSamples,
    emission: np.ndarray,
    posts: np.ndarray,
    caster: RayCaster | Occluders,
) -> tuple[np.ndarray, np.ndarray]:
    """The bilinear sample's four pixels at the posts ``posts`` (rows, cols; in the order of
    ``np.nonzero``), as :func:`blocked` takes its arguments: their positions (4, n, 2), whole
    pixels (u, v), and bilinear weights (4, n), zero where the ray through the pixel's centre,
    or :func:`blocked`'s ray beyond it (:data:`OFFSET` pixels diagonally from the post's
    position, on the pixel's side), first hits an occluder (the rule of :func:`blocked`)."""
    rows, cols = np.nonzero(posts)
    uv, gsd = samples(rows, cols)
    # the positions as the samples take them (float32: equal in every window that holds them)
    at = uv.astype(np.float32).astype(np.float64)
    base = np.floor(at)
    frac = at - base
    steps = np.array([(0, 0), (1, 0), (0, 1), (1, 1)], np.float64)  # (du, dv)
    taps = base[None] + steps[:, None]
    weights = np.where(steps[:, None, :] > 0, frac[None], 1 - frac[None]).prod(axis=-1)
    beyond = at[None] + OFFSET * (2 * steps[:, None] - 1)
    rays = np.concatenate([taps, beyond])  # all eight rays of a post in one cast
    hit = _occluders(grid, inner, camera, rows, cols, rays, gsd, emission, caster)
    return taps, np.where(hit[:4] | hit[4:], 0.0, weights)


def clear_blend(pixels: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sample (bands, n) float32 of the pixels ``pixels`` (4, bands, n) with ``weights``
    (4, n) of :func:`clear_taps`, renormalised over those with a value (NaN where no weight
    is left), and the weight (n,) of those pixels before that."""
    w = np.where(np.isfinite(pixels).all(axis=1), weights, 0.0)
    total = w[0] + w[1] + w[2] + w[3]  # (in one order: the same sum in any window)
    out = w[0] * np.nan_to_num(pixels[0])
    for t in (1, 2, 3):
        out += w[t] * np.nan_to_num(pixels[t])
    with np.errstate(invalid="ignore", divide="ignore"):
        out /= total
    return np.where(total > 0, out, np.nan).astype(np.float32), total


def _occluders(
    grid: Terrain,
    inner: tuple[slice, slice],
    camera: Camera,
    rows: np.ndarray,
    cols: np.ndarray,
    at: np.ndarray,
    gsd: np.ndarray,
    emission: np.ndarray,
    caster: RayCaster | Occluders,
) -> np.ndarray:
    """Whether (m, n) the rays through the pixel positions ``at`` (m, n, 2) first hit an
    occluder of the posts (``rows``, ``cols``) (n,) of ``inner``, whose ground sample
    distances are ``gsd`` (n,) (module docstring; the other arguments as :func:`blocked`
    takes them), all in one cast."""
    r0, c0 = inner[0].start or 0, inner[1].start or 0
    height = grid.values[inner][rows, cols]
    points = grid.to_world((cols + c0).astype(np.float64), (rows + r0).astype(np.float64), height)
    size = REACH * OFFSET * facing_gsd(gsd, emission[rows, cols])
    up = grid.up_vectors(points)
    m = len(at)
    o, d = camera.ray(at.reshape(-1, 2))
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    points, up = np.tile(points, (m, 1)), np.tile(up, (m, 1))
    along = np.einsum("ij,ij->i", points - o, unit)
    level = np.abs(np.einsum("ij,ij->i", unit, up))
    reach = np.tile(size, m) / np.maximum(level, 0.1)
    return _far_hits(caster, o, unit, along, points, reach).reshape(m, -1)


def _far_hits(
    caster: RayCaster | Occluders,
    o: np.ndarray,
    unit: np.ndarray,
    along: np.ndarray,
    points: np.ndarray,
    reach: np.ndarray,
) -> np.ndarray:
    """Which rays (origins ``o``, unit directions ``unit``, (n, 3) world frame) first hit the
    occluder surface nearer their origin than ``along`` (n,) and more than ``reach`` (n,) from
    ``points`` (n, 3), metres. On :class:`~orthomvp.occlusion.occluders.Occluders` from one
    origin (a frame camera), rays that the DEM's heights prove clear far enough before the point
    at ``along`` are not cast, and the others are cast on a mesh of the cells they pass over:
    the same answer for a fraction of the cost (no whole mesh built for a few rays)."""
    n = len(unit)
    ok = np.isfinite(unit).all(axis=1) & np.isfinite(along)
    single = n > 0 and bool((o == o[0]).all())
    if not (isinstance(caster, Occluders) and caster.provable and single):
        hits = caster.first_hit(o, unit, invalid="miss")
        front = hits.mask & (hits.distance < along)
        with np.errstate(invalid="ignore"):
            return front & (np.linalg.norm(hits.points - points, axis=1) > reach)
    centre = o[0]
    q = centre + along[:, None] * unit  # the point of the ray at the post's depth
    # a hit within ``slack`` of q horizontally, before it, lies within ``reach`` of the post
    # (its distance from q is the horizontal one over the ray's horizontal component); a
    # millionth less against rounding
    horizontal = np.hypot(unit[:, 0], unit[:, 1])
    with np.errstate(invalid="ignore"):
        slack = (reach - np.linalg.norm(q - points, axis=1)) * horizontal * (1 - 1e-6)
    cast = ok.copy()
    proved = (slack >= 0) & ok
    if proved.any():
        cast[proved] = ~caster.clear(q[proved], centre, slack[proved])
    far = np.zeros(n, bool)
    if cast.any():
        hits = caster.cast_from(centre, q[cast], 0.0)
        front = hits.mask & (hits.distance < along[cast])
        with np.errstate(invalid="ignore"):
            far[cast] = front & (np.linalg.norm(hits.points - points[cast], axis=1) > reach[cast])
    return far


def shun(
    weights: np.ndarray,
    data: np.ndarray,
    values: np.ndarray,
    blocked: np.ndarray | None,
    support: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """After labelling and blending, in place on ``weights`` (views, rows, cols) and ``data``
    (bands, rows, cols): where a post takes weight from more than one
    view, ``support`` (called once with those posts, views x rows x cols, and returning where
    the views' samples reach an occluder in the image, :mod:`orthomvp.ortho.support`) says
    which are blocked, on top of ``blocked``; where some views with weight are blocked and
    others are not, the blocked ones' weight goes to the others in proportion to theirs and
    the post's value is blended anew from ``values`` (views, bands, rows, cols, balanced).
    The labels (seamlines) stay as they were: only the feather avoids occluders. Returns the
    posts (rows, cols) whose weights moved."""
    given = weights > 0
    shared = given & (given.sum(axis=0) > 1)
    if not shared.any():
        return np.zeros(weights.shape[1:], bool)
    bad = given & support(shared)
    if blocked is not None:
        bad |= given & blocked
    keep = given & ~bad
    fix = bad.any(axis=0) & keep.any(axis=0)
    if not fix.any():
        return fix
    w = np.where(keep[:, fix], weights[:, fix], np.float32(0))
    w /= w.sum(axis=0)
    weights[:, fix] = w
    taken = np.where(w[:, None] > 0, values[:, :, fix], np.float32(0))
    data[:, fix] = np.einsum("kn,kbn->bn", w, taken).astype(np.float32)
    return fix


def facing_gsd(gsd: np.ndarray, emission: np.ndarray) -> np.ndarray:
    """The ground sample distance (metres) on a surface facing the camera, from the one along
    the surface (``gsd``) and the emission angle (degrees) of
    :class:`~orthomvp.occlusion.visibility.Visibility` (which divides it by the cosine, at
    least 0.1)."""
    return gsd * np.maximum(np.cos(np.radians(emission)), 0.1)


def near(visible: np.ndarray, radius: int) -> np.ndarray:
    """The posts (views, rows, cols) a view sees (``visible``) that have a post within the box
    ``radius`` it does not see (off the grid counts as seen): near its occlusion boundary."""
    box = np.ones((2 * radius + 1,) * 2, np.uint8)
    out = np.zeros(visible.shape, bool)
    for k, plane in enumerate(np.ascontiguousarray(visible).view(np.uint8)):
        inner = cv2.erode(plane, box, borderType=cv2.BORDER_CONSTANT, borderValue=1)
        out[k] = visible[k] & (inner == 0)
    return out


def candidates(visible: np.ndarray, radius: int = RADIUS) -> np.ndarray:
    """The posts (views, rows, cols) where the trust test asks :func:`blocked`: :func:`near`
    the view's occlusion boundary within ``radius`` (``visible`` (views, rows, cols), doubtful
    posts left out) where another view sees the post too."""
    return near(visible, radius) & (visible.sum(axis=0) > 1)


class Support:
    """The support test over one window, each post and view asked once: ``test`` (called with
    posts (views, rows, cols), returning where the views' samples there reach an occluder,
    :func:`blocked`) runs only at the posts :func:`near` a view's occlusion boundary within
    :data:`FEATHER_RADIUS` (of ``visible`` (views, rows, cols), doubtful posts left out) not
    asked before; calling the instance with posts returns where they are blocked (False where
    never tested). ``close``: the posts within :data:`RADIUS` of the boundary, where
    :func:`sharpen` asks."""

    def __init__(self, test: Callable[[np.ndarray], np.ndarray], visible: np.ndarray) -> None:
        self._test = test
        self.allowed = near(visible, FEATHER_RADIUS)
        self.close = near(visible, RADIUS)
        self.tested = np.zeros(visible.shape, bool)
        self.blocked = np.zeros(visible.shape, bool)

    def __call__(self, posts: np.ndarray) -> np.ndarray:
        new = posts & self.allowed & ~self.tested
        if new.any():
            self.blocked |= self._test(new) & new
            self.tested |= new
        return self.blocked & posts


def sharpen(
    weights: np.ndarray,
    data: np.ndarray,
    values: np.ndarray,
    support: Support,
    resample: Callable[[np.ndarray], np.ndarray],
    correction: Correction | None = None,
) -> np.ndarray:
    """After :func:`shun`, in place on ``data`` (bands, rows, cols): where a view with weight
    (``weights`` (views, rows, cols)) within :data:`RADIUS` of its occlusion boundary is still
    blocked (``support``; on the 160-post city every partial ghost among the samples it blocks
    farther out is within 4 posts, 230 of 232 within 3), its
    bilinear sample in ``values`` (views, bands, rows, cols, balanced) gives way to the
    bilinear blend of its clear pixels only (:func:`clear_taps`, :func:`clear_blend`) and the
    post is blended anew. ``resample`` (called once with those posts, views x rows x cols)
    returns their samples (bands, posts) in the order of ``np.nonzero``, before
    ``correction``, and their clear pixels' weights (posts,) (:func:`clear_blend`); NaN (no
    clear pixel) keeps the bilinear sample. Returns where (views, rows, cols) a view's value
    was resampled."""
    given = weights > 0
    at = given & support(given & support.close)
    if not at.any():
        return at
    kk, rr, cc = np.nonzero(at)
    crisp = _corrected(resample(at)[0], kk, correction)
    ok = np.isfinite(crisp).all(axis=0)
    at[kk[~ok], rr[~ok], cc[~ok]] = False
    kk, rr, cc, crisp = kk[ok], rr[ok], cc[ok], crisp[:, ok]
    fix = at.any(axis=0)
    fr, fc = np.nonzero(fix)
    index = np.zeros(fix.shape, np.int64)
    index[fr, fc] = np.arange(len(fr))
    taken = values[:, :, fr, fc]  # (views, bands, posts)
    taken[kk, :, index[rr, cc]] = crisp.T
    w = weights[:, fr, fc]
    blend = np.zeros(taken.shape[1:], np.float32)
    for k in range(len(w)):  # view by view, those with weight (a window's views as the grid's)
        if (w[k] > 0).any():
            blend += np.where(w[k] > 0, w[k] * taken[k], np.float32(0))
    data[:, fr, fc] = blend
    return at


def fill_doubtful(
    data: np.ndarray,
    label: np.ndarray,
    weights: np.ndarray,
    doubtful: np.ndarray,
    resample: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    correction: Correction | None = None,
) -> np.ndarray:
    """In place on ``data`` (bands, rows, cols), ``label`` (rows, cols; -1 where no trusted
    view gives the post) and ``weights`` (views, rows, cols): a post that no trusted view
    gives and that views call visible only doubtfully (``doubtful`` (views, rows, cols)) takes
    the sample of the clear pixels (:func:`clear_taps`) of the doubtful view whose clear
    pixels weigh most (the first on ties), where any is clear; ``resample`` and
    ``correction`` as :func:`sharpen` takes them. On the cities of 160 posts (seeds 0, 1 and
    2) and 96 posts, 3 of the 23 such posts have a doubtful view with a clear pixel, all three
    truly visible in it (their samples still hold an occluder); of the 20 without, 11 are
    hidden. Returns the posts (rows, cols) filled."""
    at = doubtful & (label < 0)[None]
    got = np.zeros(label.shape, bool)
    if not at.any():
        return got
    kk, rr, cc = np.nonzero(at)
    samples, clear = resample(at)
    samples = _corrected(samples, kk, correction)
    ok = (clear > 0) & np.isfinite(samples).all(axis=0)
    score = np.zeros(at.shape)
    score[kk[ok], rr[ok], cc[ok]] = clear[ok]
    best = np.argmax(score, axis=0)
    got = score.max(axis=0) > 0
    index = np.full(at.shape, -1, np.int64)
    index[kk, rr, cc] = np.arange(len(kk))
    gr, gc = np.nonzero(got)
    data[:, gr, gc] = samples[:, index[best[gr, gc], gr, gc]]
    weights[:, got] = best[got][None] == np.arange(len(weights))[:, None]
    label[got] = best[got]
    return got


def _corrected(samples: np.ndarray, views: np.ndarray, correction: Correction | None) -> np.ndarray:
    """``samples`` (bands, n) of the views ``views`` (n,) after ``correction`` (float32, as
    :meth:`~orthomvp.ortho.balance.Correction.apply` gives them)."""
    if correction is None:
        return samples
    gains, offsets = correction.gains[views].T, correction.offsets[views].T
    return (samples * gains + offsets).astype(np.float32)


def heaviest(label: np.ndarray, weights: np.ndarray, moved: np.ndarray) -> np.ndarray:
    """The 0-based view (rows, cols) int64 of each post: its ``label`` (-1: none), but where
    the feather's test moved the weights (``moved`` (rows, cols), :func:`shun`, which can take
    all of a label's weight away) the view of largest weight (``weights`` (views, rows, cols))
    unless the label weighs as much."""
    top = np.argmax(weights, axis=0)
    own = np.take_along_axis(weights, np.maximum(label, 0)[None], axis=0)[0]
    keep = (own >= np.take_along_axis(weights, top[None], axis=0)[0]) | ~moved
    return np.where(label < 0, -1, np.where(keep, label, top)).astype(np.int64)
