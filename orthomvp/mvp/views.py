"""Windows of views: the fit's image pyramids built from a window of each image, equal to the
pyramids of the whole image wherever the fit samples them.

A :class:`~orthomvp.mvp.patches.ViewStack` built from windows (:class:`ViewWindow`) keeps the
whole images' cameras, sizes and thresholds, and samples each window at the whole image's
pixel positions shifted by the window's origin (an integer at every level, subtracted in
float32 exactly). Where those samples read only pixels that the window computes as the whole
image would (:func:`exact_masks`), the fit is the same, bit for bit, as on the whole images.

What makes a window's pixel exact, level by level (checked by ``tests/test_fit_engine.py``
against the whole image, OpenCV's vector code included):

- level 0: without lens distortion every pixel; with it, the pixels whose undistortion reads
  (bilinear, :func:`~orthomvp.mvp.patches.undistorted_image`) only window pixels, or beyond an
  image edge that the window shares (both replicate the same border);
- level L + 1 (``cv2.pyrDown``, 5 x 5 taps): the pixels whose taps at level L are exact;
- a sample (value and the 5-tap gradients, bilinear): exact when the four pixels around it are
  exact 2 pixels either way;
- and at every level, nothing within :data:`EDGE` pixels of a window edge that is not an image
  edge: OpenCV computes pixels next to an image border in other code than the rest, whose
  float32 results may differ in the last bit.

Windows start on multiples of :func:`alignment` pixels: then every level's window starts on a
whole pixel of that level, on a multiple of :data:`LANES` (the widest vector OpenCV uses for
float32), so that OpenCV's vector loops split a window's rows where they split the whole
image's, and pixels at a shared image edge come out of the same code.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.ndimage import minimum_filter

from orthomvp.camera import Camera, NullDistortion, PinholeCamera
from orthomvp.errors import InputError

LANES = 32
"""Pixels that every level's window origin is a multiple of (AVX-512 holds 16 float32)."""

EDGE = 8
"""Pixels next to a window edge inside the image that are never taken as exact (OpenCV's
border code reaches 6 pixels into pyrDown's and filter2D's results here)."""

MARGIN = EDGE + 4
"""Pixels of each level read around the samples: :data:`EDGE`, the gradients' 2 and the
pyramid's taps."""

WindowT = tuple[int, int, int, int]
"""(row0, row1, col0, col1), half-open, in pixels of the whole image."""

Box = tuple[float, float, float, float]
"""(c_min, c_max, r_min, r_max) of pixel positions."""


def alignment(levels: int) -> int:
    """Pixels that window origins are multiples of, for ``levels`` pyramid levels."""
    return LANES << (levels - 1)


def level_size(size: tuple[int, int], level: int) -> tuple[int, int]:
    """(width, height) of an image of ``size`` at pyramid ``level`` (``cv2.pyrDown`` rounds
    up)."""
    w, h = size
    for _ in range(level):
        w, h = (w + 1) // 2, (h + 1) // 2
    return w, h


@dataclass(frozen=True)
class ViewWindow:
    """Where the pixels given for a view lie in its whole image, and what the whole image
    sets: ``window`` (row0, row1, col0, col1) in its pixels (row0 and col0 multiples of
    :func:`alignment`), ``size`` its (width, height), ``fill`` the value of its nodata pixels
    (the mean of its valid ones) and ``std`` per pyramid level the standard deviation of the
    image (filled, without lens distortion), from which
    :class:`~orthomvp.mvp.patches.ViewStack` sets its flatness threshold."""

    window: WindowT
    size: tuple[int, int]
    fill: float
    std: tuple[float, ...]

    @property
    def origin(self) -> tuple[int, int]:
        """(col0, row0) of the window."""
        return self.window[2], self.window[0]

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the window."""
        r0, r1, c0, c1 = self.window
        return r1 - r0, c1 - c0

    @property
    def whole(self) -> bool:
        """Whether the window is the whole image."""
        return self.window == (0, self.size[1], 0, self.size[0])


def has_lens(camera: Camera) -> bool:
    """Whether ``camera`` is a pinhole with lens distortion (whose images the fit resamples
    without it); other cameras' images are taken as they are."""
    return isinstance(camera, PinholeCamera) and not isinstance(camera.distortion, NullDistortion)


