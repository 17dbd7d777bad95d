"""The MVP objective as one fused numba kernel, parallel over posts.

Per post and view the kernel applies the homography to the patch offsets, samples the image, its c
and r gradients bilinearly (as ``cv2.remap`` does: BORDER_REPLICATE, exact weights), normalises the
patch (eq. 19), and accumulates the albedo, the cost (eq. 20) and the Gauss-Newton normal equations,
without the (B, K, P, S) temporaries of the numpy objective (:func:`orthomvp.mvp.patches.evaluate`,
which stays as its reference). Each post is reduced by one thread in a fixed order, so a post's
results do not depend on the batch it is in or on the number of threads. Per-sample positions and
derivatives are float32 as in the numpy objective; derivatives and sums over samples and views are
float64.

numba is imported here (and in :mod:`orthomvp.jit`) only, and this module only when the fitter first
evaluates; the first call compiles (a few seconds, see ``orthomvp bench``) into numba's cache
in the user's cache folder (:func:`orthomvp.jit.cache_dir`); without a writable one it compiles
in every process."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np
from numba.typed import List

from orthomvp.jit import cached_jit
from orthomvp.mvp.window import Window

__all__ = ["KernelResult", "compile_seconds", "fused_evaluate", "typed_images"]

_COMPILE_S: float | None = None


def _sample(
    img: np.ndarray,
    origin: np.ndarray,
    H: np.ndarray,
    dH: np.ndarray,
    xo: np.ndarray,
    yo: np.ndarray,
    jac: bool,
    U: np.ndarray,
    V: np.ndarray,
    IW: np.ndarray,
    It: np.ndarray,
    Gc: np.ndarray,
    Gr: np.ndarray,
    dIt: np.ndarray,
    box: np.ndarray,
    corner: np.ndarray,
    weight: np.ndarray,
    D: np.ndarray,
) -> None:
    """One view of one post, as the numpy objective: float32 positions ``U``, ``V`` and 1/w
    ``IW`` of the window's offsets through ``H`` (3, 3), their bounding ``box`` (4,), float32
    samples ``It`` of ``img`` (rows, cols, 3) (whose first pixel is ``origin`` (2,)) and,
    with ``jac``, gradients ``Gc``, ``Gr`` and float64 derivatives ``dIt`` (3, S) through
    ``dH`` (3, 3, 3). Scratch: ``corner`` (4, S) int64 flat indices of the four pixels
    around each position, ``weight`` (4, S) float32 their bilinear weights, ``D`` (3, 3, 3)
    float64. Compiled without fast-math, so that the roundings are the numpy objective's;
    the corners and weights are computed in a loop of their own, which vectorises, apart
    from the gathers."""
    one = np.float32(1.0)
    S = xo.shape[0]
    h22 = H[2, 2]
    h00, h01, h02 = np.float32(H[0, 0] / h22), np.float32(H[0, 1] / h22), np.float32(H[0, 2] / h22)
    h10, h11, h12 = np.float32(H[1, 0] / h22), np.float32(H[1, 1] / h22), np.float32(H[1, 2] / h22)
    h20, h21, h2 = np.float32(H[2, 0] / h22), np.float32(H[2, 1] / h22), np.float32(h22 / h22)
    for s in range(S):
        iw = one / (h20 * xo[s] + h21 * yo[s] + h2)
        IW[s] = iw
        U[s] = (h00 * xo[s] + h01 * yo[s] + h02) * iw
        V[s] = (h10 * xo[s] + h11 * yo[s] + h12) * iw
    finite = True
    for s in range(S):
        finite &= np.isfinite(U[s]) & np.isfinite(V[s])
    if finite:
        umin, umax, vmin, vmax = U[0], U[0], V[0], V[0]
        for s in range(S):
            u, v = U[s], V[s]
            umin = u if u < umin else umin
            umax = u if u > umax else umax
            vmin = v if v < vmin else vmin
            vmax = v if v > vmax else vmax
        box[0], box[1], box[2], box[3] = umin, umax, vmin, vmax
    else:
        box[:] = np.nan
    # bilinear, as cv2.remap with BORDER_REPLICATE (a position that is not finite
    # takes the first pixel)
    rows, cols = img.shape[0], img.shape[1]
    pixels = img.reshape(img.size)  # (r, c, channel) at 3 (r cols + c) + channel
    zero = np.float32(0.0)
    oc, orr = origin[0], origin[1]
    for s in range(S):
        uc = U[s] - oc
        vc = V[s] - orr
        ok = np.isfinite(uc) & np.isfinite(vc)
        uc = uc if ok else zero
        vc = vc if ok else zero
        fu = np.floor(uc)
        fv = np.floor(vc)
        fx = uc - fu
        fy = vc - fv
        ic = np.int64(min(max(fu, np.float32(-1.0)), np.float32(cols)))  # far outside: border
        ir = np.int64(min(max(fv, np.float32(-1.0)), np.float32(rows)))
        c0 = 3 * min(max(ic, 0), cols - 1)
        c1 = 3 * min(max(ic + 1, 0), cols - 1)
        r0 = 3 * cols * min(max(ir, 0), rows - 1)
        r1 = 3 * cols * min(max(ir + 1, 0), rows - 1)
        corner[0, s] = r0 + c0
        corner[1, s] = r0 + c1
        corner[2, s] = r1 + c0
        corner[3, s] = r1 + c1
        weight[0, s] = (one - fy) * (one - fx)
        weight[1, s] = (one - fy) * fx
        weight[2, s] = fy * (one - fx)
        weight[3, s] = fy * fx
    for s in range(S):  # unsigned indices: no wraparound of negative ones
        i00, i01 = np.uintp(corner[0, s]), np.uintp(corner[1, s])
        i10, i11 = np.uintp(corner[2, s]), np.uintp(corner[3, s])
        w00, w01, w10, w11 = weight[0, s], weight[1, s], weight[2, s], weight[3, s]
        It[s] = pixels[i00] * w00 + pixels[i01] * w01 + pixels[i10] * w10 + pixels[i11] * w11
        if jac:
            nxt = np.uintp(1)  # the next channel
            i00, i01, i10, i11 = i00 + nxt, i01 + nxt, i10 + nxt, i11 + nxt
            Gc[s] = pixels[i00] * w00 + pixels[i01] * w01 + pixels[i10] * w10 + pixels[i11] * w11
            i00, i01, i10, i11 = i00 + nxt, i01 + nxt, i10 + nxt, i11 + nxt
            Gr[s] = pixels[i00] * w00 + pixels[i01] * w01 + pixels[i10] * w10 + pixels[i11] * w11
    if jac:  # d(u, v) = (d(x, y) - (u, v) dw) / w with d(x, y, w) = dH (xo, yo, 1), float64
        for p in range(3):
            for i in range(3):
                for j in range(3):
                    D[p, i, j] = np.float32(dH[p, i, j] / h22)
        for s in range(S):
            x, y = np.float64(xo[s]), np.float64(yo[s])
            iw = np.float64(IW[s])
            a = Gc[s] * iw
            bb = Gr[s] * iw
            cc = -(a * U[s] + bb * V[s])
            for p in range(3):
                dIt[p, s] = (
                    a * (D[p, 0, 0] * x + D[p, 0, 1] * y + D[p, 0, 2])
                    + bb * (D[p, 1, 0] * x + D[p, 1, 1] * y + D[p, 1, 2])
                    + cc * (D[p, 2, 0] * x + D[p, 2, 1] * y + D[p, 2, 2])
                )


def _evaluate(
    images,  # noqa: ANN001 - numba typed List of (rows, cols, 3) float32 arrays
    origins: np.ndarray,
    flat: np.ndarray,
    H: np.ndarray,
    dH: np.ndarray,
    W: np.ndarray,
    xo: np.ndarray,
    yo: np.ndarray,
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
    """The numba kernel behind :func:`fused_evaluate` (its arguments, with the window's
    offsets as columns ``xo``, ``yo`` and P = 3 parameters; outputs filled in). Loops over
    samples are kept free of branches where they can be vectorised."""
    B, K = W.shape
    S = xo.shape[0]
    for b in numba.prange(B):
        # written before they are read, for the views used (no zeroing: 57 kB a post)
        Ik = np.empty((K, S))  # normalised patches
        dI = np.empty((K, 3, S))  # their derivatives
        U = np.empty(S, np.float32)  # positions and 1 / w
        V = np.empty(S, np.float32)
        IW = np.empty(S, np.float32)
        It = np.empty(S, np.float32)  # raw samples and gradients
        Gc = np.empty(S, np.float32)
        Gr = np.empty(S, np.float32)
        dIt = np.empty((3, S))  # raw samples' derivatives (with jac)
        corner = np.empty((4, S), np.int64)  # scratch of _sample
        weight = np.empty((4, S), np.float32)
        D = np.empty((3, 3, 3))
        A = np.zeros(S)
        dA = np.zeros((3, S))
        n = 0
        for k in range(K):
            used[b, k] = False
            loo[b, k] = np.nan
            box[b, k, 0] = box[b, k, 2] = np.inf
            box[b, k, 1] = box[b, k, 3] = -np.inf
            if not W[b, k]:
                continue
            _sample(
                images[k],
                origins[k],
                H[b, k],
                dH[b, k],
                xo,
                yo,
                jac,
                U,
                V,
                IW,
                It,
                Gc,
                Gr,
                dIt,
                box[b, k],
                corner,
                weight,
                D,
            )
            # eq. 19: I = (It - <1, It>) / sd with <x, y> = sum g x y, and through it
            # dI = (dIt - <1, dIt> - I <I, dIt>) / sd
            m = 0.0
            for s in range(S):
                m += g[s] * It[s]
            var = 0.0
            for s in range(S):
                c = It[s] - m
                var += g[s] * c * c
            sd = np.sqrt(max(var, 0.0))
            if not sd > flat[k]:
                continue
            used[b, k] = True
            n += 1
            isd = 1.0 / sd
            if not jac:
                for s in range(S):
                    i = (It[s] - m) * isd
                    Ik[k, s] = i
                    A[s] += i
                continue
            dm0 = dm1 = dm2 = ds0 = ds1 = ds2 = 0.0
            for s in range(S):
                i = (It[s] - m) * isd
                Ik[k, s] = i
                A[s] += i
                gs = g[s]
                gi = gs * i
                dm0 += gs * dIt[0, s]
                dm1 += gs * dIt[1, s]
                dm2 += gs * dIt[2, s]
                ds0 += gi * dIt[0, s]
                ds1 += gi * dIt[1, s]
                ds2 += gi * dIt[2, s]
            for s in range(S):
                i = Ik[k, s]
                d0 = (dIt[0, s] - dm0 - i * ds0) * isd
                d1 = (dIt[1, s] - dm1 - i * ds1) * isd
                d2 = (dIt[2, s] - dm2 - i * ds2) * isd
                dI[k, 0, s] = d0
                dI[k, 1, s] = d1
                dI[k, 2, s] = d2
                dA[0, s] += d0
                dA[1, s] += d1
                dA[2, s] += d2
        nn = max(n, 1)
        inn = 1.0 / nn
        for s in range(S):
            A[s] *= inn
        for p in range(3):
            for s in range(S):
                dA[p, s] *= inn
        # residuals R_k = sqrt(g) (A - I_k) and their derivatives dA - dI_k, used views only
        f = 0.0
        r0_ = r1_ = r2_ = 0.0
        j00 = j10 = j11 = j20 = j21 = j22 = 0.0
        q00 = q10 = q11 = q20 = q21 = q22 = 0.0
        for k in range(K):
            if not used[b, k]:
                continue
            for s in range(S):
                r = A[s] - Ik[k, s]
                f += g[s] * r * r
            if not jac:
                continue
            for s in range(S):
                gs = g[s]
                gr_ = gs * (A[s] - Ik[k, s])
                e0 = dA[0, s] - dI[k, 0, s]
                e1 = dA[1, s] - dI[k, 1, s]
                e2 = dA[2, s] - dI[k, 2, s]
                r0_ += gr_ * e0
                r1_ += gr_ * e1
                r2_ += gr_ * e2
                g0, g1, g2 = gs * e0, gs * e1, gs * e2
                j00 += g0 * e0
                j10 += g1 * e0
                j11 += g1 * e1
                j20 += g2 * e0
                j21 += g2 * e1
                j22 += g2 * e2
            if not extras:
                continue
            for s in range(S):
                gs = g[s] * g[s]
                e0 = dA[0, s] - dI[k, 0, s]
                e1 = dA[1, s] - dI[k, 1, s]
                e2 = dA[2, s] - dI[k, 2, s]
                q00 += gs * e0 * e0
                q10 += gs * e1 * e0
                q11 += gs * e1 * e1
                q20 += gs * e2 * e0
                q21 += gs * e2 * e1
                q22 += gs * e2 * e2
        cost[b] = f if n >= 2 else np.inf
        JTr[b, 0], JTr[b, 1], JTr[b, 2] = r0_, r1_, r2_
        JTJ[b, 0, 0], JTJ[b, 1, 1], JTJ[b, 2, 2] = j00, j11, j22
        JTJ[b, 1, 0] = JTJ[b, 0, 1] = j10
        JTJ[b, 2, 0] = JTJ[b, 0, 2] = j20
        JTJ[b, 2, 1] = JTJ[b, 1, 2] = j21
        JgJ[b, 0, 0], JgJ[b, 1, 1], JgJ[b, 2, 2] = q00, q11, q22
        JgJ[b, 1, 0] = JgJ[b, 0, 1] = q10
        JgJ[b, 2, 0] = JgJ[b, 0, 2] = q20
        JgJ[b, 2, 1] = JgJ[b, 1, 2] = q21
        if extras and n >= 2:  # each view against the mean of the others (leave-one-out)
            for k in range(K):
                if used[b, k]:
                    num = 0.0
                    den = 0.0
                    for s in range(S):
                        al = (nn * A[s] - Ik[k, s]) / (nn - 1.0)
                        num += g[s] * Ik[k, s] * al
                        den += g[s] * al * al
                    loo[b, k] = num / np.sqrt(max(den, 1e-30))


# numpy's error model: a division by zero gives inf or NaN (as in the numpy objective), not
# an exception, and divisions need no test
_sample = cached_jit(_sample, fastmath=False, error_model="numpy")
_kernel = cached_jit(
    _evaluate, parallel=True, fastmath={"reassoc", "contract"}, error_model="numpy"
)


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


def _typed_list(arrays: tuple) -> List:
    """The arrays of a tuple of same-typed arrays as a numba typed List."""
    out = List()
    for a in arrays:
        out.append(a)
    return out


_typed_list = cached_jit(_typed_list)


def typed_images(images: list[np.ndarray]) -> List:
    """``images`` as the numba typed List of C-order float32 arrays that :func:`_kernel`
    takes, built by a compiled function cached on disk: numba's own ``List(images)`` compiles
    the list's methods again in every process (0.25-0.6 s of the README's fit)."""
    arrays = tuple(np.ascontiguousarray(img, np.float32) for img in images)
    return _typed_list(arrays) if arrays else List(arrays)


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
    if dH.shape[2:] != (3, 3, 3):
        raise ValueError(f"the kernel fits 3 plane parameters, dH is {dH.shape}")
    P = 3
    if not hasattr(images, "_numba_type_"):  # C order: _sample indexes them flat
        images = typed_images(images)
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
        np.ascontiguousarray(window.offsets[:, 0]),
        np.ascontiguousarray(window.offsets[:, 1]),
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
