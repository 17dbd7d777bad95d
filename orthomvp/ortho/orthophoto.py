"""Orthophotos on the DEM grid that leave occluded posts empty, and mosaics that fill them.

An orthophoto samples the image at the projection of every post (``cv2.remap``), all bands,
float32 with NaN as nodata. With occlusion on (the default) only posts whose visibility code is
1 (visible) get a value; ``occlusion=False`` gives the naive orthophoto of other tools, which
paints the occluder's pixels again onto every post hidden behind it (ghosts).

Mosaics combine views as :mod:`orthomvp.ortho.composite` describes: by default each post prefers the
visible view with the smallest emission angle (the angle between the DEM's surface normal and
the direction to the camera, the least foreshortening), seamlines keep away from occlusion
boundaries and disagreement, seams are feathered over 8 posts, and posts visible in no view
stay nodata.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import cv2
import numpy as np
from affine import Affine

from orthomvp.camera import Camera, as_image, check_image
from orthomvp.codes import Code, Interp
from orthomvp.errors import GeometryError, InputError, LeftOutWarning
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import finite_rows
from orthomvp.io.preflight import check_memory, count_text
from orthomvp.occlusion.paths import Geometry, VisibilityPath
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import (
    VISIBILITY_BYTES_PER_POST,
    Visibility,
    check_visibility_of,
    compute_visibility,
    occluder_caster,
)
from orthomvp.ortho.balance import Correction, pair_stats, solve_balance
from orthomvp.ortho.composite import (
    FUSED_POSTS,
    MosaicOptions,
    clamp_blend,
    compose,
    doubtful,
    nadir_angle,
    overlap_width,
)
from orthomvp.ortho.support import Support, candidates, clear_blend, clear_taps, window_samples
from orthomvp.ortho.support import blocked as support_blocked
from orthomvp.validate import of_type

if TYPE_CHECKING:
    from pyproj import CRS
    from rasterio.crs import CRS as FileCRS

MAP_SIDE = 32766
"""The most rows or columns a map of ``cv2.remap`` may have (OpenCV wants fewer than 32767)."""
CUBIC_FRAME = 3
"""Pixels of NaN around an image sampled by cubic interpolation (whose taps reach 2 pixels)."""
OUTSIDE = -1e6
"""A pixel position far outside any image (where ``cv2.remap``'s border, NaN, is sampled)."""
BYTES_PER_BAND_POST = 12
"""Memory of an orthophoto per band and post beyond its visibility: the float32 result and the
samples, bytes."""

INTERPOLATION = {
    Interp.NEAREST: cv2.INTER_NEAREST,
    Interp.BILINEAR: cv2.INTER_LINEAR,
    Interp.CUBIC: cv2.INTER_CUBIC,
}
"""OpenCV interpolation flag of each :class:`~orthomvp.codes.Interp`."""


@dataclass
class Ortho:
    """An orthophoto: ``data`` (bands, rows, cols) float32, NaN where empty, on the grid given
    by ``transform`` (pixel corners) and ``crs``; ``visibility`` of the posts it came from."""

    data: np.ndarray
    transform: Affine
    crs: CRS | FileCRS
    visibility: Visibility


@dataclass
class Mosaic:
    """A mosaic: ``data`` as in :class:`Ortho`; ``source`` (rows, cols) uint8, the 1-based index
    of the view each post is labelled with (0 where none); ``visibilities`` per view;
    ``flags`` (rows, cols) :class:`~orthomvp.ortho.composite.Flag`; ``weights`` (views, rows, cols)
    each view's blend weight; ``correction`` the radiometric balance applied (or None);
    ``resampled`` (views, rows, cols) where a view's value is the blend of its clear pixels,
    its bilinear sample reaching an occluder (:func:`orthomvp.ortho.support.sharpen`; None:
    one view)."""

    data: np.ndarray
    source: np.ndarray
    transform: Affine
    crs: CRS | FileCRS
    visibilities: list[Visibility]
    flags: np.ndarray
    weights: np.ndarray
    correction: Correction | None = None
    resampled: np.ndarray | None = None


def sample_image(
    image: np.ndarray,
    uv: np.ndarray,
    interp: Interp | str = Interp.BILINEAR,
    *,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Sample ``image`` (bands, rows, cols) at pixel positions ``uv`` (..., 2) -> (bands, ...).

    ``interp`` is an :class:`~orthomvp.codes.Interp` or its name. NaN positions, positions
    outside the image and NaN image pixels give NaN. ``out``: a float32 array (bands, ...) to
    write the samples into (and return), C-contiguous.
    """
    flag = INTERPOLATION[Interp(interp)]
    image = as_image(image)
    if uv is not None and np.asarray(uv).dtype != np.float32:  # float32 positions as they are
        uv = np.asarray(uv, dtype=np.float64)
    if uv is None or uv.shape[-1:] != (2,):
        raise InputError(
            f"pixel positions must have shape (..., 2), got {getattr(uv, 'shape', uv)}"
        )
    shape = uv.shape[:-1]
    n = int(np.prod(shape))
    if uv.ndim == 3 and uv.dtype == np.float32 and 0 < max(shape) <= MAP_SIDE:
        maps = np.ascontiguousarray(uv)  # a grid of positions is the map as it is
    else:  # cv2.remap takes at most 32767 columns per map: lay the points out as rows of 4096
        width = 4096
        maps = np.full((n + (-n) % width, 2), OUTSIDE, np.float32)
        maps[:n] = uv.reshape(-1, 2)
        maps = maps.reshape(-1, width, 2)
    bad = ~finite_rows(maps)
    if bad.any():  # a NaN position samples nothing: far outside, where the border is NaN
        maps = np.where(bad[..., None], np.float32(OUTSIDE), maps)
    border = cv2.BORDER_CONSTANT
    if flag == cv2.INTER_CUBIC:  # OpenCV 5.0's cubic remap with a NaN border value gives NaN
        # far inside the image too: the NaN border becomes a frame of the image instead, which
        # the replicated border extends to any position outside
        maps, border = maps + np.float32(CUBIC_FRAME), cv2.BORDER_REPLICATE
    bands = image.shape[0]
    if out is not None and (
        out.shape != (bands, *shape) or out.dtype != np.float32 or not out.flags.c_contiguous
    ):
        raise InputError(
            f"samples go into a C-contiguous float32 array {(bands, *shape)}, not "
            f"{out.dtype} {out.shape}{'' if out.flags.c_contiguous else ' (not contiguous)'}"
        )
    into = out if out is not None and maps.shape[:2] == shape else None  # the grid map's
    samples = np.empty((bands, *maps.shape[:2]), np.float32) if into is None else into
    for b, band in enumerate(image):
        band = np.ascontiguousarray(band, dtype=np.float32)
        if flag == cv2.INTER_CUBIC:
            band = cv2.copyMakeBorder(band, *[CUBIC_FRAME] * 4, cv2.BORDER_CONSTANT, value=np.nan)
        cv2.remap(  # one two-channel map: no copy of each coordinate per band
            band, maps, None, flag, dst=samples[b], borderMode=border, borderValue=np.nan
        )
    if into is not None:
        return into
    samples = samples.reshape(bands, -1)[:, :n].reshape((bands, *shape))
    if out is None:
        return samples
    out[...] = samples
    return out


def orthorectify(
    terrain: Terrain,
    image: np.ndarray,
    camera: Camera,
    *,
    occlusion: bool = True,
    eps: float | None = None,
    interp: Interp | str = Interp.BILINEAR,
    visibility: Visibility | None = None,
    caster: RayCaster | None = None,
    progress: bool = False,
    post_scale: float = 1.0,
    dem: Terrain | None = None,
) -> Ortho:
    """Orthophoto of ``image`` (bands, rows, cols) through ``camera`` onto ``terrain``'s grid.

    With ``occlusion`` only visible posts (code 1) get values; without it, every post that
    projects inside the image does (the naive orthophoto, facing-away and occluded included).
    ``interp`` is an :class:`~orthomvp.codes.Interp` or its name. ``visibility`` reuses a
    visibility of this camera on this grid; otherwise it is computed (see
    :func:`~orthomvp.occlusion.visibility.compute_visibility` for ``eps``, ``caster``, ``progress``,
    ``post_scale`` and ``dem``).

    ``image`` may also be (rows, cols) (one band); integer images are taken as float32 with
    their values (see :func:`orthomvp.camera.as_image`). Wrong types, shapes and ranges raise
    :class:`~orthomvp.errors.InputError`, as does a grid too large for the memory.
    """
    interp = Interp(interp)
    of_type(terrain, Terrain, "terrain")
    image = as_image(image)
    camera = check_image(image, camera)
    if visibility is not None:
        of_type(visibility, Visibility, "visibility", " (of compute_visibility) or None")
        check_visibility_of(visibility, terrain, camera)
    check_orthophoto_memory(terrain.shape, image.shape[0], "use a coarser grid (Terrain.regrid)")
    vis = visibility or compute_visibility(
        terrain,
        camera,
        eps=eps,
        caster=caster,
        progress=progress,
        post_scale=post_scale,
        occlusion=occlusion,
        dem=dem,
    )
    data = sample_image(image, vis.uv, interp)
    keep = vis.codes == Code.VISIBLE if occlusion else finite_rows(vis.uv)
    data[:, ~keep] = np.nan
    return Ortho(data, terrain.transform, terrain.crs, vis)


def mosaic(
    terrain: Terrain,
    views: list[tuple[np.ndarray, Camera]],
    *,
    eps: float | None = None,
    interp: Interp | str = Interp.BILINEAR,
    caster: RayCaster | None = None,
    progress: bool = False,
    options: MosaicOptions | None = None,
    holes: str | None = None,
) -> Mosaic:
    """One orthophoto from (image, camera) views, combined as ``options`` say
    (default :class:`~orthomvp.ortho.composite.MosaicOptions`: emission priority, seamlines,
    blending over 8 posts, no balance, holes left empty; see :mod:`orthomvp.ortho.composite`), as
    the engine's mosaic does. The balance's statistics come from the whole grid (the engine's from a
    decimated one), and the blend width is clamped to the widest overlap (BlendWarning).
    All images must have the same number of bands. ``eps`` and ``interp`` as in
    :func:`orthorectify`; ``caster`` reuses a ray caster built on this terrain's occluder surface
    (one is built otherwise). ``holes``: the hole policy
    (:data:`~orthomvp.ortho.holes.HOLES`; None: that of ``options``, by default ``empty``).
    One view gives its mosaic (flags, holes, source) as several do. Of several, views that see
    no post of the grid are left out (:func:`left_out`); GeometryError when none sees one."""
    interp = Interp(interp)
    of_type(terrain, Terrain, "terrain")
    options = options or MosaicOptions()
    of_type(options, MosaicOptions, "options", " or None")
    if holes is not None:
        options = replace(options, holes=holes)
    if not isinstance(views, (list, tuple)) or not views:
        raise InputError(f"a mosaic needs a list of (image, camera) views, got {views!r:.40}")
    for k, view in enumerate(views, start=1):
        if not (isinstance(view, (list, tuple)) and len(view) == 2):
            raise InputError(f"view {k} of the mosaic must be an (image, camera) pair")
    views = [(as_image(img, f"view {k}"), cam) for k, (img, cam) in enumerate(views, start=1)]
    bands = {img.shape[0] for img, _ in views}
    if len(bands) != 1:
        raise InputError(f"the images have different numbers of bands: {sorted(bands)}")
    n, nb = len(views), bands.pop()
    check_orthophoto_memory(terrain.shape, nb * n, "use a coarser grid (Terrain.regrid)")
    caster = caster or occluder_caster(terrain)
    shape = (n, *terrain.shape)
    values = np.full((n, nb, *terrain.shape), np.nan, np.float32)
    codes = np.zeros(shape, np.uint8)
    emission, gsd, nadir = np.full(shape, np.inf), np.full(shape, np.inf), np.full(shape, np.inf)
    doubt = np.zeros(shape, bool)
    slack = np.zeros(shape)
    visibilities = []
    whole = (slice(None), slice(None))
    fused = codes[0].size >= FUSED_POSTS  # (the numba kernels pay for their load)
    geometry = Geometry.SEPARABLE_KERNEL if fused else Geometry.SEPARABLE
    path = VisibilityPath(geometry=geometry, strict=n == 1)  # (several: left_out says)
    for k, (image, camera) in enumerate(views):
        camera = check_image(image, camera)
        vis = compute_visibility(
            terrain, camera, eps=eps, caster=caster, progress=progress, path=path
        )
        visibilities.append(vis)
        codes[k], emission[k], gsd[k] = vis.codes, vis.emission, vis.gsd
        doubt[k] = doubtful(vis.miss, vis.eps)
        slack[k] = np.where(doubt[k], vis.eps - vis.miss, 0.0)
        need = vis.codes == Code.VISIBLE
        if options.holes == "behind":
            need |= vis.codes == Code.FACING_AWAY
        elif options.holes == "naive":
            need |= vis.codes != Code.NODATA
        if options.priority == "nadir" or options.holes == "naive":
            inside = finite_rows(vis.uv)
            nadir[k] = np.where(inside, nadir_angle(terrain, whole, camera, vis.uv), np.inf)
        if need.any():  # (none in a view left out)
            values[k][:, need] = sample_image(image, vis.uv[need], interp)
    left = left_out(codes)
    correction = None
    if options.balance is not None:
        stats = pair_stats(values, codes)
        correction = solve_balance(stats, options.balance, options.reference, left_out=left)
    blend = clamp_blend(options.blend, overlap_width(codes)) if options.blend else 0
    options = replace(options, blend=blend)
    sure = (codes == Code.VISIBLE) & ~doubt

    def test(posts: np.ndarray) -> np.ndarray:
        """Where the views' samples at ``posts`` (views, rows, cols) reach an occluder."""
        out = np.zeros(posts.shape, bool)
        for k, (_, camera) in enumerate(views):
            vis = visibilities[k]
            samples = window_samples(vis.uv, vis.gsd)
            out[k] = support_blocked(
                terrain, whole, camera, samples, vis.emission, posts[k], caster
            )
        return out

    def resample(posts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The samples (bands, posts) at ``posts`` (views, rows, cols) of their clear pixels,
        and those pixels' weights (posts,)."""
        taken, clear = [], []
        for k, (image, camera) in enumerate(views):
            if posts[k].any():
                vis = visibilities[k]
                samples = window_samples(vis.uv, vis.gsd)
                taps, w = clear_taps(
                    terrain, whole, camera, samples, vis.emission, posts[k], caster
                )
                pixels = sample_image(image, taps.reshape(-1, 2), Interp.NEAREST)
                value, weight = clear_blend(pixels.reshape(nb, *w.shape).swapaxes(0, 1), w)
                taken.append(value)
                clear.append(weight)
        return np.concatenate(taken, axis=1), np.concatenate(clear)

    support = Support(test, sure)
    blocked = support(candidates(sure))
    comp = compose(
        values, codes, emission, gsd, nadir, options, correction, doubt, slack=slack,
        blocked=blocked, support=support, resample=resample, fused=fused,
    )  # fmt: skip
    return Mosaic(
        comp.data,
        comp.source.astype(np.uint8 if n < 255 else np.uint16),
        terrain.transform,
        terrain.crs,
        visibilities,
        comp.flags,
        comp.weights,
        correction,
        comp.resampled,
    )


def left_out(codes: np.ndarray) -> tuple[int, ...]:
    """The views (0-based) of a mosaic's ``codes`` (views, rows, cols) that see no post (all
    outside their images), named in one :class:`~orthomvp.errors.LeftOutWarning`;
    GeometryError when every view is, or when a view sees only posts facing away (as
    :func:`~orthomvp.occlusion.visibility.compute_visibility` raises for one)."""
    n = len(codes)
    inside = (codes != Code.NODATA).reshape(n, -1).any(axis=1)
    if not inside.any():
        raise GeometryError(f"none of the {n} views sees a post of the grid")
    seen = np.isin(codes, (Code.VISIBLE, Code.OCCLUDED)).reshape(n, -1).any(axis=1)
    if (inside & ~seen).any():
        raise GeometryError(
            f"view {int(np.argmax(inside & ~seen)) + 1}: every post in the image faces away "
            "from the camera: it looks at the surface from below"
        )
    left = tuple(int(k) for k in np.flatnonzero(~inside))
    if left:
        text = ", ".join(str(k + 1) for k in left)
        see, are = ("sees", "is") if len(left) == 1 else ("see", "are")
        warnings.warn(
            f"{len(left)} of {n} views {see} no post of the grid and {are} left out: {text}",
            LeftOutWarning,
            stacklevel=3,
        )
    return left


def orthophoto_bytes(shape: tuple[int, int], bands: int) -> float:
    """Peak memory of an orthophoto of ``bands`` bands on a grid of ``shape`` posts, bytes."""
    return (
        float(shape[0])
        * float(shape[1])
        * (VISIBILITY_BYTES_PER_POST + BYTES_PER_BAND_POST * bands)
    )


def check_orthophoto_memory(shape: tuple[int, int], bands: int, advice: str) -> None:
    """InputError, before any work, when an orthophoto on ``shape`` posts cannot fit in
    memory (see :mod:`orthomvp.io.preflight`)."""
    rows, cols = shape
    check_memory(
        f"this grid is {count_text(float(rows) * cols)} posts ({cols:,} x {rows:,})",
        orthophoto_bytes(shape, bands),
        advice,
    )
