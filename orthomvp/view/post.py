"""A clicked post: the explorer's plots computed live, and the 3D scene around it.

The plots are the explorer's own (:mod:`orthomvp.explore.plots`), from the same
:class:`~orthomvp.explore.Explorer` that ``orthomvp explore`` drives: at the clicked post the
plane starts as the DEM's tangent plane, the optimiser runs from it (its path), and rplot,
llplot and the patches are drawn about the fitted plane. A DEM of more than BLOCK x BLOCK posts
is explored in blocks (BLOCK posts and MARGIN around them, each made when first clicked, its
window alone read from the file), so memory stays bounded by the block, not the DEM; occluders
beyond a block's margin are then not seen.
"""

from __future__ import annotations

import base64
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np
from matplotlib.figure import Figure

from orthomvp.camera import Camera
from orthomvp.codes import Code
from orthomvp.engine.grid import DemSource, WindowT
from orthomvp.errors import InputError
from orthomvp.explore import ExploreError, Explorer
from orthomvp.explore.plots import height_plot, patches_plot, tilt_plot
from orthomvp.explore.session import DEFAULTS
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.present.colours import CAMERA_COLOURS
from orthomvp.view.layers import Layer, LayerSet
from orthomvp.view.tiles import render

BLOCK = 512
MARGIN = 128
DPI = 72


@dataclass(frozen=True)
class Controls:
    """A click's settings: ``hwin`` (posts), ``views`` (0-based indices taken, None: all),
    rplot's half-range (m) and steps, llplot's half-range (degrees) and steps."""

    hwin: int = 10
    views: tuple[int, ...] | None = None
    h_range: float | None = None
    h_steps: int = 61
    t_range: float = 20.0
    t_steps: int = 21

    def __post_init__(self) -> None:
        if not 1 <= self.hwin <= 50:
            raise ExploreError(f"hwin must be 1 to 50 posts, not {self.hwin}")
        if not 5 <= self.h_steps <= 401 or not 5 <= self.t_steps <= 81:
            raise ExploreError("steps: rplot 5 to 401, llplot 5 to 81")


RPLOT_AXES = ((0.10, 0.11, 0.87, 0.76),)
LLPLOT_AXES = ((0.11, 0.09, 0.70, 0.77), (0.85, 0.14, 0.03, 0.67))
"""Fixed axes rectangles (figure fractions) of rplot, and of llplot and its colour bar:
placed here rather than by the explorer's constrained layout, which took most of a figure's
drawing time (its tight bounding boxes measure every tick label)."""


def _patch_axes(n: int) -> tuple[tuple[float, float, float, float], ...]:
    """Fixed rectangles of the patches figure's ``n`` panels (views and albedo) and its colour
    bar, for the figure's 2.3 inches a panel (the bar and its label take the last 0.9 inch)."""
    inch = 1.0 / (2.3 * n)
    width = (1.0 - 0.9 * inch - 0.02) / n
    panels = tuple((0.02 + k * width, 0.04, 0.92 * width, 0.64) for k in range(n))
    return (*panels, (1.0 - 0.85 * inch, 0.1, 0.15 * inch, 0.52))


def _png(fig: Figure, rects: tuple[tuple[float, float, float, float], ...]) -> str:
    """A PNG data URL of ``fig`` drawn once at DPI with its axes at ``rects`` (in the order of
    ``fig.axes``) and their titles at a fixed height, instead of its own constrained layout."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from orthomvp.view.tiles import png

    fig.set_layout_engine("none")
    for ax in fig.axes:  # a title at a fixed height: no bounding boxes to place it
        if ax.get_title():
            ax.set_title(ax.get_title(), fontsize=ax.title.get_fontsize(), y=1.0)
    for ax, rect in zip(fig.axes, rects, strict=True):
        ax.set_position(rect)
    fig.set_dpi(DPI)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    data = png(np.asarray(canvas.buffer_rgba()))
    return "data:image/png;base64," + base64.b64encode(data).decode()


@contextmanager
def _one_thread() -> Iterator[None]:
    """numba's kernels on this (the request's) thread run on one thread: a click evaluates one
    post at a time (the fit), and waking numba's OpenMP threads for each cost 10-15 ms on 2
    busy cores against 0.7 ms for the evaluation itself (the same result: posts are
    independent). numba's thread count is per calling thread."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


