"""The fit problem: a DEM and its views prepared for the MVP objective, shared by the fitter
(:func:`orthomvp.mvp.fit.fit_dem`) and the objective explorer (:mod:`orthomvp.explore`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.camera import Camera, PinholeCamera, as_image, check_image
from orthomvp.codes import Code
from orthomvp.errors import InputError
from orthomvp.geometry.normals import grid_normals
from orthomvp.geometry.terrain import Terrain
from orthomvp.mvp.local import local_projections
from orthomvp.mvp.model import PlaneModel
from orthomvp.mvp.patches import ViewStack
from orthomvp.mvp.plane import PostLines, post_lines
from orthomvp.mvp.views import ViewWindow
from orthomvp.occlusion.visibility import Visibility, compute_visibility, occluder_caster

MIN_LEVEL_SIZE = 16  # pixels: no pyramid level whose smallest image is narrower


def pyramid_levels(images: list[np.ndarray], wanted: int) -> int:
    """At most ``wanted`` levels, and none whose images would be under MIN_LEVEL_SIZE pixels
    across."""
    return levels_for(min(min(img.shape[-2:]) for img in images), wanted)


def levels_for(smallest: int, wanted: int) -> int:
    """:func:`pyramid_levels` of images whose smallest side is ``smallest`` pixels."""
    return max(1, min(wanted, int(np.floor(np.log2(max(smallest / MIN_LEVEL_SIZE, 1)))) + 1))


def first_bands(
    images: list[np.ndarray],
    cameras: list[Camera],
    names: list[str],
    windows: list[ViewWindow] | None = None,
) -> tuple[list[np.ndarray], list[Camera]]:
    """Band 1 of each image ((bands, rows, cols) or (rows, cols), see
    :func:`orthomvp.camera.as_image`) as float32, and each camera checked against its image and
    given its size; ``names`` label errors. With ``windows`` the images are those windows of
    the cameras' images (of the windows' sizes)."""
    bands, cams = [], []
    for k, (image, camera, name) in enumerate(zip(images, cameras, names, strict=True)):
        img = as_image(image, name)
        if windows is None:
            cams.append(check_image(img, camera, name))
        else:
            if img.shape[1:] != windows[k].shape:
                raise InputError(
                    f"{name}: the window is {windows[k].shape} px (rows, cols), the image "
                    f"given {img.shape[1:]}"
                )
            cams.append(camera.with_image_size(*windows[k].size))
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
    ``spacing``: the mean post spacing in metres; ``cameras`` (K) the views' cameras and
    ``hwin`` the window's half-size in posts, over whose patches cameras that are not pinholes
    are approximated by projection matrices (:mod:`orthomvp.mvp.local`).
    """

    terrain: Terrain
    names: list[str]
    stack: ViewStack
    visible: np.ndarray
    visibility: list[Visibility] | None
    normals: np.ndarray
    usable: np.ndarray
    spacing: float
    origin: tuple[int, int] = (0, 0)
    geometry: Terrain | None = None
    cameras: list[Camera] | None = None
    hwin: int = 10

    @classmethod
    def build(
        cls,
        terrain: Terrain,
        images: list[np.ndarray],
        cameras: list[Camera],
        *,
        levels: int,
        hwin: int = 10,
        eps: float | None = None,
        visible: np.ndarray | None = None,
        names: list[str] | None = None,
        min_views: int = 1,
        windows: list[ViewWindow] | None = None,
        spacing: float | None = None,
        origin: tuple[int, int] = (0, 0),
        geometry: Terrain | None = None,
    ) -> FitProblem:
        """From ``images`` (each (bands, rows, cols) or (rows, cols); band 1 is used) seen
        through ``cameras``, at least ``min_views`` of them; ``levels``: pyramid levels wanted
        (fewer when the images are small, see :func:`pyramid_levels`). ``visible`` (K, rows,
        cols) bool overrides the visibility test
        (:func:`orthomvp.occlusion.visibility.compute_visibility` with ``eps`` in DEM posts, on
        this DEM's mesh); ``names`` label the views (default "image 1", ...); ``hwin``: the
        window's half-size in posts (see :mod:`orthomvp.mvp.local`).

        A window of a larger DEM and images: ``windows`` (one per view) say where the images
        lie in the cameras' images (:mod:`orthomvp.mvp.views`; the visibility test needs the
        whole images, so ``visible`` must then be given, and ``levels`` is taken as it is),
        and ``spacing`` is the whole DEM's mean post spacing (metres), which scales the
        fitted tilts and the convergence tests. ``terrain`` may be the window whose first post
        is post ``origin`` (c, r) of the grid of ``geometry`` (the whole DEM, or a Terrain
        with its georeference, conventions and ``wrap_lon``; its values are not read): posts'
        geometry (height lines, normals) is then computed on that grid, exactly as for the
        whole DEM."""
        if len(images) != len(cameras) or len(images) < min_views:
            plural = "s" if min_views > 1 else ""
            raise InputError(
                f"got {len(images)} images and {len(cameras)} cameras: this needs at least "
                f"{min_views} image{plural}, each with its camera"
            )
        names = names or [f"image {k + 1}" for k in range(len(images))]
        bands, cams = first_bands(images, cameras, names, windows)
        visibility = None
        if visible is None and windows is not None:
            raise InputError("a fit on windows of the images needs the visibility masks")
        if visible is None:
            caster = occluder_caster(terrain)
            visibility = [compute_visibility(terrain, cam, eps=eps, caster=caster) for cam in cams]
            visible = np.stack([v.codes == Code.VISIBLE for v in visibility])
        visible = np.asarray(visible, bool)
        if visible.shape != (len(cams), *terrain.shape):
            raise InputError(f"visibility masks must be (K, rows, cols), got {visible.shape}")
        n_levels = pyramid_levels(bands, levels) if windows is None else levels
        stack = ViewStack.build(bands, cams, n_levels, windows)
        if geometry is None:
            if origin != (0, 0):
                raise InputError("a window of a DEM (origin) needs the DEM's geometry")
            normals = terrain.normals()
        else:
            c, r = terrain.grid()
            p = geometry.to_world(c + origin[0], r + origin[1], terrain.values)
            normals = grid_normals(p, geometry.up_vectors(p))
        usable = terrain.valid & np.isfinite(normals).all(axis=-1)
        if spacing is None:
            spacing = float(np.mean(terrain.post_spacing()))
        return cls(
            terrain, names, stack, visible, visibility, normals, usable, spacing, origin, geometry,
            cams, hwin,
        )  # fmt: skip

    @property
    def levels(self) -> int:
        """Pyramid levels of the views (1 = no coarse to fine)."""
        return len(self.stack.levels)

    def lines(self, c: np.ndarray, r: np.ndarray) -> PostLines:
        """Height lines of posts (``c``, ``r``) (B,) integers, at the DEM's values there
        (on the grid of ``geometry`` when given: its lines' ``c``, ``r`` are then that grid's)."""
        c0, r0 = self.origin
        return post_lines(
            self.geometry or self.terrain,
            (c + c0).astype(float),
            (r + r0).astype(float),
            self.terrain.values[r, c],
        )

    def model(
        self,
        lines: PostLines,
        n0: np.ndarray,
        t1: np.ndarray | None = None,
        t2: np.ndarray | None = None,
    ) -> PlaneModel:
        """The plane model of posts with height ``lines``, starting normals ``n0`` (B, 3) and
        tilt directions ``t1``, ``t2`` (B, 3) (from ``n0`` unless given), seen by these views:
        pinholes through their own matrices, other cameras through matrices fitted around each
        post at its DEM value (:func:`~orthomvp.mvp.local.local_projections`)."""
        F = self.stack.F
        local = [
            k for k, cam in enumerate(self.cameras or []) if not isinstance(cam, PinholeCamera)
        ]
        if local:
            c0, r0 = self.origin
            rows, cols = self.terrain.shape
            ci = np.clip(np.rint(lines.c).astype(int) - c0, 0, cols - 1)
            ri = np.clip(np.rint(lines.r).astype(int) - r0, 0, rows - 1)
            F = np.repeat(F[None], len(lines.c), axis=0)
            for k in local:
                F[:, k], _ = local_projections(
                    self.cameras[k], self.geometry or self.terrain, lines.c, lines.r,
                    self.terrain.values[ri, ci], hwin=self.hwin, spacing=self.spacing,
                )  # fmt: skip
        return PlaneModel(lines, n0, F, self.spacing, t1, t2)
