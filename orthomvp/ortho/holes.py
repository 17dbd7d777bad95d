"""A mosaic's holes: the posts no trusted view gives a value, how each hole policy fills them,
and why each post left empty is empty.

Policies (:data:`HOLES`, ``--holes``), after the trusted views of
:func:`orthomvp.ortho.composite.trusted` have given every post they can:

- ``empty`` (default, a true orthophoto): holes stay empty.
- ``behind``: a post that some view sees only doubtfully (its first hit in the last
  :data:`~orthomvp.codes.DOUBT` posts of epsilon) takes the sample of the clear pixels of the
  doubtful view whose clear pixels weigh most (:func:`orthomvp.ortho.support.fill_doubtful`),
  else the doubtful view with the largest margin (epsilon minus the miss, posts; the first
  view on ties), flagged :attr:`Flag.DOUBTFUL`; any other hole takes the least-cost view
  that images it facing away (from behind; never one that calls it occluded), flagged
  :attr:`Flag.BEHIND`.
- ``inpaint``: doubtful posts as above, then OpenCV's Navier-Stokes inpainting
  (``cv2.inpaint`` with ``INPAINT_NS``, :data:`INPAINT_RADIUS` posts) of every hole whose
  8-connected component fits in :data:`INPAINT_SIZE` x :data:`INPAINT_SIZE` posts, from the
  filled posts around it, flagged :attr:`Flag.INPAINTED`; larger holes stay empty. OpenCV is
  already a dependency and its inpainting is maintained; of its two methods, Navier-Stokes
  takes float32 bands as they are, while Telea's on float32 returns values far outside the
  data in OpenCV 5.0 (a ramp from 0.37 to 0.43 inpainted as -0.8 to 1.6) and would otherwise
  need the bands quantised to 8 or 16 bits.
- ``naive``: doubtful posts as above, then the naive value (occluded included: a ghost) of
  the most nadir view imaging the post, flagged :attr:`Flag.NAIVE`.

Doubtful posts stay empty in the default policy because the city with exact truth shows that
their margin does not tell visible from hidden: of its 9 posts that only doubtful views see
(160 x 160 posts, 4 views, seed 0) 3 are visible in the view of the largest margin, 5 occluded
and 1 facing away. Clear pixels tell better (the 2 of the 9 with a doubtful view that has a
clear pixel are visible in it, and 1 of 10 on seed 1), but those samples still hold an occluder
against the truth.

Tiling. Every policy but ``inpaint`` decides each post from its own views. Inpainting a hole
component reads only the posts within :data:`INPAINT_RADIUS` of its bounding box, so a
component that touches a tile's core lies within ``INPAINT_SIZE - 1`` posts of it and reads
within :data:`INPAINT_HALO` - 1; the mosaic's margin grows by :data:`INPAINT_HALO`
(:attr:`orthomvp.ortho.composite.MosaicOptions.margin`), within which the composition is that
of the whole grid, so every tiling gives the same values. A component touching the window's
edge is never inpainted: within the margin that happens only at the grid's edge, where the
whole grid has the same edge.

Hole reasons (band 2 of the source raster with the fill flags, :class:`Flag`), over the views
that image the post (inside the image, with a pixel value where visible): none does
(:attr:`Flag.OUTSIDE`, also posts without a height; :attr:`Flag.NO_VALUE` where images see it
but have no pixel value there, nodata pixels or the image's edge), every one faces away
(:attr:`Flag.FACING_AWAY`), every one is occluded (:attr:`Flag.OCCLUDED`), each does one or
the other (:attr:`Flag.HIDDEN`), or some see it but all only doubtfully
(:attr:`Flag.DOUBTFUL_EMPTY`).
"""

from __future__ import annotations

from enum import IntEnum

import cv2
import numpy as np

from orthomvp.codes import Code

HOLES = ("empty", "behind", "inpaint", "naive")
"""Hole policies (module docstring)."""

FILL_ALIASES = {"none": "empty", "any-view": "behind", "naive": "naive"}
"""The hole policy of each value of the deprecated ``fill`` option (``--fill``)."""