class Posts:
    """Clicks on the map: the views (images, cameras, names) and the DEM (``dem``, read in the
    windows a click needs, in the cameras' world frame: :func:`~orthomvp.engine.grid.with_world`),
    with the fitted-height and uncertainty layers when given."""

    def __init__(
        self,
        layers: LayerSet,
        dem: DemSource,
        images: list[np.ndarray],
        cameras: list[Camera],
        names: list[str],
        *,
        eps: float | None = None,
        levels: int = DEFAULTS.levels,
    ) -> None:
        self.layers, self.dem, self.grid = layers, dem, dem.geometry()
        self.images, self.cameras, self.names = images, cameras, names
        self.eps, self.levels = eps, levels
        self._explorers: dict[tuple[int, int], Explorer] = {}
        self._lock = threading.Lock()

    def warm(self) -> None:
        """Make the explorer of the DEM's centre and evaluate the objective there once (numba
        compiles its kernels), so that the first click is as fast as the others."""
        rows, cols = self.dem.shape
        with self._lock:
            ex, cl, rl = self.explorer(cols // 2, rows // 2)  # its visibility on every core
        with self._lock, _one_thread():
            try:
                ex.set_poi(cl, rl)
                ex.height_curve(10.0, 5)
                ex.fit()
            except ExploreError:
                pass  # a post no two views see: the kernels compile at the first click

    def post_of(self, x: float, y: float) -> tuple[int, int]:
        """The nearest DEM post (c, r) to map point (x, y); ExploreError outside the DEM."""
        c, r = self.grid.crs_to_pixel(np.array([x]), np.array([y]))
        c, r = int(np.rint(c[0])), int(np.rint(r[0]))
        rows, cols = self.dem.shape
        if not (0 <= c < cols and 0 <= r < rows):
            raise ExploreError("outside the DEM: click on the DEM's posts")
        return c, r

    def explorer(self, c: int, r: int) -> tuple[Explorer, int, int]:
        """The explorer holding post (c, r) and the post's place in it."""
        rows, cols = self.dem.shape
        if rows <= BLOCK + 2 * MARGIN and cols <= BLOCK + 2 * MARGIN:
            key, window = (0, 0), (0, rows, 0, cols)
        else:
            key = (r // BLOCK, c // BLOCK)
            window = (
                max(key[0] * BLOCK - MARGIN, 0),
                min((key[0] + 1) * BLOCK + MARGIN, rows),
                max(key[1] * BLOCK - MARGIN, 0),
                min((key[1] + 1) * BLOCK + MARGIN, cols),
            )
        if key not in self._explorers:
            self._explorers[key] = Explorer(
                self.terrain(window),
                self.images,
                self.cameras,
                names=self.names,
                eps=self.eps,
                levels=self.levels,
            )
        return self._explorers[key], c - window[2], r - window[0]

    def terrain(self, window: WindowT) -> Terrain:
        """The DEM's posts in ``window`` (row0, row1, col0, col1) read from the file, as a
        Terrain of their own whose longitudes wrap as the whole DEM's."""
        t = self.dem.window_terrain(window, self.dem.read(window))
        return replace(t, wrap_lon=self.grid.wrap_lon)

    def _file_value(self, kind: str, x: float, y: float) -> float | None:
        for layer in self.layers.layers.values():
            if layer.kind.name == kind:
                v = layer.value_at(x, y)
                if v is not None and np.isfinite(v[0]):
                    return float(v[0])
        return None

    def click(self, x: float, y: float, controls: Controls) -> dict:
        """The explorer's views at the post nearest (x, y): JSON with the post, the views, the
        fit, rplot's minimum and the plots as PNG data URLs; ``error`` says why there are no
        plots (a post no two views see, a hole in the DEM)."""
        c, r = self.post_of(x, y)
        with self._lock:
            ex, cl, rl = self.explorer(c, r)  # made at a block's first click: on every core
        with self._lock, _one_thread():
            out: dict = {"post": [c, r]}
            ex.set_poi(cl, rl)
            lon, lat = ex.post_lonlat()
            px, py = self.grid.pixel_to_crs(np.array([c]), np.array([r]))
            fitted = self._file_value("height", float(px[0]), float(py[0]))
            sigma = self._file_value("uncertainty", float(px[0]), float(py[0]))
            out.update(
                lon=lon,
                lat=lat,
                x=float(px[0]),
                y=float(py[0]),
                dem_height=float(ex.theta[0]),
                fitted_file=fitted,
                sigma_file=sigma,
            )
            ex.hwin = controls.hwin
            if controls.views is not None:
                keep = np.zeros(len(ex.names), bool)
                keep[[k for k in controls.views if 0 <= k < len(keep)]] = True
                ex.visible = ex.visible & keep
            out["views"] = [vars(v) for v in ex.views()]
            try:
                out.update(self._plots(ex, controls, fitted, sigma))
            except ExploreError as exc:
                out["error"] = str(exc)
        return out

    def _plots(
        self, ex: Explorer, controls: Controls, fitted: float | None, sigma: float | None
    ) -> dict:
        c, r = ex.poi
        where = f"post ({c}, {r}), hwin {ex.hwin}"
        path, _ = ex.fit()
        h_range = controls.h_range or 5.0 * ex.spacing
        curve = ex.height_curve(h_range, controls.h_steps)
        rplot = height_plot(curve, float(ex.theta[0]), where, path)
        ax = rplot.figure.axes[0]
        if fitted is not None:
            ax.axvline(
                fitted, color="tab:green", lw=1.5, label=f"fitted DEM {fitted:.2f} m (deconvolved)"
            )
            if sigma is not None:
                ax.axvspan(
                    fitted - sigma,
                    fitted + sigma,
                    color="tab:green",
                    alpha=0.15,
                    label=f"± {sigma:.2f} m (1 sigma)",
                )
            ax.legend(fontsize=8)
        surf = ex.tilt_surface(controls.t_range, controls.t_steps)
        _, _, e, n = ex.plane_angles()
        llplot = tilt_plot(surf, (e, n), where, path)
        names, patches, albedo, loo, _ = ex.patches()
        patch = patches_plot(names, patches, albedo, list(loo), where)
        nt, nphi, _, _ = ex.plane_angles()
        return {
            "fit": {"h": float(ex.theta[0]), "n_theta": nt, "n_phi": nphi, "steps": len(path) - 1},
            "rplot": {
                "h_min": curve.h_min,
                "cost_min": curve.cost_min,
                "local_minima": curve.local_minima,
                "png": _png(rplot.figure, RPLOT_AXES),
            },
            "llplot": {
                "east_min": surf.east_min,
                "north_min": surf.north_min,
                "png": _png(llplot.figure, LLPLOT_AXES),
            },
            "patches": {"views": names, "png": _png(patch.figure, _patch_axes(len(names) + 1))},
        }

    # ------------------------------------------------------------------ 3D
    def scene(self, x: float, y: float, layer: Layer, radius: int = 40) -> dict:
        """The DEM window of ``radius`` posts around the post nearest (x, y) in a local frame
        (metres east, north, up of the post), draped with ``layer`` (a PNG data URL), and each
        view's camera and ray to the post with its first hit in the window."""
        c, r = self.post_of(x, y)
        rows, cols = self.dem.shape
        r0, r1 = max(r - radius, 0), min(r + radius + 1, rows)
        c0, c1 = max(c - radius, 0), min(c + radius + 1, cols)
        win = self.terrain((r0, r1, c0, c1))
        gc, gr = win.grid()
        world = win.to_world(gc, gr, win.values)
        origin = win.to_world(np.array(c - c0), np.array(r - r0), win.values[r - r0, c - c0])
        if not np.isfinite(origin).all():
            raise ExploreError(f"post ({c}, {r}) has no DEM value")
        up = win.up_vectors(origin)
        east = np.array([1.0, 0, 0]) if abs(up[2]) > 0.999999 else np.cross([0, 0, 1.0], up)
        east /= np.linalg.norm(east)
        frame = np.stack([east, np.cross(up, east), up])
        local = (world - origin) @ frame.T
        rect = self._window_bounds(r0, r1, c0, c1)
        spacing = self.dem.post_spacing()
        mpp = spacing / 4
        tex = render(layer, rect, (4 * (c1 - c0), 4 * (r1 - r0)), mpp)
        from orthomvp.view.tiles import png

        with self._lock:
            ex, cl, rl = self.explorer(c, r)
        reach = 1.5 * radius * spacing
        views = []
        tmesh = terrain_mesh(win)
        caster = RayCaster(tmesh, threads=1)
        for k, (name, cam) in enumerate(zip(self.names, self.cameras, strict=True)):
            uv = ex.visibility[k].uv[rl, cl]
            code = int(ex.visibility[k].codes[rl, cl])
            if not np.isfinite(uv).all():
                views.append({"name": name, "code": Code(code).label, "camera": None})
                continue
            centre = cam.origins(uv[None])[0]
            d = origin - centre
            dist = float(np.linalg.norm(d))
            hits = caster.first_hit(centre[None], (d / dist)[None], invalid="miss")
            hit = (hits.points[0] - origin) @ frame.T if hits.mask[0] else None
            cam_local = (centre - origin) @ frame.T
            shown = cam_local * min(1.0, reach / dist)
            views.append(
                {
                    "name": name,
                    "code": Code(code).label,
                    "colour": CAMERA_COLOURS[k % 4],
                    "camera": shown.tolist(),
                    "distance": dist,
                    "hit": None if hit is None else hit.tolist(),
                    "hit_colour": "#{:02x}{:02x}{:02x}".format(*Code(code).rgb),
                }
            )
        z = np.where(np.isfinite(local[..., 2]), local[..., 2], np.nan)
        return {
            "post": [c, r],
            "shape": [r1 - r0, c1 - c0],
            "layer": layer.title,
            "x": _list(local[..., 0]),
            "y": _list(local[..., 1]),
            "z": _list(z),
            "texture": "data:image/png;base64," + base64.b64encode(png(tex)).decode(),
            "views": views,
            "spacing": spacing,
        }

    def _window_bounds(self, r0: int, r1: int, c0: int, c1: int) -> tuple[float, ...]:
        t = self.dem.transform
        xs = [t.c + t.a * c0, t.c + t.a * c1]
        ys = [t.f + t.e * r0, t.f + t.e * r1]
        return (min(xs), min(ys), max(xs), max(ys))


def _list(a: np.ndarray) -> list:
    """Rounded floats (cm) with NaN as None, for JSON."""
    flat = np.round(a.ravel(), 2)
    return [None if not np.isfinite(v) else float(v) for v in flat]


def check_views(views: list[int], count: int) -> tuple[int, ...]:
    """0-based view indices, InputError for one out of range."""
    bad = [k for k in views if not 0 <= k < count]
    if bad:
        raise InputError(f"no view {bad[0] + 1}: there are {count}")
    return tuple(views)
