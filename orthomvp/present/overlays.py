"""What a snapshot draws over the DEM surface: camera glyphs (frustum, optical axis, tether to
a far camera), rays to their first hits, the camera labels placed clear of each other, and the
scale bar with its length and vertical-exaggeration labels.

Everything is drawn in the local frame of :mod:`orthomvp.present.snapshot` (world metres minus
the snapshot's origin); text positions are display pixels, origin lower left. pyvista is
imported only when a snapshot is rendered.
"""

from __future__ import annotations

from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera import Camera
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.mesh import TerrainMesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.optional import require
from orthomvp.present.figures import round_length
from orthomvp.present.viewpoint import Glyph, Rect

if TYPE_CHECKING:
    import pyvista as pv


def _pyvista() -> ModuleType:
    return require("pyvista", "3D snapshots")


def add_camera(plotter: pv.Plotter, glyph: Glyph, colour: str) -> None:
    """Draw a camera glyph: frustum, optical axis, and a line towards a far camera (its label
    is placed with the others by :func:`add_labels`)."""
    pv = _pyvista()
    lines = [[2, 0, k] for k in range(1, 5)] + [[5, 1, 2, 3, 4, 1], [2, 0, 5]]
    frustum = pv.PolyData(glyph.points, lines=np.concatenate(lines))
    plotter.add_mesh(frustum, color=colour, line_width=2, lighting=False)
    if glyph.far:
        tether = pv.Line(glyph.points[0], glyph.centre)
        plotter.add_mesh(tether, color=colour, line_width=1, opacity=0.5, lighting=False)


Box = tuple[float, float, float, float]
"""(x0, y0, x1, y1) of a text on the window, display pixels (origin lower left)."""


