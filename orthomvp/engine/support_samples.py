"""What a mosaic tile keeps of each view for the support test
(:func:`orthomvp.ortho.support.blocked`): the image positions and GSDs only at the posts the
test can ask about, not the whole tile.

The test and the clear-pixel resampling run at posts a view sees surely (visible, not
doubtful) with a post within :data:`~orthomvp.ortho.support.RADIUS` (the trust test's
candidates, and the sharpening) or :data:`~orthomvp.ortho.support.FEATHER_RADIUS` (the
feather's) that it does not see (:func:`~orthomvp.ortho.support.near`), and at the view's
doubtful visible posts (the fill of doubtful holes): posts that each view's codes and doubt
give alone, as the tile computes them. Keeping the positions (float64 (u, v)) and GSDs there
only takes a mosaic tile's memory from about 66 to about 30 bytes per view and post held
before composing (the fixed benchmark set, 64 views over every post)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.ortho.support import FEATHER_RADIUS, near
from orthomvp.ortho.support import RADIUS as SUPPORT_RADIUS

SAMPLE_REACH = max(SUPPORT_RADIUS, FEATHER_RADIUS)
"""Box radius (posts) within which a post the view does not see makes a post testable."""


@dataclass(frozen=True)
class SupportSamples:
    """One view's image positions ``uv`` (n, 2) and GSDs ``gsd`` (n,) at the posts ``index``
    (n,; flat, in C order) of a window of ``shape`` (rows, cols)."""

    shape: tuple[int, int]
    index: np.ndarray
    uv: np.ndarray
    gsd: np.ndarray

    @classmethod
    def keep(
        cls, sure: np.ndarray, uv: np.ndarray, gsd: np.ndarray, also: np.ndarray | None = None
    ) -> SupportSamples:
        """The samples at the posts of ``sure`` (rows, cols: the view sees them, not
        doubtful) with a post not ``sure`` within :data:`SAMPLE_REACH` (off the window counts
        as sure: :func:`~orthomvp.ortho.support.near`), and at the posts ``also``
        (the view's doubtful visible posts, which the clear-pixel fill of doubtful holes
        resamples); ``uv`` (rows, cols, 2) and ``gsd`` (rows, cols) of the whole window."""
        kept = near(sure[None], SAMPLE_REACH)[0]
        if also is not None:
            kept |= also
        return cls(sure.shape, np.flatnonzero(kept), uv[kept], gsd[kept])

    def at(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The kept image positions (n, 2) and GSDs (n,) at the posts (``rows``, ``cols``)
        (n,) of the window, NaN at posts not kept (which the support test never asks): the
        :data:`~orthomvp.ortho.support.PostSamples` of the view."""
        flat = np.ravel_multi_index((rows, cols), self.shape)
        if not len(self.index):
            return np.full((len(flat), 2), np.nan), np.full(len(flat), np.nan)
        at = np.minimum(np.searchsorted(self.index, flat), len(self.index) - 1)
        found = self.index[at] == flat
        return np.where(found[:, None], self.uv[at], np.nan), np.where(found, self.gsd[at], np.nan)

    def holds(self, posts: np.ndarray) -> bool:
        """Whether every post of ``posts`` (rows, cols) is kept."""
        kept = np.zeros(self.shape, bool)
        kept.reshape(-1)[self.index] = True
        return not (posts & ~kept).any()
