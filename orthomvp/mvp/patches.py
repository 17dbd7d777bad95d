"""Orthoimage patches through homographies, their normalisation, and the MVP objective.

Section 3.3 of the MVP paper. For a batch of B posts and K views, each view's image is sampled
(bilinear, ``cv2.remap``) on the patch grid through its homography; the patches are normalised
by their Gaussian-weighted mean and standard deviation (eq. 19), the albedo A is their mean
(eq. 21) and the objective is

    f = sum_k sum_z g(z) (A(z) - I_k(z))^2        (eq. 20, with sum_z g(z) = 1)

over the views taking part (weights ``W`` in {0, 1}). With n views, f = (n - 1) (1 - mean
pairwise weighted correlation of the patches), so 0 is perfect agreement. Derivatives with
respect to the plane parameters come from image gradients (sampled with the image) and the
exact derivatives of the homographies, through the normalisation; they give the Gauss-Newton
normal equations of the residuals sqrt(g) (A - I_k).

The patch grid and its weights g are a :class:`~orthomvp.mvp.window.Window`: (i, j) * step posts
around the post, |i|, |j| <= hwin; coarse pyramid levels use a larger step on a smaller image
(see :class:`ViewStack`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from orthomvp.camera import Camera, PinholeCamera
from orthomvp.errors import InputError
from orthomvp.mvp.views import ViewWindow, level_size, undistorted_image
from orthomvp.mvp.window import Window

__all__ = ["MIN_STD", "Evaluation", "ViewStack", "evaluate", "sample_patches", "undistorted_image"]

MIN_STD = 1e-6  # relative to the image's own standard deviation: flatter patches carry nothing


DERIVATIVE = np.array([[1.0, -8.0, 0.0, 8.0, -1.0]], np.float32) / 12.0


def image_gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d/dc and d/dr of a (rows, cols) float32 image, per pixel: the fourth-order central
    difference, which keeps 80% of the slope of a 3.75-pixel wave where the plain central
    difference keeps 60%."""
    gc = cv2.filter2D(image, -1, DERIVATIVE, borderType=cv2.BORDER_REPLICATE)
    gr = cv2.filter2D(image, -1, DERIVATIVE.T, borderType=cv2.BORDER_REPLICATE)
    return gc, gr