def _font_px(plotter: pv.Plotter) -> int:
    """Height in pixels of the snapshot's labels."""
    return max(14, plotter.window_size[1] // 30)


def _display(plotter: pv.Plotter, point: np.ndarray) -> np.ndarray:
    """Display pixel (x, y), origin lower left, of a local-frame ``point`` in the current view."""
    ren = plotter.renderer
    ren.SetWorldPoint(*(float(v) for v in point), 1.0)
    ren.WorldToDisplay()
    return np.array(ren.GetDisplayPoint()[:2])


def _text_box(text: str, font: int, x: float, y: float) -> Box:
    """The box a text of ``font`` pixels takes with its lower left corner at (x, y) (an
    estimate: characters 0.62 of the font size wide)."""
    return x, y, x + 0.62 * font * len(text) + 4, y + 1.25 * font


def _overlaps(a: Box, b: Box) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _add_text(plotter: pv.Plotter, text: str, box: Box, colour: str, name: str) -> None:
    """Draw ``text`` in ``box`` (from :func:`_text_box`) with a dark shadow, as actor ``name``."""
    actor = plotter.add_text(
        text, position=(box[0], box[1]), font_size=_font_px(plotter) // 2, color=colour, name=name
    )
    actor.prop.shadow = True


def add_labels(
    plotter: pv.Plotter, labels: list[tuple[np.ndarray, str, str]], placed: list[Box]
) -> None:
    """Camera labels (anchor point, text, colour) beside their anchors on the window: each on
    the free side that points away from the others' anchors, inside the window and clear of
    the texts already ``placed`` (their boxes), of each other and of the other anchors."""
    if not labels:
        return
    font = _font_px(plotter)
    width, height = plotter.window_size
    anchors = [_display(plotter, point) for point, _, _ in labels]
    mean = np.mean(anchors, axis=0)
    gap = 0.4 * font
    compass = ((1, 1), (-1, 1), (1, -1), (-1, -1), (1, 0), (-1, 0), (0, 1), (0, -1))
    sides = [np.array(d, float) / np.hypot(*d) for d in compass]
    for (_, text, colour), anchor in zip(labels, anchors, strict=True):
        away = anchor - mean
        order = sorted(sides, key=lambda d: -float(d @ away)) if away.any() else sides
        w, h = _text_box(text, font, 0, 0)[2:]
        best = None
        for d in order:
            for reach in (1.0, 2.0, 3.5):
                centre = anchor + d * (gap * reach + np.array([w, h]) / 2)
                box = _text_box(text, font, *(centre - np.array([w, h]) / 2))
                inside = box[0] >= 2 and box[1] >= 2 and box[2] <= width - 2
                inside = inside and box[3] <= height - 2
                clear = not any(_overlaps(box, other) for other in placed) and not any(
                    box[0] - gap < a[0] < box[2] + gap and box[1] - gap < a[1] < box[3] + gap
                    for a in anchors
                )
                if inside and clear:
                    best = box
                    break
            if best is not None:
                break
        if best is None:  # nowhere free: above right, kept inside the window
            x = float(np.clip(anchor[0] + gap, 2, width - w - 2))
            y = float(np.clip(anchor[1] + gap, 2, height - h - 2))
            best = _text_box(text, font, x, y)
        placed.append(best)
        _add_text(plotter, text, best, colour, f"camera label {text}")


def add_scale_bar(
    plotter: pv.Plotter,
    terrain: Terrain,
    values: np.ndarray,
    origin: np.ndarray,
    exaggerate: float,
) -> Box:
    """A scale bar in front of the DEM edge nearest the bottom of the view: a straight white
    bar of a round length (metres or km, about a quarter of the edge) with end ticks, a few
    posts outside the DEM at the highest shown height of the edge beside it, labelled with its
    length and, below, the vertical exaggeration. ``values`` are the shown (exaggerated)
    heights. Returns the box of the two labels."""
    pv = _pyvista()
    rows, cols = terrain.shape
    off = max(2.0, 0.03 * max(rows, cols))  # posts outside the DEM
    edges = {  # the edge's posts along it, and the post coordinates of the bar's line
        "north": (values[0], lambda t: (t, np.full_like(t, -off)), cols),
        "south": (values[-1], lambda t: (t, np.full_like(t, rows - 1 + off)), cols),
        "west": (values[:, 0], lambda t: (np.full_like(t, -off), t), rows),
        "east": (values[:, -1], lambda t: (np.full_like(t, cols - 1 + off), t), rows),
    }
    h_mid = float(np.nanmedian(values))

    def points(name: str, t: np.ndarray, h: float) -> np.ndarray:
        c, r = edges[name][1](np.asarray(t, np.float64))
        return terrain.to_world(c, r, np.full(c.shape, h)) - origin

    def screen_y(name: str) -> float:
        n = edges[name][2]
        return float(_display(plotter, points(name, np.array([(n - 1) / 2]), h_mid)[0])[1])

    name = min(edges, key=screen_y)
    edge, _, n = edges[name]
    ends = points(name, np.array([0.0, n - 1.0]), h_mid)
    length = round_length(float(np.linalg.norm(ends[1] - ends[0])) / 4)
    start = 0.1 * (n - 1)
    if _display(plotter, ends[0])[0] > _display(plotter, ends[1])[0]:
        start = 0.9 * (n - 1)  # start from the end on the left of the view
    a, b = points(name, np.array([start, start + np.sign(n / 2 - start)]), h_mid)
    along = (b - a) / np.linalg.norm(b - a)
    lo, hi = sorted((start, start + np.sign(n / 2 - start) * length / np.linalg.norm(b - a)))
    span = edge[max(int(np.floor(lo)), 0) : int(np.ceil(hi)) + 1]
    h_bar = float(np.nanmax(span)) if np.isfinite(span).any() else h_mid
    p0 = points(name, np.array([start]), h_bar)[0]
    p1 = p0 + length * along
    up = terrain.up_vectors(p0 + origin)
    tick = 0.04 * length * up
    bar = pv.PolyData(
        np.array([p0, p1, p0 - tick, p0 + tick, p1 - tick, p1 + tick]),
        lines=np.array([2, 0, 1, 2, 2, 3, 2, 4, 5]),
    )
    plotter.add_mesh(
        bar, color="white", line_width=4, lighting=False, reset_camera=False, name="scale bar"
    )
    lines = [
        f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m",
        f"vertical exaggeration {exaggerate:g}x" if exaggerate != 1 else "no vertical exaggeration",
    ]
    font = _font_px(plotter)
    width, height = plotter.window_size
    ends = np.array([_display(plotter, p) for p in (p0, p1)])
    sizes = [_text_box(text, font, 0, 0)[2:] for text in lines]
    w, h = max(s[0] for s in sizes), sum(s[1] for s in sizes)
    gap = 0.3 * font
    (x0, y0), (x1, y1) = ends.min(axis=0), ends.max(axis=0)
    mid = (x0 + x1) / 2
    corners = [  # lower left corner of the block: below the bar, above, right of it, left
        (mid - w / 2, y0 - gap - h),
        (mid - w / 2, y1 + gap),
        (x1 + gap, (y0 + y1 - h) / 2),
        (x0 - gap - w, (y0 + y1 - h) / 2),
    ]
    fits = [c for c in corners if 2 <= c[0] <= width - w - 2 and 2 <= c[1] <= height - h - 2]
    x, y = fits[0] if fits else corners[0]
    x, y = float(np.clip(x, 2, max(width - w - 2, 2))), float(np.clip(y, 2, height - h - 2))
    box = (x, y, x + w, y + h)
    top = y + h
    for k, (text, (tw, th)) in enumerate(zip(lines, sizes, strict=True)):  # centred, stacked
        top -= th
        box_k = _text_box(text, font, x + (w - tw) / 2, top)
        _add_text(plotter, text, box_k, "white", f"scale bar label {k}")
    return box


def add_rays(
    plotter: pv.Plotter,
    camera: Camera,
    rect: Rect,
    n: int,
    tmesh: TerrainMesh,
    shown: TerrainMesh,
    colour: str,
) -> None:
    """Draw ``n`` rays through pixels spread over ``rect`` (an R2 low-discrepancy sequence) to
    their first hits on the true mesh, drawn on the shown (exaggerated) one; misses are left
    out."""
    pv = _pyvista()
    g = 1.32471795724474602596  # plastic number: R2 sequence step (1/g, 1/g^2)
    k = np.arange(n)
    fu, fv = (0.5 + k / g) % 1.0, (0.5 + k / g**2) % 1.0
    u0, v0, u1, v1 = rect
    uv = np.column_stack([u0 + (0.03 + 0.94 * fu) * (u1 - u0), v0 + (0.03 + 0.94 * fv) * (v1 - v0)])
    origins, dirs = camera.ray(uv)
    hits = RayCaster(tmesh, threads=1).first_hit(origins, dirs, invalid="miss")
    if not hits.mask.any():
        return
    tri = shown.faces[hits.triangle[hits.mask]]
    b = hits.barycentric[hits.mask]
    v = shown.vertices
    ends = (
        (1 - b.sum(axis=1))[:, None] * v[tri[:, 0]]
        + b[:, :1] * v[tri[:, 1]]
        + b[:, 1:] * v[tri[:, 2]]
    )
    starts = origins[hits.mask] - tmesh.origin  # one centre, or each ray's own origin
    m = len(ends)
    points = np.vstack([starts, ends])
    lines = np.column_stack([np.full(m, 2), np.arange(m), np.arange(m, 2 * m)]).ravel()
    plotter.add_mesh(
        pv.PolyData(points, lines=lines), color=colour, line_width=1, opacity=0.8, lighting=False
    )
    plotter.add_points(
        ends, color=colour, point_size=6, render_points_as_spheres=True, lighting=False
    )
