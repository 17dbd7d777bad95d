"""Writing a synthetic scene as a directory of files that any tool can read.

``dem.tif`` (heights: the analytic truth at the posts), ``truth_radiance.tif``
(float32 radiance at the posts), for each view ``NAME.tif`` (float32 image), ``NAME.tsai``
(a frame camera) or ``NAME.json`` (a line scanner's USGS CSM ISD), and
``NAME.visibility.tif`` (uint8 truth :class:`~orthomvp.codes.Code` on the DEM grid), and
``scene.json``: the summary that names them, read back by
:func:`orthomvp.synthetic.loader.load_scene`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Protocol, TypeVar

import numpy as np
from affine import Affine
from tqdm import tqdm

from orthomvp.camera import Camera, write_tsai
from orthomvp.camera.csm import LineScanCamera, write_isd
from orthomvp.codes import Code
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.outputs import atomic_path
from orthomvp.io.raster import write_geotiff
from orthomvp.synthetic.cameras import ViewSpec
from orthomvp.synthetic.rendering import MAX_SUPERSAMPLE
from orthomvp.validate import number


class LitSurface(Protocol):
    """What the writer needs of a scene's surface: its radiance at local (x, y) metres and the
    unit vector ``sun`` towards the sun."""

    @property
    def sun(self) -> np.ndarray: ...

    def radiance(self, x: np.ndarray, y: np.ndarray) -> np.ndarray: ...


CameraT = TypeVar("CameraT", bound=Camera)
"""The camera type of a scene's views (a city's are pinhole cameras)."""


class WritableScene(Protocol[CameraT]):
    """What :func:`write_scene` needs of a scene, as :class:`~orthomvp.synthetic.scene.Scene`
    and :class:`~orthomvp.synthetic.city.CityScene` give it (the writer depends on this alone,
    so that neither is imported here)."""

    @property
    def kind(self) -> str: ...
    @property
    def surface(self) -> LitSurface: ...
    @property
    def terrain(self) -> Terrain: ...
    @property
    def views(self) -> tuple[ViewSpec, ...]: ...
    @property
    def cameras(self) -> Mapping[str, CameraT]: ...
    @property
    def spacing(self) -> float: ...
    @property
    def gsd(self) -> float: ...
    @property
    def seed(self) -> int: ...
    @property
    def facts(self) -> dict: ...

    def post_local(self) -> tuple[np.ndarray, np.ndarray]: ...
    def frame_facts(self) -> dict: ...
    def render(self, camera: CameraT, supersample: int = 3) -> np.ndarray: ...
    def visibility_truth(self, camera: CameraT, step: float | None = None) -> np.ndarray: ...


def write_scene(
    scene: WritableScene[CameraT], outdir: str | Path, supersample: int = 3, progress: bool = False
) -> dict:
    """Render ``scene`` (``supersample`` x ``supersample`` rays per pixel) and write its
    directory into ``outdir``, with a progress bar over the views if ``progress`` and on a
    terminal. Returns the summary written to scene.json."""
    number(
        supersample,
        "supersample (rays per pixel side)",
        minimum=1,
        maximum=MAX_SUPERSAMPLE,
        integer=True,
    )
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    t = scene.terrain
    t.write(outdir / "dem.tif", overwrite=True)  # (the scene's folder: every file anew)
    x, y = scene.post_local()
    radiance = scene.surface.radiance(x, y).astype(np.float32)
    write_geotiff(outdir / "truth_radiance.tif", radiance, t.transform, t.crs, nodata=np.nan)
    views = {}
    bar = tqdm(
        scene.views, desc=f"rendering {scene.kind}", unit="view", disable=not progress or None
    )
    for view in bar:
        name, cam = view.name, scene.cameras[view.name]
        image = scene.render(cam, supersample)
        write_geotiff(outdir / f"{name}.tif", image, Affine.identity(), None)
        if isinstance(cam, LineScanCamera):
            camera_file = f"{name}.json"
            write_isd(cam, outdir / camera_file)
        else:
            camera_file = f"{name}.tsai"
            write_tsai(cam, outdir / camera_file)
        vis = scene.visibility_truth(cam)
        write_geotiff(outdir / f"{name}.visibility.tif", vis, t.transform, t.crs, nodata=None)
        views[name] = {
            "image": f"{name}.tif",
            "camera": camera_file,
            "visibility": f"{name}.visibility.tif",
            "emission_deg": view.emission,
            "gsd_m": scene.gsd,
            "visibility_counts": {code.label: int((vis == code).sum()) for code in Code},
        }
    summary = {
        "kind": scene.kind,
        "sensor": "linescan"
        if any(isinstance(c, LineScanCamera) for c in scene.cameras.values())
        else "frame",
        **scene.frame_facts(),
        "dem": "dem.tif",
        "truth_heights": "dem.tif",
        "truth_radiance": "truth_radiance.tif",
        "size": list(t.shape),
        "post_spacing_m": scene.spacing,
        "sun": scene.surface.sun.tolist(),
        "seed": scene.seed,
        "views": views,
        **scene.facts,
    }
    with atomic_path(outdir / "scene.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2))
    return summary
