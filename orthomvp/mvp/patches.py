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
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from orthomvp.camera import NullDistortion, PinholeCamera
from orthomvp.errors import InputError
from orthomvp.mvp.window import Window

MIN_STD = 1e-6  # relative to the image's own standard deviation: flatter patches carry nothing


def undistorted_image(image: np.ndarray, camera: PinholeCamera) -> tuple[np.ndarray, PinholeCamera]:
    """Resample a (rows, cols) image of a camera with lens distortion into the image of the
    same camera without it (same size and intrinsics), so that homographies apply."""
    if isinstance(camera.distortion, NullDistortion):
        return image, camera
    rows, cols = image.shape
    v, u = np.mgrid[0:rows, 0:cols].astype(np.float64)
    focal = np.array([camera.fu, camera.fv])
    offset = np.array([camera.cu, camera.cv])
    und = np.stack([u, v], axis=-1) * camera.pitch
    src = camera.distortion.distort(und, focal, offset) / camera.pitch
    out = cv2.remap(
        image.astype(np.float32),
        src[..., 0].astype(np.float32),
        src[..., 1].astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out, replace(camera, distortion=NullDistortion())


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
    projection matrices (eq. 9) of the undistorted level-0 images; level L pixel = level-0 pixel
    / 2**L. ``sizes[L][k]`` = (cols, rows). ``flat[L]`` (K,): the patch standard deviation
    below which a view's patch is taken as flat (MIN_STD times the image's own), computed once.
    ``samples`` counts the bilinear samples taken.
    """

    levels: list[list[np.ndarray]]
    F: np.ndarray
    sizes: list[list[tuple[int, int]]]
    flat: list[np.ndarray]
    samples: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

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
        (positions times channels) in ``samples``."""
        with self._lock:
            self.samples += H.shape[0] * H.shape[1] * len(window.offsets) * (1 if dH is None else 3)
        return evaluate(
            self.levels[level], self.flat[level], H, W, window, dH, extras, keep_patches
        )

    @classmethod
    def build(
        cls, images: list[np.ndarray], cameras: list[PinholeCamera], n_levels: int
    ) -> ViewStack:
        """From single-band (rows, cols) images (NaN allowed: filled with the mean) and their
        cameras; ``n_levels`` pyramid levels."""
        levels: list[list[np.ndarray]] = [[] for _ in range(n_levels)]
        sizes: list[list[tuple[int, int]]] = [[] for _ in range(n_levels)]
        Fs = []
        for image, camera in zip(images, cameras, strict=True):
            img = np.asarray(image, dtype=np.float32)
            finite = np.isfinite(img)
            if not finite.any():
                raise InputError("an image holds no valid pixels")
            img = np.where(finite, img, np.float32(img[finite].mean()))
            img, camera = undistorted_image(img, camera)
            Fs.append(camera.F)
            for level in range(n_levels):
                if level:
                    img = cv2.pyrDown(img)
                gc, gr = image_gradients(img)
                levels[level].append(np.ascontiguousarray(np.stack([img, gc, gr], axis=-1)))
                sizes[level].append((img.shape[1], img.shape[0]))
        flat = [
            np.array([MIN_STD * max(float(np.std(img[..., 0])), 1e-30) for img in lv], np.float32)
            for lv in levels
        ]
        return cls(levels, np.stack(Fs), sizes, flat)


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
    images: list[np.ndarray], H: np.ndarray, offsets: np.ndarray, channels: int = 3
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sample K ``images`` (rows, cols, 3) through homographies ``H`` (B, K, 3, 3) (patch
    offsets to pixels) at ``offsets`` (S, 2). Returns samples (B, K, S, channels) and the
    pixel positions u, v and 1/w, each (B, K, S) float32."""
    Hf = (H / H[..., 2:3, 2:3]).astype(np.float32)
    xyw = Hf @ _homogeneous(offsets)  # (B, K, 3, S)
    iw = 1.0 / xyw[:, :, 2]
    u = xyw[:, :, 0] * iw
    v = xyw[:, :, 1] * iw
    B, K, S = u.shape
    out = np.empty((B, K, S, channels), np.float32)
    for k, img in enumerate(images):
        src = img if channels == img.shape[-1] else np.ascontiguousarray(img[..., :channels])
        for b0 in range(0, B, 32000):  # cv2.remap maps hold fewer than 32768 rows
            sl = slice(b0, b0 + 32000)
            s = cv2.remap(
                src, u[sl, k], v[sl, k], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
            )
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
) -> Evaluation:
    """The objective (eq. 20) at B planes seen through K views, sampled on ``window``.

    ``flat`` (K,): patch standard deviations at or below which a view's patch carries nothing;
    ``H`` (B, K, 3, 3): homographies from patch offsets to image pixels (any scale, w > 0);
    ``W`` (B, K) bool: views allowed to take part; ``dH`` (B, K, P, 3, 3): derivatives of H
    with respect to P plane parameters, on the same scale as H, to get the normal equations.
    ``extras``: also ``loo`` and (with ``dH``) ``JgJ``, which the iterations do not need.
    """
    jac = dH is not None
    offsets, g = window.offsets, window.weights
    smp, u, v, iw = sample_patches(images, H, offsets, 3 if jac else 1)
    It = smp[..., 0]
    m = It @ g
    c = It - m[..., None]
    sd = np.sqrt(np.maximum((c * c) @ g, 0.0))
    used = W & (sd > flat)
    usedf = used.astype(np.float32)
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
    dHs = (dH / H[:, :, None, 2:3, 2:3]).astype(np.float32)
    D = dHs @ _homogeneous(offsets)  # (B, K, P, 3, S)
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
