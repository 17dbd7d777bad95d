"""The MVP plane fitter: refine every DEM post from the views in which it is visible.

Per post, a plane theta = (h, alpha, beta) (:mod:`orthomvp.mvp.model`) starts at the DEM's height
and its own surface normal n0 at the post; normals are reported as eq. 11 angles as well.
Levenberg-Marquardt (:mod:`orthomvp.mvp.lm`) on the Gauss-Newton normal equations of
:func:`patches.evaluate`, batched: a tile of posts iterates together, posts leave the batch as
they converge, and tiles run in a thread pool (the numba kernel releases the GIL). Coarse to
fine: at pyramid level L the images are reduced 2**L times and the patch grid steps 2**L posts,
so the window covers 2**L times the ground and the basin of convergence grows with it.

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

import os
from dataclasses import dataclass

import numpy as np

from orthomvp.camera import Camera
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.preflight import check_memory
from orthomvp.mvp.deconvolve import deconvolve
from orthomvp.mvp.lm import LMSettings, fit_planes
from orthomvp.mvp.model import PlaneModel
from orthomvp.mvp.patches import Evaluation, ViewStack
from orthomvp.mvp.plane import angles_from_normal
from orthomvp.mvp.problem import FitProblem
from orthomvp.mvp.views import ViewWindow
from orthomvp.mvp.window import Window
from orthomvp.occlusion.visibility import VISIBILITY_BYTES_PER_POST, run_tiles
from orthomvp.validate import number, of_type

TILE = 24  # posts per tile side: B = 576 posts per batch
MAX_DECONVOLVE = 10
"""Most Van Cittert steps: each step may amplify noise once more (up to steps + 1 times)."""
BYTES_PER_SAMPLE = 160
"""Peak memory of a batch per post, view and window sample (patches, their gradients and
normalisation; about 135 measured), bytes."""
_LM = LMSettings()


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
    The optimiser's other constants are :class:`~orthomvp.mvp.lm.LMSettings`' defaults.

    Checked when made (InputError naming the field and its range): ``hwin``, ``levels``
    integers >= 1; ``max_iter`` an integer >= 0 (0 evaluates the starting planes); ``sigma``
    None or > 0; ``htol``, ``ntol`` > 0; ``reject_below`` None or in [-1, 1] (a
    correlation); ``margin`` >= 0; ``deconvolve`` an integer from 0 to :data:`MAX_DECONVOLVE`.
    """

    hwin: int = 10
    sigma: float | None = None
    levels: int = 3
    max_iter: int = _LM.max_iter
    htol: float = _LM.htol
    ntol: float = _LM.ntol
    reject_below: float | None = 0.5
    margin: float = 1.0
    deconvolve: int = 1

    def __post_init__(self) -> None:
        def check(name: str, **limits: object) -> None:
            object.__setattr__(self, name, number(getattr(self, name), name, **limits))

        for name in ("hwin", "levels"):
            check(name, minimum=1, integer=True)
        check("max_iter", minimum=0, integer=True)  # 0: the planes where they start
        check("deconvolve", minimum=0, maximum=MAX_DECONVOLVE, integer=True)
        for name in ("htol", "ntol"):
            check(name, minimum=0, min_open=True)
        check("margin", minimum=0)
        if self.sigma is not None:
            check("sigma", minimum=0, min_open=True)
        if self.reject_below is not None:
            check("reject_below", minimum=-1, maximum=1)

    @property
    def window_sigma(self) -> float:
        return self.sigma if self.sigma is not None else self.hwin / 2.0

    @property
    def window(self) -> Window:
        """The objective's window: ``hwin`` and ``window_sigma`` (validated)."""
        return Window(self.hwin, self.window_sigma)

    @property
    def lm(self) -> LMSettings:
        """The optimiser's settings: ``max_iter``, ``htol`` and ``ntol`` from here."""
        return LMSettings(max_iter=self.max_iter, htol=self.htol, ntol=self.ntol)


