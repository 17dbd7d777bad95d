"""The MVP plane fitter: refine every DEM post from the views in which it is visible.

Per post, the parameters are theta = (h, alpha, beta): the height in the DEM's convention and a
tilt of the normal, n = n0 + alpha t1 + beta t2, with n0 the DEM's own surface normal at the post
and (t1, t2) orthonormal tangents (this stays well conditioned at the poles and in the map
frame, where eq. 11's angles are singular; results are reported as eq. 11 angles as well).

Levenberg-Marquardt on the Gauss-Newton normal equations of :func:`patches.evaluate`, batched:
a tile of posts iterates together, posts leave the batch as they converge, and tiles run in a
thread pool (numpy and OpenCV release the GIL). Coarse to fine: at pyramid level L the images
are reduced 2**L times and the patch grid steps 2**L posts, so the window covers 2**L times the
ground and the basin of convergence grows with it.

Only views whose visibility code at the post is 1 take part, and only if the patch lies inside
the image; posts with fewer than 2 views are left unresolved (NaN). After convergence, a view
whose normalised patch correlates with the mean of the other views (leave-one-out albedo) below
``reject_below`` is dropped, worst first, and the post is fitted again without it, from the
start, as long as 2 views remain.

Height uncertainty: with per-sample noise variance s^2 = f / (n - 1) (the expectation of f at the
true plane for n views with independent noise), the sandwich covariance of a windowed least
squares fit, s^2 (J^T G J)^-1 (J^T G^2 J) (J^T G J)^-1, whose (h, h) element is reported as the
1-sigma height uncertainty (J^T G J is half the Hessian of f, its local curvature).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from orthomvp.camera import PinholeCamera, check_image
from orthomvp.codes import Code
from orthomvp.errors import GeometryError, InputError
from orthomvp.mesh import terrain_mesh
from orthomvp.mvp.deconvolve import deconvolve
from orthomvp.mvp.patches import Evaluation, ViewStack, gaussian_window
from orthomvp.mvp.plane import PostLines, angles_from_normal, plane_map, post_lines, tangent_basis
from orthomvp.raycast import RayCaster
from orthomvp.terrain import Terrain
from orthomvp.visibility import compute_visibility, run_tiles

TILE = 24  # posts per tile side: B = 576 posts per batch
PREDICTED_TOL = 1e-4  # converged when a step would lower f by less than this fraction


@dataclass(frozen=True)
class FitOptions:
    """Settings of the fitter.

    ``hwin``: window half-size in posts (samples); ``sigma``: Gaussian window sigma in posts
    (default hwin / 2); ``levels``: pyramid levels (1 = no coarse-to-fine); ``max_iter``: LM
    iterations per level; ``htol``: convergence step in heights, in post spacings;
    ``ntol``: convergence step of the normal, radians; ``reject_below``: leave-one-out
    correlation under which a view is dropped (None: keep every view); ``margin``: pixels a
    patch must keep from the image border; ``deconvolve``: Van Cittert steps from plane
    heights to surface heights (:mod:`orthomvp.mvp.deconvolve`; 0 reports plane heights).
    """

    hwin: int = 10
    sigma: float | None = None
    levels: int = 3
    max_iter: int = 30
    htol: float = 5e-3
    ntol: float = 1e-4
    reject_below: float | None = 0.5
    margin: float = 1.0
    deconvolve: int = 1

    @property
    def window_sigma(self) -> float:
        return self.sigma if self.sigma is not None else self.hwin / 2.0


@dataclass
class FitResult:
    """Per-post results on the DEM grid (rows, cols); NaN / 0 where unresolved.

    ``heights`` in the DEM's convention (surface heights; ``plane_heights`` are the fitted
    planes' heights at their posts before deconvolution); ``normals`` (rows, cols, 3) unit
    world vectors;
    ``n_theta``, ``n_phi`` eq. (11) angles, degrees; ``cost`` eq. (20) at the solution;
    ``views`` number of views used; ``converged``; ``sigma_h`` 1-sigma height uncertainty in
    the heights' units; ``initial`` the input values; ``resolved`` posts with >= 2 views.
    """

    heights: np.ndarray
    plane_heights: np.ndarray
    normals: np.ndarray
    cost: np.ndarray
    views: np.ndarray
    converged: np.ndarray
    sigma_h: np.ndarray
    initial: np.ndarray
    view_mask: np.ndarray
    samples: int = 0

    @property
    def resolved(self) -> np.ndarray:
        return np.isfinite(self.heights)

    @property
    def n_theta(self) -> np.ndarray:
        return np.degrees(angles_from_normal(self.normals)[0])

    @property
    def n_phi(self) -> np.ndarray:
        return np.degrees(angles_from_normal(self.normals)[1])


@dataclass
class PlaneModel:
    """The homographies of a batch of posts and their parameter derivatives: height lines,
    starting normals ``n0`` (B, 3) with tangents ``t1``, ``t2`` (from ``n0`` unless given),
    projection matrices ``F`` (K, 3, 4) and the post spacing in metres."""

    lines: PostLines
    n0: np.ndarray
    F: np.ndarray
    spacing: float
    t1: np.ndarray | None = None
    t2: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.t1 is None or self.t2 is None:
            self.t1, self.t2 = tangent_basis(self.n0)

    def take(self, index: np.ndarray) -> PlaneModel:
        """The model of a subset of the posts."""
        return PlaneModel(
            self.lines.take(index),
            self.n0[index],
            self.F,
            self.spacing,
            self.t1[index],
            self.t2[index],
        )

    def normal(self, theta: np.ndarray) -> np.ndarray:
        n = self.n0 + theta[:, 1:2] * self.t1 + theta[:, 2:3] * self.t2
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def _outer(self, level: int) -> tuple[np.ndarray, np.ndarray]:
        """Left factor T F (K, 3, 4) (level-0 pixels to level pixels) and right factor Z (B,3,3)
        (patch offsets in steps to grid pixels)."""
        s = 2.0**level
        T = np.diag([1 / s, 1 / s, 1.0])
        Z = np.zeros((len(self.lines.c), 3, 3))
        Z[:, 0, 0] = Z[:, 1, 1] = s
        Z[:, 0, 2], Z[:, 1, 2], Z[:, 2, 2] = self.lines.c, self.lines.r, 1.0
        return T @ self.F, Z

    def homographies(
        self, theta: np.ndarray, level: int, derivatives: bool = True
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """H (B, K, 3, 3) from patch offsets to level pixels, and dH (B, K, 3, 3, 3)."""
        TF, Z = self._outer(level)
        n = self.n0 + theta[:, 1:2] * self.t1 + theta[:, 2:3] * self.t2
        G = plane_map(self.lines, theta[:, 0], n) @ Z
        H = np.einsum("kij,bjl->bkil", TF, G)
        if not derivatives:
            return H, None
        dG = (
            np.stack(
                [
                    plane_map(self.lines, np.ones(len(n)), n)
                    - plane_map(self.lines, np.zeros(len(n)), n),
                    plane_map(self.lines, theta[:, 0], self.t1),
                    plane_map(self.lines, theta[:, 0], self.t2),
                ],
                axis=1,
            )
            @ Z[:, None]
        )
        dH = np.einsum("kij,bpjl->bkpil", TF, dG)
        return H, dH

    def inside(
        self, theta: np.ndarray, level: int, hwin: int, sizes: list[tuple[int, int]], margin: float
    ) -> np.ndarray:
        """(B, K): the patch's corners land inside view k's level image, in front of it."""
        H, _ = self.homographies(theta, level, derivatives=False)
        corners = np.array([[-hwin, -hwin, 1], [hwin, -hwin, 1], [-hwin, hwin, 1], [hwin, hwin, 1]])
        p = np.einsum("bkij,sj->bksi", H, corners.astype(float))
        w = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = p[..., 0] / w, p[..., 1] / w
        size = np.array(sizes, float)
        m = margin / 2.0**level
        ok = (
            (w > 0)
            & (u >= m)
            & (v >= m)
            & (u <= size[None, :, None, 0] - 1 - m)
            & (v <= size[None, :, None, 1] - 1 - m)
        )
        return ok.all(axis=-1)


@dataclass
class Iterate:
    """One Levenberg-Marquardt iteration of a batch: pyramid ``level``, the batch rows
    ``index`` still iterating, the ``trial`` parameters (n, 3) tried and their ``cost``,
    whether each was ``accepted``, and the damping ``lam`` used."""

    level: int
    index: np.ndarray
    trial: np.ndarray
    cost: np.ndarray
    accepted: np.ndarray
    lam: np.ndarray


def _levenberg_marquardt(
    model: PlaneModel,
    stack: ViewStack,
    level: int,
    theta: np.ndarray,
    W: np.ndarray,
    offsets: np.ndarray,
    g: np.ndarray,
    opts: FitOptions,
    trace: list[Iterate] | None = None,
) -> tuple[np.ndarray, Evaluation, np.ndarray]:
    """Minimise f per post from ``theta`` (B, 3) with view mask ``W``. Returns theta, the
    evaluation (with normal equations) at it, and a converged flag (B,). ``trace`` collects
    every iteration (accepted or not)."""
    B = len(theta)
    H, dH = model.homographies(theta, level)
    ev = stack.evaluate(level, H, W, offsets, g, dH, extras=False)
    lam = np.full(B, 1e-3)
    converged = np.zeros(B, bool)
    active = np.isfinite(ev.cost)
    step_h = opts.htol * model.spacing
    max_dh = 2.0 * model.spacing * 2.0**level
    for _ in range(opts.max_iter):
        idx = np.nonzero(active)[0]
        if len(idx) == 0:
            break
        JTJ, JTr = ev.JTJ[idx], ev.JTr[idx]
        diag = np.einsum("bii->bi", JTJ)
        floor = np.maximum(1e-12 * diag.max(axis=1, keepdims=True), 1e-30)
        A = JTJ + (lam[idx, None] * diag + floor)[..., None] * np.eye(3)
        delta = -np.linalg.solve(A, JTr[..., None])[..., 0]
        big = np.maximum(np.abs(delta[:, 0]) / max_dh, np.abs(delta[:, 1:]).max(axis=1) / 0.2)
        delta /= np.maximum(big, 1.0)[:, None]
        trial = theta[idx] + delta
        # decrease of f that the Gauss-Newton model predicts for this step (f ~ |r|^2)
        predicted = -2 * np.einsum("bi,bi->b", JTr, delta) - np.einsum(
            "bi,bij,bj->b", delta, JTJ, delta
        )
        sub = model.take(idx)
        Ht, dHt = sub.homographies(trial, level)
        evt = stack.evaluate(level, Ht, W[idx], offsets, g, dHt, extras=False)
        before = ev.cost[idx]
        better = evt.cost <= before * (1 + 1e-7)
        stalled = predicted <= PREDICTED_TOL * np.maximum(before, 1e-3)
        acc = idx[better]
        theta[acc] = trial[better]
        for name in ("cost", "used", "JTJ", "JTr"):
            getattr(ev, name)[acc] = getattr(evt, name)[better]
        if trace is not None:
            trace.append(Iterate(level, idx, trial, evt.cost, better, lam[idx].copy()))
        lam[acc] *= 0.3
        lam[idx[~better]] *= 5.0
        small = (np.abs(delta[:, 0]) < step_h) & (np.abs(delta[:, 1:]).max(axis=1) < opts.ntol)
        done = (better & small) | stalled
        converged[idx[done]] = True
        active[idx[done]] = False
        active[idx[lam[idx] > 1e7]] = False
    return theta, ev, converged


def fit_planes(
    model: PlaneModel,
    stack: ViewStack,
    theta: np.ndarray,
    W: np.ndarray,
    offsets: np.ndarray,
    g: np.ndarray,
    opts: FitOptions,
    trace: list[Iterate] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Coarse to fine from ``theta`` (B, 3) over ``opts.levels`` pyramid levels with view mask
    ``W`` (B, K); at coarse levels only posts whose patch stays inside 2 or more views take
    part. Returns theta and the converged flag of the finest level; ``trace`` collects every
    iteration."""
    conv = np.zeros(len(theta), bool)
    for level in range(opts.levels - 1, -1, -1):
        Wl = W & model.inside(theta, level, opts.hwin, stack.sizes[level], opts.margin)
        ok = Wl.sum(axis=1) >= 2
        if level and not ok.any():
            continue
        sel = np.nonzero(ok)[0] if level else np.arange(len(theta))
        th, _, conv = _levenberg_marquardt(
            model.take(sel),
            stack,
            level,
            theta[sel].copy(),
            Wl[sel] if level else W[sel],
            offsets,
            g,
            opts,
            trace,
        )
        theta[sel] = th
    return theta, conv