INPAINT_SIZE = 16
"""Largest hole component inpainted: rows and columns of its bounding box, posts."""

INPAINT_RADIUS = 3
"""Neighbourhood of the inpainting, posts."""

INPAINT_HALO = INPAINT_SIZE + INPAINT_RADIUS
"""Posts the mosaic's margin grows by for inpainting (module docstring)."""


class Flag(IntEnum):
    """Band 2 of the source raster: how a post got its value, or why it has none."""

    OUTSIDE = 0
    """empty: outside every image (or no height)"""
    VISIBLE = 1
    """from the trusted views that see it"""
    BEHIND = 2
    """filled from a view that sees its surface from behind (facing away)"""
    NAIVE = 3
    """filled with the naive value of the most nadir view (a ghost where that view's occluded)"""
    DOUBTFUL = 4
    """filled from a doubtful view: the clear pixels of the one whose clear pixels weigh most,
    else the one of largest margin"""
    INPAINTED = 5
    """filled by inpainting from the posts around it"""
    FACING_AWAY = 8
    """empty: facing away in every view imaging it"""
    OCCLUDED = 9
    """empty: occluded in every view imaging it"""
    HIDDEN = 10
    """empty: occluded in some views imaging it, facing away in the others"""
    DOUBTFUL_EMPTY = 11
    """empty: seen only doubtfully (policy empty)"""
    NO_VALUE = 12
    """empty: inside images that have no pixel value there"""

    EMPTY = 0
    ANY_VIEW = 2

    @property
    def empty(self) -> bool:
        """Whether posts with this flag have no value."""
        return self in (Flag.OUTSIDE, *EMPTY_REASONS)

    @property
    def label(self) -> str:
        """Human-readable meaning (the command's summary)."""
        return _LABELS[self]


EMPTY_REASONS = (
    Flag.FACING_AWAY,
    Flag.OCCLUDED,
    Flag.HIDDEN,
    Flag.DOUBTFUL_EMPTY,
    Flag.NO_VALUE,
)
"""The flags of empty posts besides :attr:`Flag.OUTSIDE`."""

FLAGS = 13
"""Flag values counted per run (0 .. FLAGS - 1)."""

_LABELS = {
    Flag.OUTSIDE: "outside every image",
    Flag.VISIBLE: "visible",
    Flag.BEHIND: "filled from behind",
    Flag.NAIVE: "filled naive",
    Flag.DOUBTFUL: "filled from a doubtful view",
    Flag.INPAINTED: "inpainted",
    Flag.FACING_AWAY: "facing away in every view",
    Flag.OCCLUDED: "occluded in every view",
    Flag.HIDDEN: "occluded or facing away in every view",
    Flag.DOUBTFUL_EMPTY: "seen only doubtfully",
    Flag.NO_VALUE: "without a pixel value",
}


def reasons(codes: np.ndarray, finite: np.ndarray) -> np.ndarray:
    """Why each post would be empty (rows, cols) uint8 :class:`Flag`, from the views' ``codes``
    (views, rows, cols) and ``finite`` (views, rows, cols: the view has a pixel value): over
    the views imaging the post (module docstring); :attr:`Flag.DOUBTFUL_EMPTY` where one of them
    calls it visible (the trusted views, which never take a doubtful one, took all others)."""
    imaging = (codes != Code.NODATA) & ((codes != Code.VISIBLE) | finite)
    seen = (imaging & (codes == Code.VISIBLE)).any(axis=0)
    away = (imaging & (codes == Code.FACING_AWAY)).any(axis=0)
    hidden = (imaging & (codes == Code.OCCLUDED)).any(axis=0)
    out = np.full(codes.shape[1:], Flag.OUTSIDE, np.uint8)
    out[(codes != Code.NODATA).any(axis=0)] = Flag.NO_VALUE
    out[away] = Flag.FACING_AWAY
    out[hidden] = Flag.OCCLUDED
    out[away & hidden] = Flag.HIDDEN
    out[seen] = Flag.DOUBTFUL_EMPTY
    return out


