"""Offscreen 3D snapshots of a DEM and its results with pyvista (no display needed).

The scene is built in the *local* frame of :func:`orthomvp.occlusion.mesh.terrain_mesh`: world
metres (body-fixed, or the map frame) minus ``Snapshot.origin``, a point near the DEM centre, so
that VTK's float32 keeps centimetres even at planetary radius. Anything added to
``Snapshot.plotter`` must be shifted the same way. Vertical exaggeration moves only the DEM surface
(and the ray hits drawn on it): cameras stay where they are.

Colouring modes, at most one per snapshot, in the colours of :mod:`orthomvp.present.colours`: a
draped orthophoto, visibility codes (occluded posts green, as in the occlusion poster's
figure 4), height error against a truth DEM (diverging colour map in metres), or plain shaded
relief. pyvista is imported only here, when a snapshot is rendered.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera import Camera, require_pinhole
from orthomvp.codes import CODE_RGB, Code, View
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.outputs import atomic_path
from orthomvp.occlusion.mesh import TerrainMesh, terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.optional import require
from orthomvp.present.colours import (
    CAMERA_COLOURS,
    ERROR_CMAP,
    NAN_RGB,
    check_error_limit,
    error_colour_limit,
    image_colours,
    one_band,
    raster_bands,
    visibility_codes,
)
from orthomvp.present.figures import round_length
from orthomvp.present.viewpoint import (
    Glyph,
    Rect,
    camera_glyph,
    default_azimuth,
    grid_frame,
    image_rect,
    view_dem,
    view_from_camera,
)
from orthomvp.validate import number, of_type

if TYPE_CHECKING:
    import pyvista as pv

DEFAULT_SIZE = (1024, 768)
CROP_MARGIN = 12
"""Pixels of background kept around the content of a cropped snapshot."""
MAX_RAYS = 10_000
"""Most rays drawn per camera (more only paint the snapshot over)."""
BACKGROUND = ("#15171c", "#3a4150")  # bottom, top
LIGHT_ELEVATION = 35.0  # degrees above the local horizon


def _pyvista() -> ModuleType:
    return require("pyvista", "3D snapshots")


@dataclass(frozen=True)
class SnapshotOptions:
    """How a snapshot is drawn; checked on construction (InputError).

    ``rays``: rays per camera, through pixels spread over its image, drawn to their first hits
    on the DEM (0 to :data:`MAX_RAYS`). ``view`` (:class:`orthomvp.codes.View` or its string):
    ``"oblique"`` looks at the DEM centre from ``elevation`` degrees (in (0, 90]), from
    ``azimuth`` degrees clockwise from grid north (default: opposite the first camera, so that
    the slopes it cannot see face the viewer, or 210); ``"top"`` looks straight down, grid
    north up, orthographic; ``"from-camera"`` looks through ``cameras[view_camera]`` (0-based)
    with its vertical field of view and principal point (lens distortion ignored).
    ``exaggerate`` K > 0 scales heights about their median along each post's up direction
    (``h' = h_med + K (h - h_med)``). ``size`` is (width, height) in pixels, 16 to 8192 a side,
    default 1024 x 768 (``from-camera``: the camera's aspect, 1024 on the long side).
    ``legend`` draws the legend or colour bar, and a scale bar in front of the DEM's nearest
    edge labelled with its length and the vertical exaggeration; ``title`` a caption.
    ``error_limit``: the height error colours saturate at +-this many metres (positive;
    default: the 99th percentile of |error|). ``crop`` cuts the empty background around what
    is drawn, to within :data:`CROP_MARGIN` pixels (the image is then smaller than ``size``).
    """

    rays: int = 0
    view: View = View.OBLIQUE
    view_camera: int = 0
    azimuth: float | None = None
    elevation: float = 45.0
    exaggerate: float = 1.0
    size: tuple[int, int] | None = None
    legend: bool = True
    title: str | None = None
    error_limit: float | None = None
    crop: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "view", View(self.view))
        object.__setattr__(
            self, "rays", number(self.rays, "rays", minimum=0, maximum=MAX_RAYS, integer=True)
        )
        object.__setattr__(
            self, "view_camera", number(self.view_camera, "view_camera", minimum=0, integer=True)
        )
        elevation = number(
            self.elevation, "the view elevation (degrees)", minimum=0, maximum=90, min_open=True
        )
        object.__setattr__(self, "elevation", elevation)
        if self.azimuth is not None:
            object.__setattr__(self, "azimuth", number(self.azimuth, "the view azimuth (degrees)"))
        exaggerate = number(self.exaggerate, "vertical exaggeration", minimum=0, min_open=True)
        object.__setattr__(self, "exaggerate", exaggerate)
        if self.size is not None:
            if not (isinstance(self.size, (tuple, list)) and len(self.size) == 2):
                raise InputError(f"snapshot size must be (width, height), got {self.size!r}")
            size = tuple(
                number(n, "snapshot size (pixels a side)", minimum=16, maximum=8192, integer=True)
                for n in self.size
            )
            object.__setattr__(self, "size", size)
        if self.title is not None:
            of_type(self.title, str, "title")
        check_error_limit(self.error_limit)


@dataclass
class Snapshot:
    """A rendered scene: ``image`` (H, W, 3) uint8 RGB, top row first; ``plotter``, the pyvista
    Plotter, still open, for adding to the scene (in the local frame: world minus ``origin``)
    and rendering again with ``plotter.screenshot(return_img=True)``; ``origin`` (3,) float64,
    world metres; ``box`` (left, top, right, bottom) the part of the plotter's window that
    ``image`` shows (all of it unless the options asked to crop)."""

    image: np.ndarray
    plotter: pv.Plotter
    origin: np.ndarray
    box: tuple[int, int, int, int] = (0, 0, 0, 0)

    def save(self, path: str | Path) -> None:
        """Write ``image`` atomically; the format follows the suffix (.png, .jpg, ...)."""
        from PIL import Image

        path = Path(path)
        fmt = Image.registered_extensions().get(path.suffix.lower())
        if fmt is None:
            raise InputError(f"{path}: unknown image format; use .png or .jpg")
        with atomic_path(path) as tmp:
            Image.fromarray(self.image).save(tmp, format=fmt)

    def close(self) -> None:
        """Release the plotter and its offscreen OpenGL context."""
        self.plotter.close()


def snapshot(
    terrain: Terrain,
    *,
    ortho: np.ndarray | None = None,
    visibility: np.ndarray | None = None,
    heights: np.ndarray | None = None,
    truth: np.ndarray | None = None,
    cameras: Sequence[Camera] = (),
    options: SnapshotOptions | None = None,
) -> Snapshot:
    """Render the DEM ``terrain`` offscreen, coloured by at most one raster on its grid.

    Rasters are (rows, cols), (rows, cols, bands) or band-first (bands, rows, cols) on the DEM
    grid:

    - ``ortho``: an orthophoto, 1 band (grey) or 3 (RGB), stretched between its 1st and 99th
      percentiles unless uint8.
    - ``visibility``: codes 0 outside / no data, 1 visible, 2 occluded, 3 facing away
      (colours :data:`orthomvp.codes.CODE_RGB`: occluded green), with a legend.
    - ``heights`` and ``truth`` (both, metres): the error ``heights - truth`` on a diverging
      colour map symmetric about 0 (blue below, red above), with a colour bar in metres.
    - none: shaded relief.

    Posts without a value are :data:`orthomvp.present.colours.NAN_RGB`. ``cameras`` are drawn
    as frusta (see :func:`orthomvp.present.viewpoint.camera_glyph`; a narrow field of view is
    widened to show the image's shape and orientation) with their optical axis, numbered from
    1 (each label beside its glyph, inside the window and clear of the other labels), and a
    thin line towards a far camera's true position. A camera without an image size
    uses the pixel rectangle that holds the DEM's projection. Lighting comes from the image's
    upper left, 35 degrees above the horizon, for readable relief. ``options`` (default
    :class:`SnapshotOptions`) choose the view, rays, size and the rest. Raises InputError for
    rasters off the DEM grid or a from-camera view without its camera.
    """
    opts = options or SnapshotOptions()
    colouring = _colouring(terrain.shape, ortho, visibility, heights, truth)
    cameras = list(cameras)
    if opts.view == View.FROM_CAMERA and not 0 <= opts.view_camera < len(cameras):
        n = len(cameras)
        raise InputError(
            f"the from-camera view needs camera {opts.view_camera} (0-based) but {n} "
            f"camera{'s were' if n != 1 else ' was'} given"
        )
    if opts.view == View.FROM_CAMERA:
        k = opts.view_camera
        require_pinhole(cameras[k], f"camera {k}", "the from-camera view (one centre)")

    tmesh = terrain_mesh(terrain)
    shown, values = tmesh, terrain.values
    if opts.exaggerate != 1.0:
        h_med = float(np.nanmedian(terrain.values))
        values = h_med + opts.exaggerate * (terrain.values - h_med)
        shown = terrain_mesh(terrain, values, origin=tmesh.origin)
    verts = shown.vertices
    centre = (verts.min(axis=0) + verts.max(axis=0)) / 2
    radius = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)) / 2)
    up, north = grid_frame(terrain, tmesh.origin)
    rects = [image_rect(cam, tmesh, f"camera {i}") for i, cam in enumerate(cameras, start=1)]
    width, height = opts.size or _default_size(opts, cameras, rects)

    plotter = _plotter(width, height)
    try:
        _add_terrain(plotter, shown, colouring, opts.legend, opts.error_limit)
        if opts.title:
            plotter.add_text(opts.title, position="upper_left", font_size=max(8, height // 60))

        glyphs = [
            camera_glyph(cam, rect, tmesh.origin, centre, radius)
            for cam, rect in zip(cameras, rects, strict=True)
        ]
        labels = []
        for i, (cam, rect, glyph) in enumerate(zip(cameras, rects, glyphs, strict=True)):
            colour = CAMERA_COLOURS[i % len(CAMERA_COLOURS)]
            if not (opts.view == View.FROM_CAMERA and i == opts.view_camera):
                _add_camera(plotter, glyph, colour)
                labels.append((glyph.points[0], str(i + 1), colour))
            if opts.rays:
                _add_rays(plotter, cam, rect, opts.rays, tmesh, shown, colour)

        if opts.view == View.FROM_CAMERA:
            k = opts.view_camera
            view_from_camera(plotter, cameras[k], rects[k], tmesh.origin)
        else:
            azimuth = opts.azimuth
            if azimuth is None:
                azimuth = default_azimuth(glyphs, centre, up, north)
            framed = np.vstack([verts, *(g.points for g in glyphs)])
            view_dem(plotter, opts.view, framed, centre, up, north, azimuth, opts.elevation)
        _add_light(plotter, centre, up)
        placed = []
        if opts.legend:
            placed.append(_add_scale_bar(plotter, terrain, values, tmesh.origin, opts.exaggerate))
        _add_labels(plotter, labels, placed)
        plotter.reset_camera_clipping_range()
        image = np.ascontiguousarray(plotter.screenshot(return_img=True)[..., :3])
        box = (0, 0, width, height)
        if opts.crop:
            box = content_box(image, background_image(width, height), CROP_MARGIN)
            left, top, right, bottom = box
            image = np.ascontiguousarray(image[top:bottom, left:right])
    except BaseException:
        plotter.close()
        raise
    return Snapshot(image, plotter, tmesh.origin.copy(), box)


def background_image(width: int, height: int) -> np.ndarray:
    """The snapshot background alone, (height, width, 3) uint8, as a snapshot draws it."""
    plotter = _plotter(width, height)
    try:
        return np.ascontiguousarray(plotter.screenshot(return_img=True)[..., :3])
    finally:
        plotter.close()


def content_box(
    image: np.ndarray, background: np.ndarray, margin: int = 0
) -> tuple[int, int, int, int]:
    """(left, top, right, bottom) pixel box, right and bottom exclusive, around the pixels of
    ``image`` that differ from ``background`` (same shape), widened by ``margin`` pixels and
    kept inside the image; the whole image when nothing differs."""
    height, width = image.shape[:2]
    drawn = np.abs(image.astype(np.int16) - background.astype(np.int16)).max(axis=-1) > 2
    rows, cols = np.flatnonzero(drawn.any(axis=1)), np.flatnonzero(drawn.any(axis=0))
    if not len(rows):
        return 0, 0, width, height
    return (
        max(int(cols[0]) - margin, 0),
        max(int(rows[0]) - margin, 0),
        min(int(cols[-1]) + 1 + margin, width),
        min(int(rows[-1]) + 1 + margin, height),
    )


def _default_size(
    opts: SnapshotOptions, cameras: list[Camera], rects: list[Rect]
) -> tuple[int, int]:
    """(width, height) in pixels without ``opts.size``: DEFAULT_SIZE, or for the from-camera
    view the camera's aspect with 1024 pixels on the long side."""
    if opts.view != View.FROM_CAMERA:
        return DEFAULT_SIZE
    u0, v0, u1, v1 = rects[opts.view_camera]
    cam = cameras[opts.view_camera]
    aspect = (u1 - u0) / cam.fu / ((v1 - v0) / cam.fv)
    return (1024, round(1024 / aspect)) if aspect >= 1 else (round(1024 * aspect), 1024)


def _colouring(
    shape: tuple[int, int],
    ortho: np.ndarray | None,
    visibility: np.ndarray | None,
    heights: np.ndarray | None,
    truth: np.ndarray | None,
) -> tuple[str, np.ndarray | None]:
    """The colouring mode and its data: per-post RGB (rows*cols, 3) uint8 for "ortho", codes
    (rows, cols) uint8 for "visibility", the error (rows, cols) in metres for "error", None for
    "relief"."""
    if (heights is None) != (truth is None):
        raise InputError("a height-error snapshot needs both heights and truth")
    given = [ortho is not None, visibility is not None, heights is not None]
    if sum(given) > 1:
        raise InputError("colour by one of orthophoto, visibility or height error, not several")
    if ortho is not None:
        return "ortho", image_colours(raster_bands(ortho, shape, "orthophoto"), "orthophoto")
    if visibility is not None:
        return "visibility", visibility_codes(visibility, shape)
    if heights is not None:
        h = one_band(heights, shape, "heights raster").astype(np.float64)
        error = h - one_band(truth, shape, "truth raster")
        if not np.isfinite(error).any():
            raise InputError("no post has both a height and a truth height")
        return "error", error
    return "relief", None


# ------------------------------------------------------------------------------ drawing
def _plotter(width: int, height: int) -> pv.Plotter:
    """An offscreen Plotter with the snapshot background and no default lights."""
    pv = _pyvista()
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        # Without a display, go straight to EGL instead of letting VTK probe X first (which
        # works too, but prints a warning).
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    theme = pv.themes.DarkTheme()
    plotter = pv.Plotter(off_screen=True, window_size=(width, height), lighting="none", theme=theme)
    plotter.set_background(BACKGROUND[0], top=BACKGROUND[1])
    plotter.enable_anti_aliasing("ssaa")
    return plotter


def _add_terrain(
    plotter: pv.Plotter,
    shown: TerrainMesh,
    colouring: tuple[str, np.ndarray | None],
    legend: bool,
    error_limit: float | None = None,
) -> None:
    """Add the DEM surface, coloured as :func:`_colouring` says, with its legend or colour bar."""
    pv = _pyvista()
    poly = pv.PolyData.from_regular_faces(shown.vertices, shown.faces)
    poly.point_data["Normals"] = np.asarray(shown.mesh.vertex_normals)
    poly.point_data.active_normals_name = "Normals"
    material = {"ambient": 0.3, "diffuse": 0.8, "specular": 0.0, "interpolation": "gouraud"}
    kind, data = colouring
    post = shown.vertex_post
    if kind == "relief":
        plotter.add_mesh(poly, color=Code.VISIBLE.rgb, **material)
    elif kind == "ortho":  # the orthophoto has its own shading: light it less
        material.update(ambient=0.55, diffuse=0.5)
        plotter.add_mesh(poly, scalars=data[post], rgb=True, **material)
    elif kind == "visibility":
        codes = data.ravel()[post]
        plotter.add_mesh(poly, scalars=CODE_RGB[codes], rgb=True, **material)
        if legend:
            labels = [
                [f"{code.label}: {100 * np.mean(codes == code):.1f}%", np.array(code.rgb) / 255]
                for code in (Code.VISIBLE, Code.OCCLUDED, Code.FACING_AWAY, Code.NODATA)
            ]
            box = plotter.add_legend(labels, bcolor=(0.1, 0.1, 0.12), face="rectangle")
            box.SetPosition(0.69, 0.79)  # upper right: lower-left corner, viewport fractions
            box.SetPosition2(0.3, 0.2)
    else:
        font = max(10, plotter.window_size[1] // 40)
        lim = error_colour_limit(data, error_limit)
        plotter.add_mesh(
            poly,
            scalars=data.ravel()[post],
            cmap=ERROR_CMAP,
            clim=(-lim, lim),
            nan_color=np.array(NAN_RGB) / 255,
            show_scalar_bar=legend,
            scalar_bar_args={
                "title": "height error (m)",
                "vertical": True,
                "position_x": 0.86,
                "position_y": 0.15,
                "width": 0.06,
                "height": 0.7,
                "title_font_size": font,
                "label_font_size": font,
                "fmt": "%+.3g",
                "n_labels": 5,
            },
            **material,
        )


def _add_camera(plotter: pv.Plotter, glyph: Glyph, colour: str) -> None:
    """Draw a camera glyph: frustum, optical axis, and a line towards a far camera (its label
    is placed with the others by :func:`_add_labels`)."""
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


def _add_labels(
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


def _add_scale_bar(
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


def _add_rays(
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
    hits = RayCaster(tmesh, threads=1).first_hit(origins, dirs)
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


def _add_light(plotter: pv.Plotter, centre: np.ndarray, up: np.ndarray) -> None:
    """A directional light from the image's upper left, ``LIGHT_ELEVATION`` above the horizon."""
    pv = _pyvista()
    cam = plotter.camera
    fwd = np.subtract(cam.focal_point, cam.position)
    far = fwd / np.linalg.norm(fwd) + np.asarray(cam.up)
    far -= (far @ up) * up
    far /= np.linalg.norm(far)
    right = np.cross(far, up)
    horiz = (far - right) / np.sqrt(2)
    el = np.radians(LIGHT_ELEVATION)
    direction = np.cos(el) * horiz + np.sin(el) * up
    light = pv.Light(light_type="scene light", intensity=1.0)
    light.positional = False
    light.focal_point = centre
    light.position = centre + direction
    plotter.add_light(light)