def _fit_batch(
    model: PlaneModel,
    stack: ViewStack,
    visible: np.ndarray,
    h0: np.ndarray,
    opts: FitOptions,
) -> dict[str, np.ndarray]:
    """Fit B posts from heights ``h0`` and view mask ``visible`` (B, K) coarse to fine,
    rejecting outlier views. Returns per-post arrays."""
    offsets, g = gaussian_window(opts.hwin, opts.window_sigma)
    B, K = visible.shape
    start = np.zeros((B, 3))
    start[:, 0] = h0
    W0 = visible & model.inside(start, 0, opts.hwin, stack.sizes[0], opts.margin)

    def run(index: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return fit_planes(model.take(index), stack, start[index].copy(), W, offsets, g, opts)

    W = W0.copy()
    theta, conv = run(np.arange(B), W)
    todo = np.arange(B)
    if opts.reject_below is not None:
        for _ in range(K - 2):
            H, _ = model.take(todo).homographies(theta[todo], 0, derivatives=False)
            ev = stack.evaluate(0, H, W[todo], offsets, g)
            loo = np.where(ev.used, ev.loo, np.inf)
            worst = np.argmin(loo, axis=1)
            bad = (loo[np.arange(len(todo)), worst] < opts.reject_below) & (ev.used.sum(1) > 2)
            if not bad.any():
                break
            todo = todo[bad]
            W[todo, worst[bad]] = False
            theta[todo], conv[todo] = run(todo, W[todo])
    H, dH = model.homographies(theta, 0)
    ev = stack.evaluate(0, H, W, offsets, g, dH)
    return _summarise(model, theta, ev, conv)


def _summarise(
    model: PlaneModel, theta: np.ndarray, ev: Evaluation, conv: np.ndarray
) -> dict[str, np.ndarray]:
    """Per-post outputs from the final parameters and the evaluation there."""
    n_used = ev.used.sum(axis=1)
    ok = (n_used >= 2) & np.isfinite(ev.cost)
    sigma_h = np.full(len(theta), np.nan)
    pd = ok & (np.linalg.eigvalsh(ev.JTJ)[:, 0] > 0)
    if pd.any():
        inv = np.linalg.inv(ev.JTJ[pd])
        cov = inv @ ev.JgJ[pd] @ inv
        s2 = ev.cost[pd] / np.maximum(n_used[pd] - 1, 1)
        sigma_h[pd] = np.sqrt(np.maximum(s2 * cov[:, 0, 0], 0.0))
    return {
        "heights": np.where(ok, theta[:, 0], np.nan),
        "normals": np.where(ok[:, None], model.normal(theta), np.nan),
        "cost": np.where(ok, ev.cost, np.nan),
        "views": np.where(ok, n_used, 0),
        "converged": ok & conv & pd,
        "sigma_h": sigma_h,
        "view_mask": ev.used & ok[:, None],
    }


def pyramid_levels(images: list[np.ndarray], wanted: int) -> int:
    """At most ``wanted`` levels, and none whose images would be under 16 pixels across."""
    smallest = min(min(img.shape[-2:]) for img in images)
    return max(1, min(wanted, int(np.floor(np.log2(max(smallest / 16, 1)))) + 1))


def first_bands(
    images: list[np.ndarray], cameras: list[PinholeCamera], names: list[str] | None = None
) -> tuple[list[np.ndarray], list[PinholeCamera]]:
    """Band 1 of each image ((bands, rows, cols) or (rows, cols)) as float32, and each camera
    checked against its image and given its size; ``names`` label errors."""
    bands, cams = [], []
    for k, (image, camera) in enumerate(zip(images, cameras, strict=True)):
        img = np.asarray(image)
        img = img[None] if img.ndim == 2 else img
        cams.append(check_image(img, camera, names[k] if names else f"image {k + 1}"))
        bands.append(img[0].astype(np.float32))
    return bands, cams


def fit_dem(
    terrain: Terrain,
    images: list[np.ndarray],
    cameras: list[PinholeCamera],
    options: FitOptions | None = None,
    visible: np.ndarray | None = None,
    eps: float | None = None,
    progress: bool = False,
    threads: int | None = None,
) -> FitResult:
    """Refine every post of ``terrain`` from ``images`` (each (bands, rows, cols) or
    (rows, cols); band 1 is used) seen through ``cameras``.

    ``visible`` (K, rows, cols) bool overrides the visibility test (codes == 1 of
    :func:`orthomvp.visibility.compute_visibility` with ``eps``, on this DEM's mesh).
    """
    opts = options or FitOptions()
    if len(images) != len(cameras) or len(images) < 2:
        raise InputError(f"the fit needs at least 2 images with cameras, got {len(images)}")
    bands, cams = first_bands(images, cameras)
    if visible is None:
        caster = RayCaster(terrain_mesh(terrain))
        visible = np.stack(
            [
                compute_visibility(terrain, cam, eps=eps, caster=caster).codes == Code.VISIBLE
                for cam in cams
            ]
        )
    visible = np.asarray(visible, bool)
    if visible.shape != (len(cams), *terrain.shape):
        raise InputError(f"visibility masks must be (K, rows, cols), got {visible.shape}")
    stack = ViewStack.build(bands, cams, pyramid_levels(bands, opts.levels))
    if len(stack.levels) < opts.levels:
        opts = replace(opts, levels=len(stack.levels))
    normals = terrain.normals()
    ok_post = terrain.valid & np.isfinite(normals).all(axis=-1)
    spacing = float(np.mean(terrain.post_spacing()))
    rows, cols = terrain.shape
    out = FitResult(
        heights=np.full((rows, cols), np.nan),
        plane_heights=np.full((rows, cols), np.nan),
        normals=np.full((rows, cols, 3), np.nan),
        cost=np.full((rows, cols), np.nan),
        views=np.zeros((rows, cols), np.uint8),
        converged=np.zeros((rows, cols), bool),
        sigma_h=np.full((rows, cols), np.nan),
        initial=terrain.values.copy(),
        view_mask=np.zeros((len(cams), rows, cols), bool),
    )

    def work(tile: tuple[slice, slice]) -> None:
        rs, cs = tile
        r, c = np.mgrid[rs, cs]
        vis = np.moveaxis(visible[:, rs, cs], 0, -1)
        take = ok_post[rs, cs] & (vis.sum(axis=-1) >= 2)
        if not take.any():
            return
        rr, cc = r[take], c[take]
        h0 = terrain.values[rr, cc]
        lines = post_lines(terrain, cc.astype(float), rr.astype(float), h0)
        model = PlaneModel(lines, normals[rr, cc], stack.F, spacing)
        res = _fit_batch(model, stack, vis[take], h0, opts)
        out.plane_heights[rr, cc] = res["heights"]
        out.normals[rr, cc] = res["normals"]
        out.cost[rr, cc] = res["cost"]
        out.views[rr, cc] = res["views"]
        out.converged[rr, cc] = res["converged"]
        out.sigma_h[rr, cc] = res["sigma_h"]
        out.view_mask[:, rr, cc] = res["view_mask"].T

    run_tiles(work, terrain.shape, TILE, "fit", progress, threads)
    out.samples = stack.samples
    out.heights = deconvolve(out.plane_heights, opts.hwin, opts.window_sigma, opts.deconvolve)
    if not out.resolved.any():
        raise GeometryError("no post is visible in 2 or more images: nothing to fit")
    return out