def fill_holes(
    data: np.ndarray,
    label: np.ndarray,
    weights: np.ndarray,
    *,
    values: np.ndarray,
    codes: np.ndarray,
    finite: np.ndarray,
    doubt: np.ndarray | None,
    slack: np.ndarray | None,
    cost: np.ndarray,
    nadir: np.ndarray,
    holes: str,
) -> np.ndarray:
    """Fill the holes (``label`` -1) of a composed window by policy ``holes`` (:data:`HOLES`)
    in place: ``data`` (bands, rows, cols), ``label`` (rows, cols; the 0-based view given to
    a filled post, -1 where none or inpainted) and ``weights`` (views, rows, cols; one-hot
    where a view is given). Returns the :class:`Flag` of every hole (rows, cols) uint8, 0
    elsewhere. ``values`` (views, bands, rows, cols), ``codes`` and ``finite`` (views, rows,
    cols) as :func:`orthomvp.ortho.composite.compose` has them; ``doubt`` (views, rows, cols)
    the doubtful posts and ``slack`` epsilon minus the miss there (posts; None: none, and
    equal); ``cost`` and ``nadir`` (views, rows, cols) each view's priority cost and off-nadir
    angle (degrees)."""
    hole = label < 0
    flags = np.where(hole, reasons(codes, finite), 0).astype(np.uint8)
    if holes == "empty" or not hole.any():
        return flags
    rules = []
    if doubt is not None:
        usable = (codes == Code.VISIBLE) & finite & doubt
        margin = np.zeros(codes.shape) if slack is None else slack
        rules.append((usable, np.where(usable, -margin, np.inf), Flag.DOUBTFUL))
    if holes == "behind":
        usable = (codes == Code.FACING_AWAY) & finite
        rank = np.where(usable, np.nan_to_num(cost, nan=np.inf), np.inf)
        rules.append((usable, rank, Flag.BEHIND))
    elif holes == "naive":
        usable = (codes != Code.NODATA) & finite
        rules.append((usable, np.where(usable, nadir, np.inf), Flag.NAIVE))
    for usable, rank, flag in rules:
        got = hole & usable.any(axis=0)
        if not got.any():
            continue
        best = np.argmin(rank, axis=0)
        rr, cc = np.nonzero(got)
        data[:, rr, cc] = values[best[got], :, rr, cc].T
        weights[:, got] = best[got][None] == np.arange(len(values))[:, None]
        label[got] = best[got]
        flags[got] = flag
        hole &= ~got
    if holes == "inpaint" and hole.any():
        flags[inpaint(data, hole)] = Flag.INPAINTED
    return flags


def inpaint(data: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """Inpaint (Navier-Stokes, :data:`INPAINT_RADIUS`) in place the components of ``hole`` (rows,
    cols; 8-connected) of ``data`` (bands, rows, cols) float32 that fit in
    :data:`INPAINT_SIZE` posts and do not touch the window's edge, each from the posts within
    :data:`INPAINT_RADIUS` of its bounding box (the other holes there unused); returns the
    posts inpainted."""
    rows, cols = hole.shape
    count, component, stats, _ = cv2.connectedComponentsWithStats(
        hole.astype(np.uint8), connectivity=8, ltype=cv2.CV_32S
    )
    done = np.zeros(hole.shape, bool)
    r = INPAINT_RADIUS
    for i in range(1, count):
        c0, r0, w, h = (int(v) for v in stats[i, :4])
        if w > INPAINT_SIZE or h > INPAINT_SIZE:
            continue
        if r0 == 0 or c0 == 0 or r0 + h == rows or c0 + w == cols:
            continue
        window = (slice(max(r0 - r, 0), r0 + h + r), slice(max(c0 - r, 0), c0 + w + r))
        mask = hole[window].astype(np.uint8)
        part = component[window] == i
        for band in data:
            known = np.where(mask, np.float32(0), band[window]).astype(np.float32)
            out = cv2.inpaint(known, mask, r, cv2.INPAINT_NS)
            band[window][part] = out[part]
        done[window] |= part
    return done
