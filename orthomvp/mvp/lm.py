"""Levenberg-Marquardt on the MVP objective, batched over posts, and its coarse-to-fine driver.

Each post's parameters theta = (h, alpha, beta) (:mod:`orthomvp.mvp.model`) take steps delta
solving (J^T J + lam diag(J^T J)) delta = -J^T r, the damped Gauss-Newton normal equations of
the residuals whose squares sum to f (:func:`orthomvp.mvp.patches.evaluate`). A tile of posts
iterates together and posts leave the batch as they converge or give up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.mvp.model import PlaneModel
from orthomvp.mvp.patches import Evaluation, ViewStack
from orthomvp.mvp.window import Window


@dataclass(frozen=True)
class LMSettings:
    """The constants of :func:`levenberg_marquardt`.

    Iterations: at most ``max_iter`` per pyramid level. Damping: every post starts at lam =
    ``damping``; an accepted step multiplies its lam by ``down``, a rejected one by ``up``, and
    a post whose lam exceeds ``max_damping`` stops unconverged (no step lowers f).
    ``diag_floor``: added to the damped diagonal, relative to its largest element, so that a
    direction f does not see stays solvable. Step limits: ``max_step_h`` post spacings per patch
    step (2**L posts at level L) in height and ``max_step_tilt`` in each tilt parameter
    (dimensionless, about radians); a longer step is shortened as a whole. Acceptance: a step
    is taken unless f rises by more than ``accept_rise`` (relative; float32 rounding of f).
    Convergence: an accepted step moved the height by less than ``htol`` post spacings and each
    tilt parameter by less than ``ntol``, or the decrease of f that the Gauss-Newton model
    predicts for the step is at most ``predicted_tol`` times f (f taken as at least
    ``cost_floor``).
    """

    max_iter: int = 30
    htol: float = 5e-3
    ntol: float = 1e-4
    damping: float = 1e-3
    down: float = 0.3
    up: float = 5.0
    max_damping: float = 1e7
    diag_floor: float = 1e-12
    max_step_h: float = 2.0
    max_step_tilt: float = 0.2
    accept_rise: float = 1e-7
    predicted_tol: float = 1e-4
    cost_floor: float = 1e-3


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


def levenberg_marquardt(
    model: PlaneModel,
    stack: ViewStack,
    level: int,
    theta: np.ndarray,
    W: np.ndarray,
    window: Window,
    lm: LMSettings,
    trace: list[Iterate] | None = None,
) -> tuple[np.ndarray, Evaluation, np.ndarray]:
    """Minimise f per post at pyramid ``level`` from ``theta`` (B, 3) with view mask ``W``
    (B, K). Returns theta, the evaluation (with normal equations) at it, and a converged flag
    (B,). ``trace`` collects every iteration (accepted or not)."""
    B = len(theta)
    H, dH = model.homographies(theta, level)
    ev = stack.evaluate(level, H, W, window, dH, extras=False)
    lam = np.full(B, lm.damping)
    converged = np.zeros(B, bool)
    active = np.isfinite(ev.cost)
    step_h = lm.htol * model.spacing
    max_dh = lm.max_step_h * model.spacing * 2.0**level
    for _ in range(lm.max_iter):
        idx = np.nonzero(active)[0]
        if len(idx) == 0:
            break
        JTJ, JTr = ev.JTJ[idx], ev.JTr[idx]
        diag = np.einsum("bii->bi", JTJ)
        floor = np.maximum(lm.diag_floor * diag.max(axis=1, keepdims=True), 1e-30)  # never 0
        A = JTJ + (lam[idx, None] * diag + floor)[..., None] * np.eye(3)
        delta = -np.linalg.solve(A, JTr[..., None])[..., 0]
        big = np.maximum(
            np.abs(delta[:, 0]) / max_dh, np.abs(delta[:, 1:]).max(axis=1) / lm.max_step_tilt
        )
        delta /= np.maximum(big, 1.0)[:, None]
        trial = theta[idx] + delta
        # decrease of f that the Gauss-Newton model predicts for this step (f ~ |r|^2)
        predicted = -2 * np.einsum("bi,bi->b", JTr, delta) - np.einsum(
            "bi,bij,bj->b", delta, JTJ, delta
        )
        sub = model.take(idx)
        Ht, dHt = sub.homographies(trial, level)
        evt = stack.evaluate(level, Ht, W[idx], window, dHt, extras=False)
        before = ev.cost[idx]
        better = evt.cost <= before * (1 + lm.accept_rise)
        stalled = predicted <= lm.predicted_tol * np.maximum(before, lm.cost_floor)
        acc = idx[better]
        theta[acc] = trial[better]
        for name in ("cost", "used", "JTJ", "JTr"):
            getattr(ev, name)[acc] = getattr(evt, name)[better]
        if trace is not None:
            trace.append(Iterate(level, idx, trial, evt.cost, better, lam[idx].copy()))
        lam[acc] *= lm.down
        lam[idx[~better]] *= lm.up
        small = (np.abs(delta[:, 0]) < step_h) & (np.abs(delta[:, 1:]).max(axis=1) < lm.ntol)
        done = (better & small) | stalled
        converged[idx[done]] = True
        active[idx[done]] = False
        active[idx[lam[idx] > lm.max_damping]] = False
    return theta, ev, converged


def fit_planes(
    model: PlaneModel,
    stack: ViewStack,
    theta: np.ndarray,
    W: np.ndarray,
    window: Window,
    lm: LMSettings,
    margin: float,
    trace: list[Iterate] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Coarse to fine from ``theta`` (B, 3) over every pyramid level of ``stack`` with view
    mask ``W`` (B, K); at coarse levels only posts whose patch stays inside 2 or more views
    (``margin`` level-0 pixels from the border) take part. Returns theta and the converged flag
    of the finest level; ``trace`` collects every iteration."""
    conv = np.zeros(len(theta), bool)
    for level in range(len(stack.levels) - 1, -1, -1):
        Wl = W & model.inside(theta, level, window.hwin, stack.sizes[level], margin)
        ok = Wl.sum(axis=1) >= 2
        if level and not ok.any():
            continue
        sel = np.nonzero(ok)[0] if level else np.arange(len(theta))
        th, _, conv = levenberg_marquardt(
            model.take(sel),
            stack,
            level,
            theta[sel].copy(),
            Wl[sel] if level else W[sel],
            window,
            lm,
            trace,
        )
        theta[sel] = th
    return theta, conv