def source_map(camera: PinholeCamera, window: WindowT) -> np.ndarray:
    """Where each pixel of ``window`` of the image without lens distortion lies in the image
    with it: (rows, cols, 2) float64 positions (c, r) in pixels of the whole image."""
    r0, r1, c0, c1 = window
    v, u = np.mgrid[r0:r1, c0:c1].astype(np.float64)
    focal = np.array([camera.fu, camera.fv])
    offset = np.array([camera.cu, camera.cv])
    und = np.stack([u, v], axis=-1) * camera.pitch
    return camera.distortion.distort(und, focal, offset) / camera.pitch


def undistorted_image(
    image: np.ndarray,
    camera: PinholeCamera,
    origin: tuple[int, int] = (0, 0),
    src: np.ndarray | None = None,
) -> tuple[np.ndarray, PinholeCamera]:
    """Resample a (rows, cols) image of a camera with lens distortion into the image of the
    same camera without it (same size and intrinsics), so that homographies apply. The image
    may be a window of the camera's image whose first pixel is ``origin`` (c, r) there: its
    pixels are then the whole image's wherever their source lies in the window (module
    docstring). ``src``: the window's :func:`source_map`, when already known."""
    if isinstance(camera.distortion, NullDistortion):
        return image, camera
    rows, cols = image.shape
    c0, r0 = origin
    if src is None:
        src = source_map(camera, (r0, r0 + rows, c0, c0 + cols))
    out = cv2.remap(
        image.astype(np.float32),
        src[..., 0].astype(np.float32) - np.float32(c0),
        src[..., 1].astype(np.float32) - np.float32(r0),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out, replace(camera, distortion=NullDistortion())


def _edges(window: WindowT, size: tuple[int, int]) -> tuple[bool, bool, bool, bool]:
    """Whether the window's top, bottom, left and right edges are the image's."""
    r0, r1, c0, c1 = window
    return r0 == 0, r1 == size[1], c0 == 0, c1 == size[0]


def _erode(mask: np.ndarray, edges: tuple[bool, bool, bool, bool], radius: int) -> np.ndarray:
    """Pixels whose (2 radius + 1)^2 neighbourhood is all ``mask``; beyond an image edge the
    neighbourhood continues as the edge's own pixels, beyond another edge it is not exact."""
    top, bottom, left, right = edges
    pad = np.pad(mask, radius, mode="edge")
    if not top:
        pad[:radius] = False
    if not bottom:
        pad[-radius:] = False
    if not left:
        pad[:, :radius] = False
    if not right:
        pad[:, -radius:] = False
    out = minimum_filter(pad.view(np.uint8), size=2 * radius + 1, mode="nearest")
    return out[radius:-radius, radius:-radius].astype(bool)


def _inner(shape: tuple[int, int], edges: tuple[bool, bool, bool, bool]) -> np.ndarray:
    """False within :data:`EDGE` pixels of the edges that are not the image's."""
    top, bottom, left, right = edges
    out = np.ones(shape, bool)
    if not top:
        out[:EDGE] = False
    if not bottom:
        out[max(shape[0] - EDGE, 0) :] = False
    if not left:
        out[:, :EDGE] = False
    if not right:
        out[:, max(shape[1] - EDGE, 0) :] = False
    return out


def _tap_mask(src: np.ndarray, window: WindowT, size: tuple[int, int]) -> np.ndarray:
    """Pixels whose bilinear taps at positions ``src`` (rows, cols, 2), clamped to the image
    as BORDER_REPLICATE clamps them, all lie in ``window``."""
    r0, r1, c0, c1 = window
    ok = np.isfinite(src).all(axis=-1)
    for axis, (lo, hi, n) in enumerate(((c0, c1, size[0]), (r0, r1, size[1]))):
        with np.errstate(invalid="ignore"):
            tap = np.floor(src[..., axis])
        for t in (tap, tap + 1):
            t = np.clip(np.nan_to_num(t), 0, n - 1)
            ok &= (t >= lo) & (t <= hi - 1)
    return ok


def value_masks(
    view: ViewWindow, camera: Camera, levels: int, src: np.ndarray | None = None
) -> list[np.ndarray]:
    """Per pyramid level, the window's pixels whose values are the whole image's (module
    docstring; :data:`EDGE` not applied); ``src``: the window's :func:`source_map`, when
    already known."""
    edges = _edges(view.window, view.size)
    if not has_lens(camera) or view.whole:
        value = np.ones(view.shape, bool)
    else:
        if src is None:
            src = source_map(camera, view.window)
        value = _tap_mask(src, view.window, view.size)
    out = [value]
    for _ in range(1, levels):
        value = _erode(value, edges, 2)[::2, ::2]
        out.append(value)
    return out


def exact_masks(view: ViewWindow, camera: Camera, levels: int) -> list[np.ndarray]:
    """Per pyramid level, the window's pixels (of that level) around which a bilinear sample
    of value and gradients is the whole image's: its four pixels must be True here."""
    edges = _edges(view.window, view.size)
    return [
        _erode(value, edges, 2) & _inner(value.shape, edges)
        for value in value_masks(view, camera, levels)
    ]


def covers(
    view: ViewWindow, masks: list[np.ndarray], level: int, box: Box, finite: bool = True
) -> bool:
    """Whether bilinear samples at level-``level`` pixel positions (of the whole image)
    within ``box`` read only exact pixels of the window (``masks`` of :func:`exact_masks`);
    ``finite=False``: some positions were not finite (only the whole image covers them)."""
    if not finite:
        return view.whole
    u0, u1, v0, v1 = box
    if not u0 <= u1:  # no samples
        return True
    w, h = level_size(view.size, level)
    oc, orow = view.origin[0] >> level, view.origin[1] >> level
    mask = masks[level]
    ca, cb = (int(np.clip(np.floor(x) + k, 0, w - 1)) for x, k in ((u0, 0), (u1, 1)))
    ra, rb = (int(np.clip(np.floor(x) + k, 0, h - 1)) for x, k in ((v0, 0), (v1, 1)))
    if ca < oc or ra < orow or cb >= oc + mask.shape[1] or rb >= orow + mask.shape[0]:
        return False
    return bool(mask[ra - orow : rb - orow + 1, ca - oc : cb - oc + 1].all())


def window_for(box: Box, camera: Camera, size: tuple[int, int], levels: int) -> WindowT:
    """The aligned window of the image (``size`` (width, height)) whose pyramid is exact for
    bilinear samples at level-0 positions (of the image without lens distortion) in ``box``,
    at every one of ``levels`` levels: the box grown by :data:`MARGIN` pixels of the coarsest
    level, with the positions its lens distortion reads, origins rounded down to
    :func:`alignment`, ends up to it, clipped to the image."""
    width, height = size
    grow = MARGIN << (levels - 1)
    u0, u1, v0, v1 = (float(x) for x in box)
    u0, v0 = max(u0 - grow, -grow), max(v0 - grow, -grow)
    u1, v1 = min(u1 + grow, width - 1 + grow), min(v1 + grow, height - 1 + grow)
    if not (u0 <= u1 and v0 <= v1):
        u0, u1, v0, v1 = 0.0, 0.0, 0.0, 0.0
    if has_lens(camera):
        cs, rs = np.linspace(u0, u1, 65), np.linspace(v0, v1, 65)
        border = np.concatenate(
            [
                np.stack([cs, np.full(65, v0)], -1),
                np.stack([cs, np.full(65, v1)], -1),
                np.stack([np.full(65, u0), rs], -1),
                np.stack([np.full(65, u1), rs], -1),
                np.stack(np.meshgrid(cs[::8], rs[::8]), -1).reshape(-1, 2),
            ]
        )
        focal = np.array([camera.fu, camera.fv])
        offset = np.array([camera.cu, camera.cv])
        src = camera.distortion.distort(border * camera.pitch, focal, offset) / camera.pitch
        src = src[np.isfinite(src).all(axis=-1)]
        if len(src):
            u0, v0 = min(u0, src[:, 0].min() - 2), min(v0, src[:, 1].min() - 2)
            u1, v1 = max(u1, src[:, 0].max() + 2), max(v1, src[:, 1].max() + 2)
    a = alignment(levels)
    c0 = int(np.clip(np.floor(u0 / a) * a, 0, max(width - 1, 0) // a * a))
    r0 = int(np.clip(np.floor(v0 / a) * a, 0, max(height - 1, 0) // a * a))
    c1 = int(np.clip(np.ceil((u1 + 2) / a) * a, c0 + 1, width))
    r1 = int(np.clip(np.ceil((v1 + 2) / a) * a, r0 + 1, height))
    return r0, r1, c0, c1


def union(a: WindowT, b: WindowT) -> WindowT:
    """The smallest window holding both."""
    return min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3])


def view_statistics(
    read: Callable[[WindowT], np.ndarray],
    camera: Camera,
    size: tuple[int, int],
    levels: int,
    block: int = 2048,
    progress: Callable[[int], None] | None = None,
) -> tuple[float, tuple[float, ...]]:
    """What :class:`~orthomvp.mvp.patches.ViewStack` takes from a whole image, from windows
    of it: the mean of its valid pixels (``fill`` for the others) and, per pyramid level, the
    standard deviation of the image (filled, without lens distortion), to float rounding.
    ``read(window)`` gives band 1 of a window as float32 with NaN at nodata. Two passes over
    the image in blocks of ``block`` pixels a side (with margins); ``progress(n)`` counts
    pixel rows."""
    width, height = size
    total, count = 0.0, 0
    for r0 in range(0, height, block):
        part = read((r0, min(r0 + block, height), 0, width))
        ok = np.isfinite(part)
        total += float(part[ok].sum(dtype=np.float64))
        count += int(ok.sum())
        if progress:
            progress(part.shape[0])
    if not count:
        raise InputError("an image holds no valid pixels")
    fill = float(np.float32(total / count))
    step = max(alignment(levels), block // alignment(levels) * alignment(levels))
    sums = np.zeros((levels, 3))  # count, sum, sum of squares (about fill)
    for r0 in range(0, height, step):
        for c0 in range(0, width, step):
            core = (r0, min(r0 + step, height), c0, min(c0 + step, width))
            box = (core[2], core[3] - 1, core[0], core[1] - 1)
            win = window_for(box, camera, size, levels)
            view = ViewWindow(win, size, fill, (1.0,) * levels)
            img = read(win)
            img = np.where(np.isfinite(img), img, np.float32(fill))
            src = None
            if has_lens(camera):
                src = source_map(camera, win)
                img, _ = undistorted_image(img, camera, view.origin, src)
            masks = value_masks(view, camera, levels, src)
            edges = _edges(win, size)
            for level in range(levels):
                if level:
                    img = cv2.pyrDown(img)
                a, b, c, d = (-(-x // (1 << level)) for x in core)  # the core at this level
                rows = slice(a - (win[0] >> level), b - (win[0] >> level))
                cols = slice(c - (win[2] >> level), d - (win[2] >> level))
                exact = masks[level] & _inner(masks[level].shape, edges)
                if not exact[rows, cols].all():  # pragma: no cover - window_for's margin holds
                    raise AssertionError("statistics block outside its exact window")
                values = img[rows, cols].astype(np.float64) - fill
                sums[level] += (values.size, values.sum(), (values * values).sum())
            if progress and c0 == 0:
                progress(core[1] - core[0])
    n, s1, s2 = sums.T
    return fill, tuple(float(x) for x in np.sqrt(np.maximum(s2 / n - (s1 / n) ** 2, 0.0)))
