"""Reading scene directories written by ``orthomvp synth`` and scoring against their truth."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_erosion

from orthomvp.camera import PinholeCamera, read_camera
from orthomvp.errors import InputError
from orthomvp.raster import read_image
from orthomvp.terrain import Terrain


@dataclass
class SceneView:
    """One view of a scene directory: image (bands, rows, cols), camera with image size,
    truth visibility codes (rows, cols)."""

    name: str
    image: np.ndarray
    camera: PinholeCamera
    truth: np.ndarray


@dataclass
class SceneData:
    """A scene directory loaded: the DEM, the true radiance, the views and the summary."""

    terrain: Terrain
    radiance: np.ndarray
    views: dict[str, SceneView]
    summary: dict


def load_scene(directory: str | Path) -> SceneData:
    """Load a scene directory (``scene.json`` and the files it names)."""
    directory = Path(directory)
    meta = directory / "scene.json"
    if not meta.is_file():
        raise InputError(f"{directory}: not a scene directory (no scene.json)")
    try:
        summary = json.loads(meta.read_text())
        terrain = Terrain.read(directory / summary["dem"])
        radiance = read_image(directory / summary["truth_radiance"])[0]
        views = {}
        for name, v in summary["views"].items():
            image = read_image(directory / v["image"])
            cam = read_camera(directory / v["camera"])
            cam = cam.with_image_size(image.shape[2], image.shape[1])
            truth = read_image(directory / v["visibility"])[0].astype(np.uint8)
            views[name] = SceneView(name, image, cam, truth)
    except (KeyError, TypeError, json.JSONDecodeError) as exc:
        raise InputError(f"{meta}: malformed scene summary ({exc})") from exc
    return SceneData(terrain, radiance, views, summary)


def away_from_boundaries(codes: np.ndarray, width: int = 1) -> np.ndarray:
    """Posts farther than ``width`` posts (8-neighbourhood) from any boundary between truth
    classes, and not next to the DEM border."""
    st = np.ones((2 * width + 1, 2 * width + 1), bool)
    keep = np.zeros(codes.shape, bool)
    for k in np.unique(codes):
        keep |= binary_erosion(codes == k, st, border_value=0)
    return keep


def classification_scores(predicted: np.ndarray, truth: np.ndarray, keep: np.ndarray) -> dict:
    """Precision, recall and F1 of 'visible' (code 1) and of 'hidden' (codes 2, 3) among the
    posts in ``keep`` whose truth is inside the image (code != 0)."""
    keep = keep & (truth != 0)
    out = {"scored": int(keep.sum())}
    for label, pos_t, pos_p in (
        ("visible", truth == 1, predicted == 1),
        ("hidden", np.isin(truth, (2, 3)), np.isin(predicted, (2, 3))),
    ):
        tp = int((pos_t & pos_p & keep).sum())
        fp = int((~pos_t & pos_p & keep).sum())
        fn = int((pos_t & ~pos_p & keep).sum())
        precision = tp / (tp + fp) if tp + fp else 1.0
        recall = tp / (tp + fn) if tp + fn else 1.0
        f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else 1.0
        out.update({f"precision_{label}": precision, f"recall_{label}": recall, f"f1_{label}": f1})
    return out
