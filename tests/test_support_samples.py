"""A mosaic tile's support samples (orthomvp.engine.support_samples): kept at every post the
support test can ask about, exact there."""

from __future__ import annotations

import numpy as np
import pytest

from orthomvp.engine.support_samples import SupportSamples
from orthomvp.ortho.support import FEATHER_RADIUS, RADIUS, candidates, near


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kept_where_the_support_test_can_ask(seed: int) -> None:
    """Every post where the support test may ask (support.near within FEATHER_RADIUS, which
    holds the trust test's candidates and the sharpening's posts within RADIUS) and every
    doubtful visible post (the fill of doubtful holes) is kept, with its exact position and
    GSD; far from a view's occlusion boundary nothing else is."""
    rng = np.random.default_rng(seed)
    views, rows, cols = 3, 90, 110
    sure = np.ones((views, rows, cols), bool)
    for k in range(views):  # a few blocks the view does not see, and scattered posts
        for _ in range(4):
            r, c = rng.integers(0, rows - 10), rng.integers(0, cols - 10)
            sure[k, r : r + rng.integers(2, 10), c : c + rng.integers(2, 10)] = False
        sure[k][rng.random((rows, cols)) < 0.002] = False
    uv = rng.normal(size=(views, rows, cols, 2)) * 1000
    gsd = rng.random((views, rows, cols))
    doubtful = ~sure & (rng.random((views, rows, cols)) < 0.01)
    asked = candidates(sure) | near(sure, RADIUS) | near(sure, FEATHER_RADIUS) | doubtful
    for k in range(views):
        kept = SupportSamples.keep(sure[k], uv[k], gsd[k], doubtful[k])
        assert kept.holds(asked[k])
        assert 0 < len(kept.index) < rows * cols
        at_uv, at_gsd = kept.at(*np.nonzero(asked[k]))
        np.testing.assert_array_equal(at_uv, uv[k][asked[k]])
        np.testing.assert_array_equal(at_gsd, gsd[k][asked[k]])
        # not kept: posts more than FEATHER_RADIUS from every post the view does not see
        far = np.ones((rows, cols), bool)
        rr, cc = np.nonzero(~sure[k])
        r, c = np.mgrid[0:rows, 0:cols]
        for a, b in zip(rr, cc, strict=True):
            far &= (np.abs(r - a) > 15) | (np.abs(c - b) > 15)
        assert far.any()
        lost_uv, lost_gsd = kept.at(*np.nonzero(far & ~doubtful[k]))
        assert np.isnan(lost_uv).all() and np.isnan(lost_gsd).all()
