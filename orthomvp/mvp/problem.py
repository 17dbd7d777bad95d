"""The fit problem: a DEM and its views prepared for the MVP objective, shared by the fitter
(:func:`orthomvp.mvp.fit.fit_dem`) and the objective explorer (:mod:`orthomvp.explore`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.camera import PinholeCamera, as_image, check_image
from orthomvp.codes import Code
from orthomvp.errors import InputError
from orthomvp.mesh import terrain_mesh
from orthomvp.mvp.model import PlaneModel
from orthomvp.mvp.patches import ViewStack
from orthomvp.mvp.plane import PostLines, post_lines
from orthomvp.raycast import RayCaster
from orthomvp.terrain import Terrain
from orthomvp.visibility import Visibility, compute_visibility

MIN_LEVEL_SIZE = 16  # pixels: no pyramid level whose smallest image is narrower


def pyramid_levels(images: list[np.ndarray], wanted: int) -> int:
    """At most ``wanted`` levels, and none whose images would be under MIN_LEVEL_SIZE pixels
    across."""
    smallest = min(min(img.shape[-2:]) for img in images)
    return max(1, min(wanted, int(np.floor(np.log2(max(smallest / MIN_LEVEL_SIZE, 1)))) + 1))


def first_bands(
    images: list[np.ndarray], cameras: list[PinholeCamera], names: list[str]
) -> tuple[list[np.ndarray], list[PinholeCamera]]:
    """Band 1 of each image ((bands, rows, cols) or (rows, cols), see
    :func:`orthomvp.camera.as_image`) as float32, and each camera checked against its image and
    given its size; ``names`` label errors."""
    bands, cams = [], []
    for image, camera, name in zip(images, cameras, names, strict=True):
        img = as_image(image, name)
        cams.append(check_image(img, camera, name))
        bands.append(img[0])
    return bands, cams


@dataclass
class FitProblem:
    """A DEM and K views, ready for the objective.

    ``terrain``: the DEM (heights in its own convention); ``names`` (K) the views' labels;
    ``stack``: the views' images and pyramids (:class:`~orthomvp.mvp.patches.ViewStack`; its
    level count is the number of pyramid levels fitted); ``visible`` (K, rows, cols) bool: the
    posts each view may see (visibility code 1 unless given); ``visibility``: each view's full
    visibility test (None when ``visible`` was given); ``normals`` (rows, cols, 3): the DEM's
    unit surface normals; ``usable`` (rows, cols): posts with a value and a normal;
    ``spacing``: the mean post spacing in metres.
    """

    terrain: Terrain
    names: list[str]
    stack: ViewStack
    visible: np.ndarray
    visibility: list[Visibility] | None
    normals: np.ndarray
    usable: np.ndarray
    spacing: float

    @classmethod
    def build(
        cls,
        terrain: Terrain,
        images: list[np.ndarray],
        cameras: list[PinholeCamera],
        *,
        levels: int,
        eps: float | None = None,
        visible: np.ndarray | None = None,
        names: list[str] | None = None,
        min_views: int = 1,
    ) -> FitProblem:
        """From ``images`` (each (bands, rows, cols) or (rows, cols); band 1 is used) seen
        through ``cameras``, at least ``min_views`` of them; ``levels``: pyramid levels wanted
        (fewer when the images are small, see :func:`pyramid_levels`). ``visible`` (K, rows,
        cols) bool overrides the visibility test (:func:`orthomvp.visibility.compute_visibility`
        with ``eps`` in DEM posts, on this DEM's mesh); ``names`` label the views (default
        "image 1", ...)."""
        if len(images) != len(cameras) or len(images) < min_views:
            plural = "s" if min_views > 1 else ""
            raise InputError(
                f"got {len(images)} images and {len(cameras)} cameras: this needs at least "
                f"{min_views} image{plural}, each with its camera"
            )
        names = names or [f"image {k + 1}" for k in range(len(images))]
        bands, cams = first_bands(images, cameras, names)
        visibility = None
        if visible is None:
            caster = RayCaster(terrain_mesh(terrain))
            visibility = [compute_visibility(terrain, cam, eps=eps, caster=caster) for cam in cams]
            visible = np.stack([v.codes == Code.VISIBLE for v in visibility])
        visible = np.asarray(visible, bool)
        if visible.shape != (len(cams), *terrain.shape):
            raise InputError(f"visibility masks must be (K, rows, cols), got {visible.shape}")
        stack = ViewStack.build(bands, cams, pyramid_levels(bands, levels))
        normals = terrain.normals()
        usable = terrain.valid & np.isfinite(normals).all(axis=-1)
        spacing = float(np.mean(terrain.post_spacing()))
        return cls(terrain, names, stack, visible, visibility, normals, usable, spacing)

    @property
    def levels(self) -> int:
        """Pyramid levels of the views (1 = no coarse to fine)."""
        return len(self.stack.levels)

    def lines(self, c: np.ndarray, r: np.ndarray) -> PostLines:
        """Height lines of posts (``c``, ``r``) (B,) integers, at the DEM's values there."""
        return post_lines(self.terrain, c.astype(float), r.astype(float), self.terrain.values[r, c])

    def model(
        self,
        lines: PostLines,
        n0: np.ndarray,
        t1: np.ndarray | None = None,
        t2: np.ndarray | None = None,
    ) -> PlaneModel:
        """The plane model of posts with height ``lines``, starting normals ``n0`` (B, 3) and
        tilt directions ``t1``, ``t2`` (B, 3) (from ``n0`` unless given), seen by these views."""
        return PlaneModel(lines, n0, self.stack.F, self.spacing, t1, t2)
