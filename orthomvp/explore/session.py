"""The state and computations of the objective explorer: one DEM post, one plane, K views.

The current plane at the point of interest (a DEM post) is ``theta = (h, a, b)``: ``h`` the
height in the DEM's convention (metres above the reference surface, or radius with radius
values) and the normal ``n ~ up + a east + b north`` in the post's local frame, so that
``atan(a)`` and ``atan(b)`` are the normal's tilts towards east and north (degrees in the
interface). ``up`` is the DEM's own height direction at the post; east is ``z x up`` in the body
frame (+x in the map frame), north completes the frame. Normals are also reported as eq. (11)
angles (n_theta, n_phi). The objective is eq. (20) at pyramid level 0, over the views in which
the post is visible (visibility code 1) and whose patch lies inside the image at the plane.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import find_peaks

from orthomvp.camera import PinholeCamera
from orthomvp.codes import Code, WorldFrame
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.mvp.fit import FitOptions
from orthomvp.mvp.lm import Iterate, fit_planes
from orthomvp.mvp.patches import Evaluation
from orthomvp.mvp.plane import angles_from_normal, normal_from_angles
from orthomvp.mvp.problem import FitProblem
from orthomvp.mvp.window import Window
from orthomvp.occlusion.visibility import Visibility

PROMINENCE = 0.02  # a local minimum counts when this fraction of the curve's range deep
DEFAULTS = FitOptions()  # the explorer's window, margin and optimiser settings start as the fit's


class ExploreError(InputError):
    """A command that cannot be carried out (bad arguments, a post without enough views)."""


@dataclass
class Curve:
    """The objective along heights: ``heights`` (N,) and ``cost`` (N,), the grid minimum and
    its parabola-refined height, the curvature there (cost per m^2) and the number of interior
    local minima at least PROMINENCE of the curve's range deep."""

    heights: np.ndarray
    cost: np.ndarray
    h_min: float
    cost_min: float
    curvature: float
    local_minima: int


@dataclass
class Surface:
    """The objective over normal tilts (degrees towards east and north) at a fixed height:
    ``cost`` (len(north), len(east)), and the normals' eq. (11) angles there in degrees."""

    east: np.ndarray
    north: np.ndarray
    cost: np.ndarray
    n_theta: np.ndarray
    n_phi: np.ndarray
    east_min: float
    north_min: float


@dataclass
class PathPoint:
    """One accepted iterate of the optimiser: pyramid level, parameters, the cost at its level
    and at level 0 (to compare with the plots)."""

    level: int
    theta: np.ndarray
    cost_level: float
    cost: float


@dataclass
class ViewInfo:
    """One view at the point of interest: visibility code name, emission angle (degrees), ground
    sample distance (m/pixel), whether it takes part in the objective at the current plane, and
    its leave-one-out correlation there (NaN when not used)."""

    name: str
    code: str
    emission: float
    gsd: float
    used: bool
    loo: float


