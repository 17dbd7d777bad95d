"""The MVP objective as one fused numba kernel, parallel over posts.

Per post and view the kernel applies the homography to the patch offsets, samples the image,
its c and r gradients bilinearly (as ``cv2.remap`` does: BORDER_REPLICATE, exact weights),
normalises the patch (eq. 19), and accumulates the albedo, the cost (eq. 20) and the
Gauss-Newton normal equations, without the (B, K, P, S) temporaries of the numpy objective
(:func:`orthomvp.mvp.patches.evaluate`, which stays as its reference). Each post is reduced
by one thread in a fixed order, so a post's results do not depend on the batch it is in or on
the number of threads. Per-sample positions and derivatives are float32 as in the numpy
objective; sums over samples and views are float64.

numba is imported here only, and this module only when the fitter first evaluates; the first
call compiles (a few seconds, see ``orthomvp bench``) into numba's cache: beside this file
when its directory is writable, else the user's cache directory (``~/.cache/numba``) or
``NUMBA_CACHE_DIR``; without any writable place it compiles in every process.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np
from numba.typed import List

from orthomvp.mvp.window import Window

__all__ = ["KernelResult", "compile_seconds", "fused_evaluate"]

_COMPILE_S: float | None = None


def _evaluate(
    images,  # noqa: ANN001 - numba typed List of (rows, cols, 3) float32 arrays
    origins: np.ndarray,
    flat: np.ndarray,
    H: np.ndarray,
    dH: np.ndarray,
    W: np.ndarray,
    offsets: np.ndarray,
    g: np.ndarray,
    jac: bool,
    extras: bool,
    cost: np.ndarray,
    used: np.ndarray,
    JTJ: np.ndarray,
    JTr: np.ndarray,
    JgJ: np.ndarray,
    loo: np.ndarray,
    box: np.ndarray,
) -> None:
    """The numba kernel behind :func:`fused_evaluate` (its arguments; outputs filled in)."""
    B, K = W.shape
    S = offsets.shape[0]
    P = dH.shape[2]
    one = np.float32(1.0)
    for b in numba.prange(B):
        Ik = np.zeros((K, S))
        dI = np.zeros((K, P, S))
        dIt = np.empty((P, S), np.float32)
        sds = np.ones(K)
        n = 0
        for k in range(K):
            box[b, k, 0] = np.inf
            box[b, k, 1] = -np.inf
            box[b, k, 2] = np.inf
            box[b, k, 3] = -np.inf
            used[b, k] = False
            loo[b, k] = np.nan
            if not W[b, k]:
                continue
            img = images[k]
            rows, cols = img.shape[0], img.shape[1]
            oc, orr = origins[k, 0], origins[k, 1]
            h22 = H[b, k, 2, 2]
            Hf = np.empty((3, 3), np.float32)
            for i in range(3):
                for j in range(3):
                    Hf[i, j] = np.float32(H[b, k, i, j] / h22)
            Df = np.empty((P, 3, 3), np.float32)
            if jac:
                for p in range(P):
                    for i in range(3):
                        for j in range(3):
                            Df[p, i, j] = np.float32(dH[b, k, p, i, j] / h22)
            umin, umax, vmin, vmax = np.inf, -np.inf, np.inf, -np.inf
            finite = True
            It = Ik[k]
            for s in range(S):
                xo, yo = offsets[s, 0], offsets[s, 1]
                x = Hf[0, 0] * xo + Hf[0, 1] * yo + Hf[0, 2]
                y = Hf[1, 0] * xo + Hf[1, 1] * yo + Hf[1, 2]
                w = Hf[2, 0] * xo + Hf[2, 1] * yo + Hf[2, 2]
                iw = one / w
                u = x * iw
                v = y * iw
                if np.isfinite(u) and np.isfinite(v):
                    umin = min(umin, u)
                    umax = max(umax, u)
                    vmin = min(vmin, v)
                    vmax = max(vmax, v)
                    uc = u - oc
                    vc = v - orr
                    fu = np.floor(uc)
                    fv = np.floor(vc)
                    fx = uc - fu
                    fy = vc - fv
                    ic = int(min(max(fu, -1.0), cols))  # far outside: the border pixel
                    ir = int(min(max(fv, -1.0), rows))
                    c0 = min(max(ic, 0), cols - 1)
                    c1 = min(max(ic + 1, 0), cols - 1)
                    r0 = min(max(ir, 0), rows - 1)
                    r1 = min(max(ir + 1, 0), rows - 1)
                else:
                    finite = False
                    fx = np.float32(0.0)
                    fy = np.float32(0.0)
                    c0 = c1 = r0 = r1 = 0
                w00 = (one - fy) * (one - fx)
                w01 = (one - fy) * fx
                w10 = fy * (one - fx)
                w11 = fy * fx
                It[s] = (
                    img[r0, c0, 0] * w00
                    + img[r0, c1, 0] * w01
                    + img[r1, c0, 0] * w10
                    + img[r1, c1, 0] * w11
                )
                if jac:
                    gc = (
                        img[r0, c0, 1] * w00
                        + img[r0, c1, 1] * w01
                        + img[r1, c0, 1] * w10
                        + img[r1, c1, 1] * w11
                    )
                    gr = (
                        img[r0, c0, 2] * w00
                        + img[r0, c1, 2] * w01
                        + img[r1, c0, 2] * w10
                        + img[r1, c1, 2] * w11
                    )
                    a = gc * iw
                    bb = gr * iw
                    cc = -(a * u + bb * v)
                    for p in range(P):
                        d0 = Df[p, 0, 0] * xo + Df[p, 0, 1] * yo + Df[p, 0, 2]
                        d1 = Df[p, 1, 0] * xo + Df[p, 1, 1] * yo + Df[p, 1, 2]
                        d2 = Df[p, 2, 0] * xo + Df[p, 2, 1] * yo + Df[p, 2, 2]
                        dIt[p, s] = a * d0 + bb * d1 + cc * d2
            if finite:
                box[b, k, 0], box[b, k, 1], box[b, k, 2], box[b, k, 3] = umin, umax, vmin, vmax
            else:
                box[b, k, :] = np.nan
            # eq. 19: I = (It - <1, It>) / sd, with <x, y> = sum g x y
            m = 0.0
            for s in range(S):
                m += g[s] * It[s]
            var = 0.0
            for s in range(S):
                It[s] -= m
                var += g[s] * It[s] * It[s]
            sd = np.sqrt(max(var, 0.0))
            if not sd > flat[k]:
                It[:] = 0.0
                continue
            used[b, k] = True
            n += 1
            sds[k] = sd
            for s in range(S):
                It[s] /= sd
            if jac:  # dI = (dIt - <1, dIt> - I <I, dIt>) / sd
                for p in range(P):
                    dm = 0.0
                    ds = 0.0
                    for s in range(S):
                        dm += g[s] * dIt[p, s]
                        ds += g[s] * It[s] * dIt[p, s]
                    for s in range(S):
                        dI[k, p, s] = (dIt[p, s] - dm - It[s] * ds) / sd
        nn = max(n, 1)
        A = np.zeros(S)
        for k in range(K):
            if used[b, k]:
                for s in range(S):
                    A[s] += Ik[k, s]
        for s in range(S):
            A[s] /= nn
        f = 0.0
        for k in range(K):
            if used[b, k]:
                for s in range(S):
                    r = A[s] - Ik[k, s]
                    f += g[s] * r * r
        cost[b] = f if n >= 2 else np.inf
        if extras and n >= 2:  # each view against the mean of the others (leave-one-out)
            for k in range(K):
                if used[b, k]:
                    num = 0.0
                    den = 0.0
                    for s in range(S):
                        al = (nn * A[s] - Ik[k, s]) / max(nn - 1.0, 1.0)
                        num += g[s] * Ik[k, s] * al
                        den += g[s] * al * al
                    loo[b, k] = num / np.sqrt(max(den, 1e-30))
        if not jac:
            continue
        # residuals sqrt(g) (A - I_k), their derivatives dR_k = dA - dI_k over the used views
        dA = np.zeros((P, S))
        for k in range(K):
            if used[b, k]:
                for p in range(P):
                    for s in range(S):
                        dA[p, s] += dI[k, p, s]
        for p in range(P):
            for s in range(S):
                dA[p, s] /= nn
        for p in range(P):
            JTr[b, p] = 0.0
            for q in range(P):
                JTJ[b, p, q] = 0.0
                JgJ[b, p, q] = 0.0
        for k in range(K):
            if not used[b, k]:
                continue
            for p in range(P):
                t = 0.0
                for s in range(S):
                    t += g[s] * (dA[p, s] - dI[k, p, s]) * (A[s] - Ik[k, s])
                JTr[b, p] += t
                for q in range(p + 1):
                    t1 = 0.0
                    t2 = 0.0
                    for s in range(S):
                        e = g[s] * (dA[p, s] - dI[k, p, s]) * (dA[q, s] - dI[k, q, s])
                        t1 += e
                        t2 += g[s] * e
                    JTJ[b, p, q] += t1
                    JgJ[b, p, q] += t2
        for p in range(P):
            for q in range(p):
                JTJ[b, q, p] = JTJ[b, p, q]
                JgJ[b, q, p] = JgJ[b, p, q]


def _jit(fn: Callable) -> Callable:
    """``fn`` compiled lazily (on its first call), cached on disk where numba can."""
    options = {"parallel": True, "fastmath": False, "nogil": True}
    try:
        return numba.njit(cache=True, **options)(fn)
    except RuntimeError as err:  # no writable cache directory anywhere
        warnings.warn(f"numba cannot cache the MVP kernel ({err})", stacklevel=2)
        return numba.njit(**options)(fn)


_kernel = _jit(_evaluate)


def compile_seconds() -> float:
    """Seconds this process spent compiling the kernel or loading it from the cache: the first
    call (on a tiny problem) times it; later calls return that figure."""
    global _COMPILE_S
    if _COMPILE_S is None:
        rng = np.random.default_rng(0)
        images = [rng.random((8, 8, 3), dtype=np.float32) for _ in range(2)]
        H = np.tile(np.eye(3), (1, 2, 1, 1))
        H[..., :2, 2] = 3.0
        dH = np.zeros((1, 2, 3, 3, 3))
        t0 = time.perf_counter()
        fused_evaluate(
            images, np.zeros((2, 2), np.float32), np.zeros(2, np.float32), H, dH,
            np.ones((1, 2), bool), Window(1, 1.0), True,
        )  # fmt: skip
        _COMPILE_S = time.perf_counter() - t0
    return _COMPILE_S


@dataclass
class KernelResult:
    """What :func:`fused_evaluate` returns: ``cost`` (B,), ``used`` (B, K), ``JTJ``, ``JgJ``
    (B, P, P) and ``JTr`` (B, P) (zeros without derivatives), ``loo`` (B, K) (NaN without
    extras) as in :class:`orthomvp.mvp.patches.Evaluation`; ``box`` (B, K, 4) the bounding
    box (c_min, c_max, r_min, r_max) of each post's sampled positions in view k, whole-image
    pixels (inf / -inf where not sampled, NaN where a position was not finite)."""

    cost: np.ndarray
    used: np.ndarray
    JTJ: np.ndarray
    JTr: np.ndarray
    JgJ: np.ndarray
    loo: np.ndarray
    box: np.ndarray


def fused_evaluate(
    images: list[np.ndarray],
    origins: np.ndarray,
    flat: np.ndarray,
    H: np.ndarray,
    dH: np.ndarray | None,
    W: np.ndarray,
    window: Window,
    extras: bool,
) -> KernelResult:
    """The objective at B posts through K views, as :func:`orthomvp.mvp.patches.evaluate`
    (see there for ``flat``, ``H``, ``dH``, ``W`` and ``window``): ``images`` the K (rows,
    cols, 3) float32 stacks of value and gradients (or a numba typed List of them),
    ``origins`` (K, 2) float32 their first pixels in the whole images; ``dH`` gives the
    normal equations, ``extras`` the leave-one-out correlations (and ``JgJ``)."""
    B, K = W.shape
    jac = dH is not None
    if dH is None:
        dH = np.zeros((B, K, 3, 3, 3))
    P = dH.shape[2]
    if not hasattr(images, "_numba_type_"):
        images = List(images)
    out = KernelResult(
        cost=np.empty(B),
        used=np.empty((B, K), bool),
        JTJ=np.zeros((B, P, P)),
        JTr=np.zeros((B, P)),
        JgJ=np.zeros((B, P, P)),
        loo=np.empty((B, K)),
        box=np.empty((B, K, 4), np.float32),
    )
    _kernel(
        images,
        np.ascontiguousarray(origins, np.float32),
        np.ascontiguousarray(flat, np.float32),
        np.ascontiguousarray(H, np.float64),
        np.ascontiguousarray(dH, np.float64),
        np.ascontiguousarray(W, bool),
        window.offsets,
        window.weights,
        jac,
        extras,
        out.cost,
        out.used,
        out.JTJ,
        out.JTr,
        out.JgJ,
        out.loo,
        out.box,
    )
    return out
