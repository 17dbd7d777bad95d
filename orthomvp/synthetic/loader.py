"""Reading scene directories written by ``orthomvp synth`` (see
:mod:`orthomvp.synthetic.writer`)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from orthomvp.camera import Camera, read_camera
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import read_image


@dataclass
class SceneView:
    """One view of a scene directory: image (bands, rows, cols), camera with image size,
    truth visibility codes (rows, cols)."""

    name: str
    image: np.ndarray
    camera: Camera
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
        terrain = Terrain.read(directory / summary["dem"], world=summary.get("world", "body"))
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