@dataclass
class ViewStack:
    """The K views prepared for sampling.

    ``levels[L][k]``: view k at pyramid level L (image reduced 2**L times by ``cv2.pyrDown``) as
    a (rows, cols, 3) float32 array of value and its c and r gradients per pixel. ``F`` (K, 3, 4)
    projection matrices (eq. 9) of the undistorted level-0 images (NaN for cameras that are not
    pinholes: :mod:`orthomvp.mvp.local` approximates them per post); level L pixel = level-0
    pixel / 2**L. ``sizes[L][k]`` = (cols, rows). ``flat[L]`` (K,): the patch standard deviation
    below which a view's patch is taken as flat (MIN_STD times the image's own), computed once.
    The fill value of nodata pixels and the standard deviations are taken in float64, so that
    windows of the image (which sum them in other orders) agree to float32 rounding.
    ``samples`` counts the bilinear samples taken.

    Built from windows of the images (:mod:`orthomvp.mvp.views`), ``levels`` hold the windows,
    ``origins[L]`` (K, 2) float32 their first pixels (c, r) in the whole images at level L,
    and everything else is the whole images'; ``extents[L]`` (K, 4) then records the bounding
    box (c_min, c_max, r_min, r_max) of the positions sampled at level L for views taking
    part (whole-image pixels of that level; NaN once a position was not finite), to check
    that they stayed where the windows are exact.
    """

    levels: list[list[np.ndarray]]
    F: np.ndarray
    sizes: list[list[tuple[int, int]]]
    flat: list[np.ndarray]
    samples: int = 0
    origins: list[np.ndarray] | None = None
    extents: list[np.ndarray] | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _typed: list | None = field(default=None, repr=False)

    def evaluate(
        self,
        level: int,
        H: np.ndarray,
        W: np.ndarray,
        window: Window,
        dH: np.ndarray | None = None,
        extras: bool = True,
        keep_patches: bool = False,
    ) -> Evaluation:
        """:func:`evaluate` on the images of ``level``, counting the bilinear samples taken
        (positions of views allowed to take part, times channels) in ``samples``. The fused
        kernel (:mod:`orthomvp.mvp.kernel`) computes it, the numpy objective only when the
        patches are kept."""
        with self._lock:
            self.samples += int(W.sum()) * len(window.offsets) * (1 if dH is None else 3)
        origins = np.zeros((len(self.flat[level]), 2), np.float32)
        if self.origins is not None:
            origins = self.origins[level]
        if keep_patches:
            track = None
            if self.extents is not None:

                def track(u: np.ndarray, v: np.ndarray) -> None:
                    self._track(level, boxes(u, v, W))

            return evaluate(
                self.levels[level], self.flat[level], H, W, window, dH, extras, True,
                origins=origins, track=track,
            )  # fmt: skip
        from orthomvp.mvp.kernel import fused_evaluate

        res = fused_evaluate(
            self.typed_levels(level), origins, self.flat[level], H, dH, W, window, extras
        )
        if self.extents is not None:
            self._track(level, res.box)
        ev = Evaluation(res.cost, res.used)
        if extras:
            ev.loo = res.loo
        if dH is not None:
            ev.JTJ, ev.JTr = res.JTJ, res.JTr
            if extras:
                ev.JgJ = res.JgJ
        return ev

    def typed_levels(self, level: int) -> object:
        """The images of ``level`` as a numba typed List (made once; :mod:`orthomvp.mvp.kernel`
        takes them so)."""
        from orthomvp.mvp.kernel import typed_images

        with self._lock:
            if self._typed is None:
                self._typed = [None] * len(self.levels)
            if self._typed[level] is None:
                self._typed[level] = typed_images(self.levels[level])
            return self._typed[level]

    def _track(self, level: int, box: np.ndarray) -> None:
        """Widen ``extents[level]`` by the bounding boxes ``box`` (B, K, 4) of the sampled
        positions of each post and view (inf / -inf where not sampled, NaN where not
        finite)."""
        assert self.extents is not None
        lo, hi = box[..., 0::2].min(axis=0), box[..., 1::2].max(axis=0)  # (K, 2), NaN kept
        with self._lock:
            ext = self.extents[level]
            bad = np.isnan(lo).any(axis=1) | np.isnan(hi).any(axis=1) | np.isnan(ext).any(axis=1)
            ext[:, 0::2] = np.minimum(ext[:, 0::2], lo)
            ext[:, 1::2] = np.maximum(ext[:, 1::2], hi)
            ext[bad] = np.nan

    @classmethod
    def build(
        cls,
        images: list[np.ndarray],
        cameras: list[Camera],
        n_levels: int,
        windows: list[ViewWindow] | None = None,
    ) -> ViewStack:
        """From single-band (rows, cols) images (NaN allowed: filled with the mean) and their
        cameras; ``n_levels`` pyramid levels. With ``windows``, each image is that window of
        the camera's image (see :mod:`orthomvp.mvp.views`: its origin a multiple of
        :func:`~orthomvp.mvp.views.alignment`), whose fill value and standard deviations
        come from the window."""
        levels: list[list[np.ndarray]] = [[] for _ in range(n_levels)]
        sizes: list[list[tuple[int, int]]] = [[] for _ in range(n_levels)]
        stds: list[list[float]] = [[] for _ in range(n_levels)]
        Fs = []
        for k, (image, camera) in enumerate(zip(images, cameras, strict=True)):
            view = None if windows is None else windows[k]
            img = np.asarray(image, dtype=np.float32)
            finite = np.isfinite(img)
            if view is None and not finite.any():
                raise InputError("an image holds no valid pixels")
            mean = img[finite].mean(dtype=np.float64) if view is None else view.fill
            fill = np.float32(mean)
            img = np.where(finite, img, fill)
            origin = (0, 0) if view is None else view.origin
            if isinstance(camera, PinholeCamera):
                img, camera = undistorted_image(img, camera, origin)
                Fs.append(camera.F)
            else:
                Fs.append(np.full((3, 4), np.nan))
            for level in range(n_levels):
                if level:
                    img = cv2.pyrDown(img)
                gc, gr = image_gradients(img)
                levels[level].append(np.ascontiguousarray(np.stack([img, gc, gr], axis=-1)))
                if view is None:
                    sizes[level].append((img.shape[1], img.shape[0]))
                    stds[level].append(float(np.std(img, dtype=np.float64)))
                else:
                    sizes[level].append(level_size(view.size, level))
                    stds[level].append(view.std[level])
        flat = [np.array([MIN_STD * max(s, 1e-30) for s in lv], np.float32) for lv in stds]
        stack = cls(levels, np.stack(Fs), sizes, flat)
        if windows is not None:
            stack.origins = [
                np.array([[v.origin[0] >> L, v.origin[1] >> L] for v in windows], np.float32)
                for L in range(n_levels)
            ]
            stack.extents = [
                np.tile([np.inf, -np.inf, np.inf, -np.inf], (len(windows), 1))
                for _ in range(n_levels)
            ]
        return stack