@dataclass
class FitResult:
    """Per-post results on the DEM grid (rows, cols); NaN / 0 where unresolved.

    ``heights`` in the DEM's convention (surface heights; ``plane_heights`` are the fitted
    planes' heights at their posts before deconvolution); ``normals`` (rows, cols, 3) unit
    world vectors;
    ``n_theta``, ``n_phi`` eq. (11) angles, degrees; ``cost`` eq. (20) at the solution;
    ``views`` number of views used; ``converged``; ``sigma_h`` 1-sigma height uncertainty in
    the heights' units; ``initial`` the input values; ``resolved`` posts with >= 2 views.
    ``extents``: on windows of the images, the sampled positions per level and view (see
    :class:`~orthomvp.mvp.patches.ViewStack`), else None.
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
    extents: list[np.ndarray] | None = None

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
class BatchFit:
    """The results of a batch of B posts, NaN / 0 / False where unresolved (fewer than 2 views):
    ``heights`` (B,) the planes' heights at their posts in the DEM's convention, ``normals``
    (B, 3) unit world vectors, ``cost`` (B,) eq. (20), ``views`` (B,) the number of views used,
    ``converged`` (B,), ``sigma_h`` (B,) 1-sigma height uncertainty in the heights' units and
    ``view_mask`` (B, K) the views used."""

    heights: np.ndarray
    normals: np.ndarray
    cost: np.ndarray
    views: np.ndarray
    converged: np.ndarray
    sigma_h: np.ndarray
    view_mask: np.ndarray

    @classmethod
    def summarise(
        cls, model: PlaneModel, theta: np.ndarray, ev: Evaluation, conv: np.ndarray
    ) -> BatchFit:
        """From the final parameters ``theta`` (B, 3), the evaluation there (with the normal
        equations and ``JgJ``) and the converged flags of the optimiser."""
        n_used = ev.used.sum(axis=1)
        ok = (n_used >= 2) & np.isfinite(ev.cost)
        sigma_h = np.full(len(theta), np.nan)
        pd = ok & (np.linalg.eigvalsh(ev.JTJ)[:, 0] > 0)
        if pd.any():
            inv = np.linalg.inv(ev.JTJ[pd])
            cov = inv @ ev.JgJ[pd] @ inv
            s2 = ev.cost[pd] / np.maximum(n_used[pd] - 1, 1)
            sigma_h[pd] = np.sqrt(np.maximum(s2 * cov[:, 0, 0], 0.0))
        return cls(
            heights=np.where(ok, theta[:, 0], np.nan),
            normals=np.where(ok[:, None], model.normal(theta), np.nan),
            cost=np.where(ok, ev.cost, np.nan),
            views=np.where(ok, n_used, 0),
            converged=ok & conv & pd,
            sigma_h=sigma_h,
            view_mask=ev.used & ok[:, None],
        )


def _fit_batch(
    model: PlaneModel,
    stack: ViewStack,
    visible: np.ndarray,
    h0: np.ndarray,
    window: Window,
    opts: FitOptions,
) -> BatchFit:
    """Fit B posts from heights ``h0`` and view mask ``visible`` (B, K) coarse to fine on
    ``window``, rejecting outlier views."""
    B, K = visible.shape
    start = np.zeros((B, 3))
    start[:, 0] = h0
    W0 = visible & model.inside(start, 0, window.hwin, stack.sizes[0], opts.margin)
    lm = opts.lm

    def run(index: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return fit_planes(model.take(index), stack, start[index].copy(), W, window, lm, opts.margin)

    W = W0.copy()
    theta, conv = run(np.arange(B), W)
    todo = np.arange(B)
    if opts.reject_below is not None:
        for _ in range(K - 2):
            H, _ = model.take(todo).homographies(theta[todo], 0, derivatives=False)
            ev = stack.evaluate(0, H, W[todo], window)
            loo = np.where(ev.used, ev.loo, np.inf)
            worst = np.argmin(loo, axis=1)
            bad = (loo[np.arange(len(todo)), worst] < opts.reject_below) & (ev.used.sum(1) > 2)
            if not bad.any():
                break
            todo = todo[bad]
            W[todo, worst[bad]] = False
            theta[todo], conv[todo] = run(todo, W[todo])
    H, dH = model.homographies(theta, 0)
    ev = stack.evaluate(0, H, W, window, dH)
    return BatchFit.summarise(model, theta, ev, conv)


def fit_dem(
    terrain: Terrain,
    images: list[np.ndarray],
    cameras: list[Camera],
    options: FitOptions | None = None,
    visible: np.ndarray | None = None,
    eps: float | None = None,
    progress: bool = False,
    threads: int | None = None,
    *,
    windows: list[ViewWindow] | None = None,
    spacing: float | None = None,
    origin: tuple[int, int] = (0, 0),
    geometry: Terrain | None = None,
    strict: bool = True,
) -> FitResult:
    """Refine every post of ``terrain`` from ``images`` (at least 2; each (bands, rows, cols)
    or (rows, cols); band 1 is used) seen through ``cameras``.

    ``visible`` (K, rows, cols) bool overrides the visibility test (codes == 1 of
    :func:`orthomvp.occlusion.visibility.compute_visibility` with ``eps`` in DEM posts, on this
    DEM's mesh); see :class:`~orthomvp.mvp.problem.FitProblem`. ``threads``: tiles fitted at once
    (default: one per core); ``progress``: a progress bar over tiles.

    A window of a larger fit (what :mod:`orthomvp.engine.fit` runs per tile): ``terrain`` a
    window of the DEM at ``origin`` on the grid of ``geometry``, ``images`` windows of the
    images at ``windows``, ``visible`` given, ``spacing`` the whole DEM's and
    ``options.levels`` the levels of the whole images (see :meth:`FitProblem.build`);
    ``strict=False`` returns an unresolved result instead of raising GeometryError when no
    post is fitted.
    """
    opts = FitOptions() if options is None else of_type(options, FitOptions, "options")
    of_type(terrain, Terrain, "terrain")
    if not isinstance(images, (list, tuple)) or not isinstance(cameras, (list, tuple)):
        raise InputError(
            f"images and cameras must be lists, got {type(images).__name__} and "
            f"{type(cameras).__name__}"
        )
    if threads is not None:
        threads = number(threads, "threads", minimum=1, integer=True)
    check_fit_memory(terrain.shape, len(images), opts.hwin, threads or os.cpu_count() or 1)
    window = opts.window
    problem = FitProblem.build(
        terrain,
        images,
        cameras,
        levels=opts.levels,
        hwin=opts.hwin,
        eps=eps,
        visible=visible,
        min_views=2,
        windows=windows,
        spacing=spacing,
        origin=origin,
        geometry=geometry,
    )
    stack = problem.stack
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
        view_mask=np.zeros((len(problem.names), rows, cols), bool),
    )

    def work(tile: tuple[slice, slice]) -> None:
        rs, cs = tile
        r, c = np.mgrid[rs, cs]
        vis = np.moveaxis(problem.visible[:, rs, cs], 0, -1)
        take = problem.usable[rs, cs] & (vis.sum(axis=-1) >= 2)
        if not take.any():
            return
        rr, cc = r[take], c[take]
        model = problem.model(problem.lines(cc, rr), problem.normals[rr, cc])
        res = _fit_batch(model, stack, vis[take], terrain.values[rr, cc], window, opts)
        out.plane_heights[rr, cc] = res.heights
        out.normals[rr, cc] = res.normals
        out.cost[rr, cc] = res.cost
        out.views[rr, cc] = res.views
        out.converged[rr, cc] = res.converged
        out.sigma_h[rr, cc] = res.sigma_h
        out.view_mask[:, rr, cc] = res.view_mask.T

    run_tiles(work, terrain.shape, TILE, "fit", progress=progress, threads=threads)
    out.samples = stack.samples
    out.extents = stack.extents
    out.heights = deconvolve(out.plane_heights, window.hwin, window.sigma, opts.deconvolve)
    if strict and not out.resolved.any():
        seen = problem.usable & (problem.visible.sum(axis=0) >= 2)
        raise GeometryError(nothing_fitted(int(seen.sum()), window.hwin, problem.levels))
    return out


def nothing_fitted(seen: int, hwin: int, levels: int) -> str:
    """Why a fit resolved no post, from the count of posts ``seen`` (visible in 2 or more
    images), the window half-size ``hwin`` and the pyramid's ``levels``."""
    if not seen:
        return "no post is visible in 2 or more images: nothing to fit"
    side = 2 * hwin + 1
    step = 2 ** (levels - 1)
    steps = f", {step} posts a sample at the coarsest level" if step > 1 else ""
    return (
        f"{seen:,} posts are visible in 2 or more images, but at none of them do 2 images "
        f"hold the whole patch of {side} x {side} samples (hwin {hwin}{steps}): choose a "
        "smaller hwin" + (" or fewer levels" if step > 1 else "")
    )


def check_fit_memory(
    shape: tuple[int, int],
    views: int,
    hwin: int,
    threads: int | None = None,
    advice: str = "choose a smaller hwin",
) -> None:
    """InputError, before any work, when a fit of ``views`` views on a DEM of ``shape`` posts
    with window half-size ``hwin``, ``threads`` batches at once (default one per core),
    cannot fit in memory."""
    threads = threads or os.cpu_count() or 1
    side = 2 * hwin + 1
    batch = TILE * TILE * views * side * side * BYTES_PER_SAMPLE
    posts = float(shape[0]) * shape[1] * views * VISIBILITY_BYTES_PER_POST
    check_memory(
        f"hwin {hwin} makes patches of {side:,} x {side:,} samples, for {views} views and "
        f"{TILE * TILE} posts at a time on {threads} thread{'s' if threads > 1 else ''}",
        threads * batch + posts,
        advice,
    )