class Explorer:
    """The MVP objective at one DEM post, for plots and experiments (the mvpgui successor).

    ``problem``: the DEM and views (:class:`~orthomvp.mvp.problem.FitProblem`, as ``fit_dem``
    builds it); ``options``: the window, margin and optimiser settings (``FitOptions``'
    defaults; ``hwin`` and ``sigma`` set them); ``poi`` the point of interest (c, r) and
    ``theta`` the current plane there.
    """

    def __init__(
        self,
        terrain: Terrain,
        images: list[np.ndarray],
        cameras: list[PinholeCamera],
        names: list[str] | None = None,
        eps: float | None = None,
        levels: int = DEFAULTS.levels,
    ) -> None:
        """``images`` (bands, rows, cols) or (rows, cols), band 1 is used; ``names`` label the
        views (default "view 1", ...); ``eps`` the visibility tolerance in DEM posts (default
        rule when None); ``levels`` pyramid levels for ``fit``."""
        self.problem = FitProblem.build(
            terrain,
            images,
            cameras,
            levels=levels,
            eps=eps,
            names=names or [f"view {k + 1}" for k in range(len(images))],
        )
        self.options = replace(DEFAULTS, levels=self.problem.levels)
        self.path: list[PathPoint] | None = None
        rows, cols = terrain.shape
        self.set_poi((cols - 1) // 2, (rows - 1) // 2)

    # ------------------------------------------------------------------ data and window
    @property
    def terrain(self) -> Terrain:
        return self.problem.terrain

    @property
    def names(self) -> list[str]:
        return self.problem.names

    @property
    def visibility(self) -> list[Visibility]:
        """Each view's visibility test on the DEM."""
        assert self.problem.visibility is not None  # the explorer always runs the test
        return self.problem.visibility

    @property
    def spacing(self) -> float:
        """Mean post spacing, metres."""
        return self.problem.spacing

    @property
    def hwin(self) -> int:
        """The window's half-size in posts."""
        return self.options.hwin

    @hwin.setter
    def hwin(self, value: int) -> None:
        self.options = replace(self.options, hwin=value)

    @property
    def sigma(self) -> float | None:
        """The Gaussian window's standard deviation in posts as set (None: hwin / 2)."""
        return self.options.sigma

    @sigma.setter
    def sigma(self, value: float | None) -> None:
        self.options = replace(self.options, sigma=value)

    @property
    def window_sigma(self) -> float:
        """The Gaussian window's standard deviation in posts (hwin / 2 unless set)."""
        return self.options.window_sigma

    # ------------------------------------------------------------------ point and plane
    def set_poi(self, c: int, r: int) -> None:
        """Move to post (c, r) (column, row) and reset the plane to the DEM's tangent plane."""
        rows, cols = self.terrain.shape
        if not (0 <= c < cols and 0 <= r < rows):
            raise ExploreError(f"post ({c}, {r}) is outside the DEM's {cols} x {rows} posts")
        if not self.problem.usable[r, c]:
            raise ExploreError(f"post ({c}, {r}) has no valid DEM value or normal")
        self.poi = (int(c), int(r))
        lines = self.problem.lines(np.array([self.poi[0]]), np.array([self.poi[1]]))
        up = lines.up[0]
        if self.terrain.world == WorldFrame.MAP:
            east = np.array([1.0, 0.0, 0.0])
        else:
            east = np.cross([0.0, 0.0, 1.0], up)
            if np.linalg.norm(east) < 1e-9:  # at a pole: any horizontal direction
                east = np.cross([0.0, 1.0, 0.0], up)
        east = east - (east @ up) * up
        east /= np.linalg.norm(east)
        north = np.cross(up, east)
        self.up, self.east, self.north = up, east, north
        self.model = self.problem.model(lines, up[None], east[None], north[None])
        self.visible = self.problem.visible[:, r, c]
        self.reset_plane()

    def lonlat_to_post(self, lon: float, lat: float) -> tuple[int, int]:
        """The nearest post to (lon, lat) in degrees."""
        c, r = self.terrain.lonlat_to_pixel(np.radians([lon]), np.radians([lat]))
        if not (np.isfinite(c[0]) and np.isfinite(r[0])):
            raise ExploreError(f"lon {lon} lat {lat} has no place on the DEM")
        return int(np.rint(c[0])), int(np.rint(r[0]))

    def post_lonlat(self) -> tuple[float, float]:
        """(lon, lat) of the point of interest, degrees."""
        lon, lat = self.terrain.pixel_to_lonlat(np.array([self.poi[0]]), np.array([self.poi[1]]))
        return float(np.degrees(lon[0])), float(np.degrees(lat[0]))

    def reset_plane(self) -> None:
        """The current plane becomes the DEM's tangent plane at the point of interest (cpi)."""
        c, r = self.poi
        normal = self.problem.normals[r, c]
        self.theta = np.array([float(self.terrain.values[r, c]), *self._tilt(normal)])
        self.path = None

    def _tilt(self, n: np.ndarray) -> tuple[float, float]:
        """(a, b) of a normal n = up + a east + b north (scaled)."""
        up_part = float(n @ self.up)
        if up_part <= 1e-6:
            raise ExploreError("the normal must point upwards (less than 90 degrees from up)")
        return float(n @ self.east) / up_part, float(n @ self.north) / up_part

    def set_plane(self, h: float, n_theta: float, n_phi: float) -> None:
        """Set the current plane from a height and eq. (11) normal angles in degrees."""
        if not all(np.isfinite([h, n_theta, n_phi])):
            raise ExploreError("the plane needs finite height and angles")
        n = normal_from_angles(np.radians(n_theta), np.radians(n_phi))
        self.theta = np.array([h, *self._tilt(n)])
        self.path = None

    def normal(self, theta: np.ndarray) -> np.ndarray:
        """Unit normals (..., 3) of parameters (..., 3)."""
        n = self.up + theta[..., 1:2] * self.east + theta[..., 2:3] * self.north
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def plane_angles(self, theta: np.ndarray | None = None) -> tuple[float, float, float, float]:
        """(n_theta, n_phi, tilt east, tilt north) of a plane, degrees."""
        theta = self.theta if theta is None else theta
        nt, nphi = angles_from_normal(self.normal(theta))
        return (
            float(np.degrees(nt)),
            float(np.degrees(nphi)),
            float(np.degrees(np.arctan(theta[1]))),
            float(np.degrees(np.arctan(theta[2]))),
        )

    # ------------------------------------------------------------------ the objective
    def active_views(
        self, theta: np.ndarray | None = None, window: Window | None = None
    ) -> np.ndarray:
        """(K,) views visible at the post whose patch (the explorer's window unless given) lies
        inside the image at the plane (the current one unless given)."""
        theta = self.theta if theta is None else theta
        hwin = (window or self.options.window).hwin
        sizes = self.problem.stack.sizes[0]
        inside = self.model.inside(theta[None], 0, hwin, sizes, self.options.margin)[0]
        return self.visible & inside

    def _views_or_fail(self, window: Window | None = None) -> np.ndarray:
        W = self.active_views(window=window)
        if W.sum() < 2:
            names = [n for n, v in zip(self.names, self.visible, strict=True) if v]
            raise ExploreError(
                f"post {self.poi} needs 2 views with the patch inside the image, has "
                f"{int(W.sum())} (visible in: {', '.join(names) or 'none'})"
            )
        return W

    def evaluate(
        self,
        thetas: np.ndarray,
        W: np.ndarray,
        extras: bool = False,
        keep_patches: bool = False,
        window: Window | None = None,
    ) -> Evaluation:
        """Eq. (20) at level 0 for planes ``thetas`` (N, 3) with views ``W`` (K,), on the
        explorer's window unless given; ``extras`` adds the leave-one-out correlations."""
        thetas = np.atleast_2d(thetas)
        model = self.model.take(np.zeros(len(thetas), int))
        H, _ = model.homographies(thetas, 0, derivatives=False)
        Wn = np.broadcast_to(W, (len(thetas), len(W)))
        return self.problem.stack.evaluate(
            0, H, Wn, window or self.options.window, extras=extras, keep_patches=keep_patches
        )

    def height_curve(self, half_range: float, steps: int, window: Window | None = None) -> Curve:
        """The objective at ``steps`` heights within +-``half_range`` metres of the current
        plane's, its orientation held, on the explorer's window unless given."""
        if not half_range > 0 or steps < 5:
            raise ExploreError("rplot needs a positive range (metres) and at least 5 steps")
        W = self._views_or_fail(window)
        hs = self.theta[0] + np.linspace(-half_range, half_range, steps)
        thetas = np.repeat(self.theta[None], steps, axis=0)
        thetas[:, 0] = hs
        cost = self.evaluate(thetas, W, window=window).cost
        return _curve(hs, cost)

    def tilt_surface(self, half_range: float, steps: int) -> Surface:
        """The objective over a ``steps`` x ``steps`` grid of normal tilts within
        +-``half_range`` degrees (towards east and north) of the current plane's, height held."""
        if not 0 < half_range < 80 or steps < 5:
            raise ExploreError("llplot needs a range in (0, 80) degrees and at least 5 steps")
        W = self._views_or_fail()
        _, _, e0, n0 = self.plane_angles()
        east = e0 + np.linspace(-half_range, half_range, steps)
        north = n0 + np.linspace(-half_range, half_range, steps)
        if np.abs(east).max() >= 89 or np.abs(north).max() >= 89:
            raise ExploreError("llplot: the range reaches a vertical plane; use a smaller range")
        E, N = np.meshgrid(east, north)
        thetas = np.stack([np.full(E.size, self.theta[0]), np.tan(np.radians(E.ravel())),
                           np.tan(np.radians(N.ravel()))], axis=-1)  # fmt: skip
        cost = self.evaluate(thetas, W).cost.reshape(E.shape)
        nt, nphi = angles_from_normal(self.normal(thetas))
        finite = np.where(np.isfinite(cost), cost, np.inf)
        i, j = np.unravel_index(np.argmin(finite), cost.shape)
        return Surface(
            east,
            north,
            cost,
            np.degrees(nt).reshape(E.shape),
            np.degrees(nphi).reshape(E.shape),
            float(east[j]),
            float(north[i]),
        )

    def views(self) -> list[ViewInfo]:
        """Every view at the point of interest (see :class:`ViewInfo`)."""
        c, r = self.poi
        W = self.active_views()
        loo = np.full(len(W), np.nan)
        used = np.zeros(len(W), bool)
        if W.sum() >= 2:
            ev = self.evaluate(self.theta, W, extras=True)
            used, loo = ev.used[0], np.where(ev.used[0], ev.loo[0], np.nan)
        return [
            ViewInfo(
                self.names[k],
                Code(int(v.codes[r, c])).label,
                float(v.emission[r, c]),
                float(v.gsd[r, c]),
                bool(used[k]),
                float(loo[k]),
            )
            for k, v in enumerate(self.visibility)
        ]

    def patches(self) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray, float]:
        """Names of the used views, their normalised patches (n, 2 hwin + 1, 2 hwin + 1), the
        albedo (2 hwin + 1, 2 hwin + 1), the views' leave-one-out correlations (n,) and the
        cost, at the current plane. Rows run along the DEM's rows, columns along its
        columns."""
        W = self._views_or_fail()
        ev = self.evaluate(self.theta, W, extras=True, keep_patches=True)
        side = self.options.window.side
        used = np.nonzero(ev.used[0])[0]
        patches = ev.patches[0, used].reshape(len(used), side, side)
        return (
            [self.names[k] for k in used],
            patches,
            ev.albedo[0].reshape(side, side),
            ev.loo[0, used],
            float(ev.cost[0]),
        )

    def fit(self) -> tuple[list[PathPoint], list[Iterate]]:
        """Run the optimiser (coarse to fine Levenberg-Marquardt, as ``orthomvp fit`` does, without
        outlier rejection) from the current plane; the plane becomes the result. Returns the
        path (the start and every accepted iterate) and every iteration tried."""
        W = self._views_or_fail()
        opts = self.options
        trace: list[Iterate] = []
        start = self.theta.copy()
        theta, _ = fit_planes(
            self.model,
            self.problem.stack,
            start[None].copy(),
            W[None],
            opts.window,
            opts.lm,
            opts.margin,
            trace,
        )
        start_cost = float(self.evaluate(start, W).cost[0])
        path = [PathPoint(self.problem.levels - 1, start, np.nan, start_cost)]
        for it in trace:
            if it.accepted[0]:
                t = it.trial[0].copy()
                path.append(PathPoint(it.level, t, float(it.cost[0]), np.nan))
        if len(path) > 1:
            level0 = self.evaluate(np.array([p.theta for p in path[1:]]), W).cost
            for p, cst in zip(path[1:], level0, strict=True):
                p.cost = float(cst)
        self.theta = theta[0]
        self.path = path
        return path, trace

    def sweep(
        self, hwins: list[int], half_range: float, steps: int
    ) -> list[tuple[int, float, Curve]]:
        """(hwin, sigma, height curve with the orientation held) for each window half-size in
        ``hwins``, sigma = hwin / 2 unless sigma was set; the explorer's own window is not
        changed."""
        out = []
        for h in hwins:
            window = replace(self.options, hwin=h).window
            out.append((h, window.sigma, self.height_curve(half_range, steps, window)))
        return out


def _curve(hs: np.ndarray, cost: np.ndarray) -> Curve:
    """Minimum, parabola refinement, curvature and local minima of a sampled curve."""
    finite = np.isfinite(cost)
    if finite.sum() < 3:
        raise ExploreError("the objective is undefined over this range (views lost)")
    c = np.where(finite, cost, np.inf)
    i = int(np.argmin(c))
    h_min, curvature = float(hs[i]), np.nan
    if 0 < i < len(hs) - 1 and np.isfinite(c[i - 1 : i + 2]).all():
        step = hs[1] - hs[0]
        y0, y1, y2 = c[i - 1], c[i], c[i + 1]
        denom = y0 - 2 * y1 + y2
        if denom > 0:
            h_min = float(hs[i] + 0.5 * step * (y0 - y2) / denom)
            curvature = float(denom / step**2)
    finite_c = c[np.isfinite(c)]
    depth = PROMINENCE * float(finite_c.max() - finite_c.min())
    minima = len(find_peaks(-np.where(finite, cost, finite_c.max()), prominence=depth)[0])
    return Curve(hs, cost, h_min, float(c[i]), curvature, minima)