@dataclass
class Evaluation:
    """The objective at B planes: ``cost`` (B,) eq. 20 (inf where fewer than 2 views take
    part); ``used`` (B, K) views that took part; ``JTJ`` (B, 3, 3) and ``JTr`` (B, 3) the
    Gauss-Newton normal equations; ``JgJ`` (B, 3, 3) the same with squared window weights (for
    the uncertainty); ``loo`` (B, K) each view's weighted correlation with the mean of the other
    views (leave-one-out albedo); ``patches`` (B, K, S) the normalised patches and ``albedo``
    (B, S), when asked for."""

    cost: np.ndarray
    used: np.ndarray
    JTJ: np.ndarray | None = None
    JTr: np.ndarray | None = None
    JgJ: np.ndarray | None = None
    loo: np.ndarray | None = None
    patches: np.ndarray | None = None
    albedo: np.ndarray | None = None


def sample_patches(
    images: list[np.ndarray],
    H: np.ndarray,
    offsets: np.ndarray,
    channels: int = 3,
    origins: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sample K ``images`` (rows, cols, 3) through homographies ``H`` (B, K, 3, 3) (patch
    offsets to pixels) at ``offsets`` (S, 2). Returns samples (B, K, S, channels) and the
    pixel positions u, v and 1/w, each (B, K, S) float32. ``origins`` (K, 2) float32: the
    images are windows whose first pixels (c, r) are these whole-image pixels (integers:
    positions shift exactly in float32)."""
    Hf = (H / H[..., 2:3, 2:3]).astype(np.float32)[..., None]  # (B, K, 3, 3, 1)
    oc, orr = offsets[:, 0], offsets[:, 1]
    iw = 1.0 / (Hf[:, :, 2, 0] * oc + Hf[:, :, 2, 1] * orr + Hf[:, :, 2, 2])  # (B, K, S)
    u = (Hf[:, :, 0, 0] * oc + Hf[:, :, 0, 1] * orr + Hf[:, :, 0, 2]) * iw
    v = (Hf[:, :, 1, 0] * oc + Hf[:, :, 1, 1] * orr + Hf[:, :, 1, 2]) * iw
    B, K, S = u.shape
    out = np.empty((B, K, S, channels), np.float32)
    for k, img in enumerate(images):
        src = img if channels == img.shape[-1] else np.ascontiguousarray(img[..., :channels])
        uk, vk = u[:, k], v[:, k]
        if origins is not None:
            uk, vk = uk - origins[k, 0], vk - origins[k, 1]
        for b0 in range(0, B, 32000):  # cv2.remap maps hold fewer than 32768 rows
            sl = slice(b0, b0 + 32000)
            s = cv2.remap(src, uk[sl], vk[sl], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            out[sl, k] = s.reshape(-1, S, channels)
    return out, u, v, iw


def evaluate(
    images: list[np.ndarray],
    flat: np.ndarray,
    H: np.ndarray,
    W: np.ndarray,
    window: Window,
    dH: np.ndarray | None = None,
    extras: bool = True,
    keep_patches: bool = False,
    *,
    origins: np.ndarray | None = None,
    track: Callable[[np.ndarray, np.ndarray], None] | None = None,
) -> Evaluation:
    """The objective (eq. 20) at B planes seen through K views, sampled on ``window``.

    ``flat`` (K,): patch standard deviations at or below which a view's patch carries nothing;
    ``H`` (B, K, 3, 3): homographies from patch offsets to image pixels (any scale, w > 0);
    ``W`` (B, K) bool: views allowed to take part; ``dH`` (B, K, P, 3, 3): derivatives of H
    with respect to P plane parameters, on the same scale as H, to get the normal equations.
    ``extras``: also ``loo`` and (with ``dH``) ``JgJ``, which the iterations do not need.
    ``origins``: see :func:`sample_patches`; ``track(u, v)`` is called with the sampled
    positions (B, K, S). Positions and samples are float32, everything after them float64:
    the reference of the fused kernel (:mod:`orthomvp.mvp.kernel`), which the fitter runs.
    """
    jac = dH is not None
    offsets, g = window.offsets, window.weights
    smp, u, v, iw = sample_patches(images, H, offsets, 3 if jac else 1, origins)
    if track is not None:
        track(u, v)
    smp, u, v, iw, g = (x.astype(np.float64) for x in (smp, u, v, iw, g))
    It = smp[..., 0]
    m = It @ g
    c = It - m[..., None]
    sd = np.sqrt(np.maximum((c * c) @ g, 0.0))
    used = W & (sd > flat)
    usedf = used.astype(np.float64)
    n = usedf.sum(axis=1)
    Ik = c / np.where(used, sd, 1.0)[..., None]
    Ik *= usedf[..., None]
    nn = np.maximum(n, 1.0)
    A = Ik.sum(axis=1) / nn[:, None]
    R = (A[:, None, :] - Ik) * usedf[..., None]
    cost = ((R * R) @ g).sum(axis=1)
    cost = np.where(n >= 2, cost, np.inf)
    out = Evaluation(cost.astype(np.float64), used)
    if extras:  # leave-one-out albedo correlation of each view
        out.loo = _leave_one_out(Ik, A, used, n, nn, g)
    if keep_patches:
        out.patches, out.albedo = Ik, A
    if not jac:
        return out
    # d(raw sample)/d(param) = grad O . d(u, v)/d(param), with
    # d(u, v) = (d(x, y) - (u, v) dw) / w and d(x, y, w) = dH (oc, or, 1)
    a = smp[..., 1] * iw
    b = smp[..., 2] * iw
    cc = -(a * u + b * v)
    dHs = (dH / H[:, :, None, 2:3, 2:3]).astype(np.float32).astype(np.float64)
    D = dHs @ _homogeneous(offsets).astype(np.float64)  # (B, K, P, 3, S)
    dIt = a[:, :, None] * D[:, :, :, 0]
    dIt += b[:, :, None] * D[:, :, :, 1]
    dIt += cc[:, :, None] * D[:, :, :, 2]  # (B, K, P, S)
    # through eq. 19: dI = (dIt - <1, dIt> - I <I, dIt>) / sd, with <x, y> = sum g x y
    dm = dIt @ g
    ds = dIt @ (Ik * g)[..., None]
    dI = dIt - dm[..., None]
    dI -= Ik[:, :, None, :] * ds
    dI *= (usedf / np.where(used, sd, 1.0))[..., None, None]
    dA = dI.sum(axis=1) / nn[:, None, None]  # (B, P, S)
    # residuals sqrt(g) (A - I_k): sum_k <dR_k, dR_k> = sum_k <dI_k, dI_k> - n <dA, dA>, and
    # sum_k <dR_k, R_k> = -sum_k <dI_k, R_k> because sum_k R_k = 0
    nf = n[:, None, None]
    dIg = dI * g
    out.JTJ = (
        np.sum(dIg @ np.swapaxes(dI, -1, -2), axis=1) - nf * ((dA * g) @ np.swapaxes(dA, -1, -2))
    ).astype(np.float64)
    out.JTr = -np.sum(dI @ (R * g)[..., None], axis=1)[..., 0].astype(np.float64)
    if not extras:
        return out
    g2 = g * g
    out.JgJ = (
        np.sum((dIg * g) @ np.swapaxes(dI, -1, -2), axis=1)
        - nf * ((dA * g2) @ np.swapaxes(dA, -1, -2))
    ).astype(np.float64)
    return out


def boxes(u: np.ndarray, v: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(B, K, 4) bounding boxes (c_min, c_max, r_min, r_max) of the positions ``u``, ``v``
    (B, K, S) of each post in each view allowed (``W`` (B, K)): inf / -inf elsewhere, NaN
    where a position is not finite."""
    box = np.stack([u.min(-1), u.max(-1), v.min(-1), v.max(-1)], axis=-1)
    box[~np.isfinite(u).all(-1) | ~np.isfinite(v).all(-1)] = np.nan
    box[~W] = [np.inf, -np.inf, np.inf, -np.inf]
    return box


def _leave_one_out(
    Ik: np.ndarray, A: np.ndarray, used: np.ndarray, n: np.ndarray, nn: np.ndarray, g: np.ndarray
) -> np.ndarray:
    """(B, K) weighted correlation of each used patch with the mean of the other used ones."""
    Aloo = (nn[:, None, None] * A[:, None, :] - Ik) / np.maximum(nn - 1.0, 1.0)[:, None, None]
    num = (Ik * Aloo) @ g
    den = np.sqrt(np.maximum((Aloo * Aloo) @ g, 1e-30))
    return np.where(used & (n[:, None] >= 2), num / den, np.nan)


def _homogeneous(offsets: np.ndarray) -> np.ndarray:
    """(3, S) float32 rows c, r, 1 of patch offsets (S, 2)."""
    return np.vstack([offsets.T, np.ones(len(offsets))]).astype(np.float32)
