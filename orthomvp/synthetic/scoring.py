"""Scoring visibility codes against a scene's truth codes (uint8 :class:`~orthomvp.codes.Code`
rasters on the DEM grid)."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import binary_erosion

from orthomvp.codes import Code

HIDDEN = (Code.OCCLUDED, Code.FACING_AWAY)
"""The codes scored as 'hidden'."""


def away_from_boundaries(codes: np.ndarray, width: int = 1) -> np.ndarray:
    """Posts farther than ``width`` posts (8-neighbourhood) from any boundary between truth
    classes, and not next to the DEM border."""
    st = np.ones((2 * width + 1, 2 * width + 1), bool)
    keep = np.zeros(codes.shape, bool)
    for k in np.unique(codes):
        keep |= binary_erosion(codes == k, st, border_value=0)
    return keep


def classification_scores(predicted: np.ndarray, truth: np.ndarray, keep: np.ndarray) -> dict:
    """Precision, recall and F1 of 'visible' (VISIBLE) and of 'hidden' (OCCLUDED or
    FACING_AWAY) among the posts in ``keep`` whose truth is inside the image (not NODATA);
    ``scored`` counts those posts."""
    keep = keep & (truth != Code.NODATA)
    out = {"scored": int(keep.sum())}
    for label, pos_t, pos_p in (
        ("visible", truth == Code.VISIBLE, predicted == Code.VISIBLE),
        ("hidden", np.isin(truth, HIDDEN), np.isin(predicted, HIDDEN)),
    ):
        tp = int((pos_t & pos_p & keep).sum())
        fp = int((~pos_t & pos_p & keep).sum())
        fn = int((pos_t & ~pos_p & keep).sum())
        precision = tp / (tp + fp) if tp + fp else 1.0
        recall = tp / (tp + fn) if tp + fn else 1.0
        f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else 1.0
        out.update({f"precision_{label}": precision, f"recall_{label}": recall, f"f1_{label}": f1})
    return out
