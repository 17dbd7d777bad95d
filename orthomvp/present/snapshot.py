"""Offscreen 3D snapshots of a DEM and its results with pyvista (no display needed).

The scene is built in the *local* frame of :func:`orthomvp.occlusion.mesh.terrain_mesh`: world
metres (body-fixed, or the map frame) minus ``Snapshot.origin``, a point near the DEM centre, so
that VTK's float32 keeps centimetres even at planetary radius. Anything added to
``Snapshot.plotter`` must be shifted the same way. Vertical exaggeration moves only the DEM surface
(and the ray hits drawn on it): cameras stay where they are.

Colouring modes, at most one per snapshot, in the colours of :mod:`orthomvp.present.colours`: a
draped orthophoto, visibility codes (occluded posts green, as in the occlusion poster's
figure 4), height error against a truth DEM (diverging colour map in metres), or plain shaded
relief. What is drawn over the surface (cameras, rays, labels, the scale bar) is
:mod:`orthomvp.present.overlays`. pyvista is imported only when a snapshot is rendered.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera import Camera, PinholeCamera
from orthomvp.camera.csm import CsmFrameCamera
from orthomvp.codes import CODE_RGB, Code, View
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.outputs import atomic_path
from orthomvp.occlusion.mesh import TerrainMesh, terrain_mesh
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
from orthomvp.present.overlays import _pyvista, add_camera, add_labels, add_rays, add_scale_bar
from orthomvp.present.viewpoint import (
    Rect,
    camera_glyph,
    default_azimuth,
    frame_view,
    grid_frame,
    image_rect,
    view_dem,
    view_from_camera,
)
from orthomvp.validate import number, of_type

if TYPE_CHECKING:
    import pyvista as pv

DEFAULT_SIZE = (1024, 768)
FRAME = (PinholeCamera, CsmFrameCamera)
"""The cameras with one centre that the from-camera view looks through."""
CROP_MARGIN = 12
"""Pixels of background kept around the content of a cropped snapshot."""
MAX_RAYS = 10_000
"""Most rays drawn per camera (more only paint the snapshot over)."""
BACKGROUND = ("#15171c", "#3a4150")  # bottom, top
LIGHT_ELEVATION = 35.0  # degrees above the local horizon


@dataclass(frozen=True)
class SnapshotOptions:
    """How a snapshot is drawn; checked on construction (InputError).

    ``rays``: rays per camera, through pixels spread over its image, drawn to their first hits
    on the DEM (0 to :data:`MAX_RAYS`). ``view`` (:class:`orthomvp.codes.View` or its string):
    ``"oblique"`` looks at the DEM centre from ``elevation`` degrees (in (0, 90]), from
    ``azimuth`` degrees clockwise from grid north (default: opposite the first camera, so that
    the slopes it cannot see face the viewer, or 210); ``"top"`` looks straight down, grid
    north up, orthographic; ``"from-camera"`` looks through ``cameras[view_camera]`` (0-based),
    a frame camera (:data:`FRAME`: a pinhole with its vertical field of view and principal
    point, lens distortion ignored; a CSM or ISIS frame camera through its own rays).
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
            f"the from-camera view needs camera {opts.view_camera + 1} (counted from 1) but "
            f"{n} camera{'s were' if n != 1 else ' was'} given"
        )
    if opts.view == View.FROM_CAMERA and not isinstance(cameras[opts.view_camera], FRAME):
        kind = type(cameras[opts.view_camera]).__name__
        raise InputError(
            f"camera {opts.view_camera + 1}: the from-camera view needs a frame camera (one "
            "centre): a pinhole (.tsai, .pinhole, .json, Orthority frame) or a CSM or ISIS "
            f"frame camera; this one is a {kind}"
        )

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
                add_camera(plotter, glyph, colour)
                labels.append((glyph.points[0], str(i + 1), colour))
            if opts.rays:
                add_rays(plotter, cam, rect, opts.rays, tmesh, shown, colour)

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
            placed.append(add_scale_bar(plotter, terrain, values, tmesh.origin, opts.exaggerate))
        add_labels(plotter, labels, placed)
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
    _, _, _, _, (tl, tr, tt, tb) = frame_view(cameras[opts.view_camera], rects[opts.view_camera])
    aspect = (tr - tl) / (tb - tt)
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
