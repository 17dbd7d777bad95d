"""Offscreen 3D snapshots of a DEM and its results with pyvista (no display needed).

The scene is built in the *local* frame of :func:`orthomvp.mesh.terrain_mesh`: world metres
(body-fixed, or the map frame) minus ``Snapshot.origin``, a point near the DEM centre, so that
VTK's float32 keeps centimetres even at planetary radius. Anything added to ``Snapshot.plotter``
must be shifted the same way. Vertical exaggeration moves only the DEM surface (and the ray hits
drawn on it): cameras stay where they are.

Colouring modes, at most one per snapshot: a draped orthophoto, visibility codes (as in
:mod:`orthomvp.visibility`; occluded posts green, as in the occlusion poster's figure 4), height
error against a truth DEM (diverging colour map in metres), or plain shaded relief.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyvista as pv

from orthomvp.camera import PinholeCamera
from orthomvp.codes import Code
from orthomvp.errors import InputError
from orthomvp.mesh import TerrainMesh, terrain_mesh, vis_palette
from orthomvp.palette import VIS_RGB
from orthomvp.raster import atomic_path
from orthomvp.raycast import RayCaster
from orthomvp.terrain import Terrain

VIEWS = ("oblique", "top", "from-camera")
DEFAULT_SIZE = (1024, 768)
NAN_COLOUR = (48, 48, 54)
"""RGB colour of posts without a value (an empty orthophoto post, an unknown height error)."""
CAMERA_COLOURS = ("#ffd21f", "#ff4fd8", "#4fc3ff", "#ffffff", "#a98bff", "#ff6b6b")
"""Colours of cameras (frusta, rays and their hits), in turn; green is kept for occlusion."""
BACKGROUND = ("#15171c", "#3a4150")  # bottom, top
VIEW_ANGLE = 30.0  # vertical field of view of the oblique view, degrees
LIGHT_ELEVATION = 35.0  # degrees above the local horizon
GLYPH_DISTANCE = 1.2  # far cameras are drawn this many DEM radii from the DEM centre
GLYPH_SIZE = 0.25  # depth of a camera glyph, in DEM radii
GLYPH_OPENING = 0.4  # least half-size of a camera glyph's image rectangle (tangent)


@dataclass
class Snapshot:
    """A rendered scene: ``image`` (H, W, 3) uint8 RGB, top row first; ``plotter``, the pyvista
    Plotter, still open, for adding to the scene (in the local frame: world minus ``origin``)
    and rendering again with ``plotter.screenshot(return_img=True)``; ``origin`` (3,) float64,
    world metres."""

    image: np.ndarray
    plotter: pv.Plotter
    origin: np.ndarray

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
    cameras: Sequence[PinholeCamera] = (),
    rays: int = 0,
    view: str = "oblique",
    view_camera: int = 0,
    azimuth: float | None = None,
    elevation: float = 45.0,
    exaggerate: float = 1.0,
    size: tuple[int, int] | None = None,
    legend: bool = True,
    title: str | None = None,
    error_limit: float | None = None,
) -> Snapshot:
    """Render the DEM ``terrain`` offscreen, coloured by at most one raster on its grid.

    Rasters are (rows, cols) or band-first (bands, rows, cols) on the DEM grid:

    - ``ortho``: an orthophoto, 1 band (grey) or 3 (RGB), stretched between its 1st and 99th
      percentiles; NaN posts are dark grey.
    - ``visibility``: codes 0 outside / no data, 1 visible, 2 occluded, 3 facing away
      (colours :data:`orthomvp.palette.VIS_RGB`: occluded green), with a legend.
    - ``heights`` and ``truth`` (both, metres): the error ``heights - truth`` on a diverging
      colour map symmetric about 0 (blue below, red above), saturating at +-``error_limit``
      metres (default: the 99th percentile of |error|), with a colour bar in metres.
    - none: shaded relief.

    ``cameras`` are drawn as frusta (image rectangle at a depth of a quarter of the DEM's
    radius; a narrow field of view is widened to show the image's shape and orientation) with
    their optical axis, numbered from 1; a camera farther than 1.2 DEM radii from the DEM centre is
    drawn at that distance, on its line of sight to the DEM centre, with a thin line towards
    its true position. ``rays`` rays per camera, through pixels spread over its image, are drawn
    to their first hits on the DEM. A camera without an image size uses the pixel rectangle
    that holds the DEM's projection.

    ``view``: ``"oblique"`` looks at the DEM centre from ``elevation`` degrees, from
    ``azimuth`` degrees clockwise from grid north (default: opposite the first camera, so that
    the slopes it cannot see face the viewer, or 210); ``"top"`` looks straight down, grid north
    up, orthographic; ``"from-camera"`` looks through ``cameras[view_camera]`` (0-based) with
    its vertical field of view and principal point (lens distortion ignored). Lighting comes from
    the image's upper left, 35 degrees above the horizon, for readable relief.

    ``exaggerate`` K scales heights about their median along each post's up direction
    (``h' = h_med + K (h - h_med)``). ``size`` is (width, height) in pixels, default 1024 x 768
    (``from-camera``: the camera's aspect, 1024 on the long side). ``legend`` draws the legend or
    colour bar; ``title`` a caption. Raises InputError for rasters off the DEM grid, an unknown
    view or a camera index out of range.
    """
    if error_limit is not None and not error_limit > 0:
        raise InputError(f"the error limit must be a positive number of metres, got {error_limit}")
    shape = terrain.shape
    colouring = _colouring(shape, ortho, visibility, heights, truth)
    cameras = list(cameras)
    _check_options(view, view_camera, len(cameras), rays, elevation, exaggerate, size)

    tmesh = terrain_mesh(terrain)
    shown = tmesh
    if exaggerate != 1.0:
        h_med = float(np.nanmedian(terrain.values))
        values = h_med + exaggerate * (terrain.values - h_med)
        shown = terrain_mesh(terrain, values, origin=tmesh.origin)
    verts = np.asarray(shown.mesh.vertices)
    centre = (verts.min(axis=0) + verts.max(axis=0)) / 2
    radius = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)) / 2)
    up, north = _grid_frame(terrain, tmesh.origin)
    rects = [_image_rect(cam, tmesh) for cam in cameras]

    if size is None:
        size = DEFAULT_SIZE
        if view == "from-camera":
            u0, v0, u1, v1 = rects[view_camera]
            cam = cameras[view_camera]
            aspect = (u1 - u0) / cam.fu / ((v1 - v0) / cam.fv)
            size = (1024, round(1024 / aspect)) if aspect >= 1 else (round(1024 * aspect), 1024)
    width, height = int(size[0]), int(size[1])

    plotter = _plotter(width, height)
    try:
        _add_terrain(plotter, shown, colouring, legend, error_limit)
        if title:
            plotter.add_text(title, position="upper_left", font_size=max(8, height // 60))

        glyphs = [
            _glyph(cam, rect, tmesh.origin, centre, radius)
            for cam, rect in zip(cameras, rects, strict=True)
        ]
        for i, (cam, rect, glyph) in enumerate(zip(cameras, rects, glyphs, strict=True)):
            colour = CAMERA_COLOURS[i % len(CAMERA_COLOURS)]
            if not (view == "from-camera" and i == view_camera):
                _add_camera(plotter, glyph, colour, str(i + 1))
            if rays:
                _add_rays(plotter, cam, rect, rays, tmesh, shown, colour)

        if view == "from-camera":
            _view_from_camera(plotter, cameras[view_camera], rects[view_camera], tmesh.origin)
        else:
            if azimuth is None:
                azimuth = _default_azimuth(glyphs, centre, up, north)
            framed = np.vstack([verts, *(g.points for g in glyphs)])
            _view_dem(plotter, view, framed, centre, up, north, azimuth, elevation)
        _add_light(plotter, centre, up)
        plotter.reset_camera_clipping_range()
        image = np.ascontiguousarray(plotter.screenshot(return_img=True)[..., :3])
    except BaseException:
        plotter.close()
        raise
    return Snapshot(image, plotter, tmesh.origin.copy())


def visibility_codes(data: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Visibility codes (rows, cols) uint8 from a raster on the DEM grid (NaN -> 0)."""
    band = _bands("visibility", data, shape)[0]
    band = np.where(np.isfinite(band), band, Code.NODATA)
    if not np.isin(band, list(Code)).all():
        raise InputError(
            "the visibility raster holds values other than the codes 0 (outside), 1 (visible), "
            "2 (occluded) and 3 (facing away)"
        )
    return band.astype(np.uint8)


# ------------------------------------------------------------------------------ inputs
def _bands(name: str, data: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``data`` as band-first float64 (bands, rows, cols), checked against the DEM grid."""
    arr = np.asarray(data)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != shape:
        got = " x ".join(str(n) for n in arr.shape[::-1][:2]) if arr.ndim > 1 else str(arr.shape)
        raise InputError(
            f"the {name} raster is {got} but the DEM grid is {shape[1]} x {shape[0]} "
            "(columns x rows): give a raster on the DEM grid"
        )
    return arr.astype(np.float64)


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
        return "ortho", _ortho_colours(_bands("orthophoto", ortho, shape))
    if visibility is not None:
        return "visibility", visibility_codes(visibility, shape)
    if heights is not None:
        h = _bands("heights", heights, shape)[0]
        error = h - _bands("truth", truth, shape)[0]
        if not np.isfinite(error).any():
            raise InputError("no post has both a height and a truth height")
        return "error", error
    return "relief", None


def _ortho_colours(bands: np.ndarray) -> np.ndarray:
    """Per-post RGB (rows*cols, 3) uint8 of a 1- or 3-band orthophoto, NaN posts dark grey."""
    if len(bands) == 2:
        raise InputError("the orthophoto must have 1 band (grey) or 3 or more (RGB), not 2")
    rgb = np.moveaxis(bands[:3], 0, -1).reshape(-1, min(len(bands), 3))
    filled = np.isfinite(rgb).all(axis=1)
    if not filled.any():
        raise InputError("the orthophoto holds no valid values")
    lo, hi = np.percentile(rgb[filled], [1, 99])
    scaled = np.clip((rgb - lo) / max(hi - lo, 1e-12), 0, 1) * 255
    out = np.broadcast_to(np.where(filled[:, None], scaled, 0), (len(rgb), 3)).astype(np.uint8)
    out[~filled] = NAN_COLOUR
    return out


def _check_options(
    view: str,
    view_camera: int,
    n_cameras: int,
    rays: int,
    elevation: float,
    exaggerate: float,
    size: tuple[int, int] | None,
) -> None:
    if view not in VIEWS:
        raise InputError(f"unknown view {view!r}; choose one of {', '.join(VIEWS)}")
    if view == "from-camera" and not 0 <= view_camera < n_cameras:
        raise InputError(
            f"the from-camera view needs camera {view_camera} (0-based) but {n_cameras} "
            f"camera{'s were' if n_cameras != 1 else ' was'} given"
        )
    if rays < 0:
        raise InputError(f"the number of rays must be >= 0, got {rays}")
    if not 0 < elevation <= 90:
        raise InputError(f"the view elevation must be in (0, 90] degrees, got {elevation}")
    if not (np.isfinite(exaggerate) and exaggerate > 0):
        raise InputError(f"vertical exaggeration must be positive, got {exaggerate}")
    if size is not None and not all(16 <= int(n) <= 8192 for n in size):
        raise InputError(f"snapshot size must be 16 to 8192 pixels a side, got {size}")


# ----------------------------------------------------------------------------- geometry
def _grid_frame(terrain: Terrain, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit 'up' at ``origin`` and 'grid north' (towards row 0, made horizontal), world frame."""
    up = terrain.up_vectors(origin)
    rows, cols = terrain.shape
    c, r = (cols - 1) / 2, (rows - 1) / 2
    h = np.full(2, np.nanmedian(terrain.values))
    ends = terrain.to_world(np.array([c, c]), np.array([r + 1, r - 1]), h)
    north = ends[1] - ends[0]
    north -= (north @ up) * up
    return up, north / np.linalg.norm(north)


def _image_rect(camera: PinholeCamera, tmesh: TerrainMesh) -> tuple[float, float, float, float]:
    """(u0, v0, u1, v1): the image's outer pixel edges, or, without an image size, the pixel
    rectangle that holds the DEM's projection."""
    if camera.width is not None and camera.height is not None:
        return -0.5, -0.5, camera.width - 0.5, camera.height - 0.5
    verts = tmesh.world_vertices
    uv, _ = camera.project(verts[:: max(1, len(verts) // 20000)])
    uv = uv[np.isfinite(uv).all(axis=1)]
    if not len(uv):
        raise InputError("a camera without an image size does not see the DEM at all")
    (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
    return float(u0), float(v0), float(u1), float(v1)


def _pixel_tangents(camera: PinholeCamera, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, ...]:
    """Tangents of the angles right of and below the optical axis of pixels (u, v) (no lens
    distortion)."""
    return (u * camera.pitch - camera.cu) / camera.fu, (v * camera.pitch - camera.cv) / camera.fv


# ------------------------------------------------------------------------------ drawing
def _plotter(width: int, height: int) -> pv.Plotter:
    """An offscreen Plotter with the snapshot background and no default lights."""
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
    poly = pv.PolyData.from_regular_faces(
        np.asarray(shown.mesh.vertices), np.asarray(shown.mesh.faces)
    )
    poly.point_data["Normals"] = np.asarray(shown.mesh.vertex_normals)
    poly.point_data.active_normals_name = "Normals"
    material = {"ambient": 0.3, "diffuse": 0.8, "specular": 0.0, "interpolation": "gouraud"}
    kind, data = colouring
    post = shown.vertex_post
    if kind == "relief":
        plotter.add_mesh(poly, color=VIS_RGB[Code.VISIBLE], **material)
    elif kind == "ortho":  # the orthophoto has its own shading: light it less
        material.update(ambient=0.55, diffuse=0.5)
        plotter.add_mesh(poly, scalars=data[post], rgb=True, **material)
    elif kind == "visibility":
        codes = data.ravel()[post]
        plotter.add_mesh(poly, scalars=vis_palette()[codes], rgb=True, **material)
        if legend:
            labels = [
                [
                    f"{Code(k).label}: {100 * np.mean(codes == k):.1f}%",
                    np.array(VIS_RGB[k]) / 255,
                ]
                for k in (Code.VISIBLE, Code.OCCLUDED, Code.FACING_AWAY, Code.NODATA)
            ]
            box = plotter.add_legend(labels, bcolor=(0.1, 0.1, 0.12), face="rectangle")
            box.SetPosition(0.69, 0.79)  # upper right: lower-left corner, viewport fractions
            box.SetPosition2(0.3, 0.2)
    else:
        font = max(10, plotter.window_size[1] // 40)
        plotter.add_mesh(
            poly,
            scalars=data.ravel()[post],
            cmap="RdBu_r",
            clim=(-error_limit, error_limit) if error_limit else _symmetric_limit(data),
            nan_color=np.array(NAN_COLOUR) / 255,
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


def _symmetric_limit(error: np.ndarray) -> tuple[float, float]:
    """Colour limits +-a, a the 99th percentile of |error| (at least 1 mm)."""
    a = max(float(np.nanpercentile(np.abs(error), 99)), 1e-3)
    return -a, a


@dataclass
class _Glyph:
    """A camera's frustum glyph in the local frame: ``points`` (apex, 4 image corners, end of
    the optical axis) and the true camera centre ``centre``."""

    points: np.ndarray
    centre: np.ndarray

    @property
    def far(self) -> bool:
        """True when the glyph stands in for a camera elsewhere."""
        return not np.array_equal(self.points[0], self.centre)


def _glyph(
    camera: PinholeCamera,
    rect: tuple[float, float, float, float],
    origin: np.ndarray,
    centre: np.ndarray,
    radius: float,
) -> _Glyph:
    """The frustum glyph of a camera (see :func:`snapshot`); ``centre`` and ``radius``
    describe the DEM's bounding sphere in the local frame."""
    c = camera.center - origin
    offset = c - centre
    dist = float(np.linalg.norm(offset))
    apex = (
        c if dist <= GLYPH_DISTANCE * radius else centre + offset * (GLYPH_DISTANCE * radius / dist)
    )
    a = camera.world_to_image_axes  # rows: image u, v, w axes in the world frame
    u0, v0, u1, v1 = rect
    tu, tv = _pixel_tangents(camera, np.array([u0, u1, u1, u0]), np.array([v0, v0, v1, v1]))
    # A far camera's true frustum is a needle: widen the rectangle about its centre until its
    # half-size is at least GLYPH_OPENING.
    cu, cv = (tu[0] + tu[1]) / 2, (tv[0] + tv[2]) / 2
    scale = max(1.0, GLYPH_OPENING / max(abs(tu[1] - cu), abs(tv[2] - cv)))
    tu, tv = cu + scale * (tu - cu), cv + scale * (tv - cv)
    depth = GLYPH_SIZE * radius
    corners = apex + depth * (tu[:, None] * a[0] + tv[:, None] * a[1] + a[2])
    return _Glyph(np.vstack([apex, corners, apex + 1.6 * depth * a[2]]), c)


def _add_camera(plotter: pv.Plotter, glyph: _Glyph, colour: str, label: str) -> None:
    """Draw a camera glyph: frustum, optical axis, label, and a line towards a far camera."""
    lines = [[2, 0, k] for k in range(1, 5)] + [[5, 1, 2, 3, 4, 1], [2, 0, 5]]
    frustum = pv.PolyData(glyph.points, lines=np.concatenate(lines))
    plotter.add_mesh(frustum, color=colour, line_width=2, lighting=False)
    if glyph.far:
        tether = pv.Line(glyph.points[0], glyph.centre)
        plotter.add_mesh(tether, color=colour, line_width=1, opacity=0.5, lighting=False)
    plotter.add_point_labels(
        glyph.points[:1],
        [label],
        text_color=colour,
        font_size=max(10, plotter.window_size[1] // 45),
        shape=None,
        show_points=False,
        always_visible=True,
    )


def _add_rays(
    plotter: pv.Plotter,
    camera: PinholeCamera,
    rect: tuple[float, float, float, float],
    n: int,
    tmesh: TerrainMesh,
    shown: TerrainMesh,
    colour: str,
) -> None:
    """Draw ``n`` rays through pixels spread over ``rect`` (an R2 low-discrepancy sequence) to
    their first hits on the true mesh, drawn on the shown (exaggerated) one; misses are left
    out."""
    g = 1.32471795724474602596  # plastic number: R2 sequence step (1/g, 1/g^2)
    k = np.arange(n)
    fu, fv = (0.5 + k / g) % 1.0, (0.5 + k / g**2) % 1.0
    u0, v0, u1, v1 = rect
    uv = np.column_stack([u0 + (0.03 + 0.94 * fu) * (u1 - u0), v0 + (0.03 + 0.94 * fv) * (v1 - v0)])
    origins, dirs = camera.ray(uv)
    hits = RayCaster(tmesh, threads=1).first_hit(origins, dirs)
    if not hits.mask.any():
        return
    tri = np.asarray(shown.mesh.faces)[hits.triangle[hits.mask]]
    b = hits.barycentric[hits.mask]
    v = np.asarray(shown.mesh.vertices)
    ends = (
        (1 - b.sum(axis=1))[:, None] * v[tri[:, 0]]
        + b[:, :1] * v[tri[:, 1]]
        + b[:, 1:] * v[tri[:, 2]]
    )
    start = camera.center - tmesh.origin
    m = len(ends)
    points = np.vstack([start, ends])
    lines = np.column_stack([np.full(m, 2), np.zeros(m, int), np.arange(1, m + 1)]).ravel()
    plotter.add_mesh(
        pv.PolyData(points, lines=lines), color=colour, line_width=1, opacity=0.8, lighting=False
    )
    plotter.add_points(
        ends, color=colour, point_size=6, render_points_as_spheres=True, lighting=False
    )


def _add_light(plotter: pv.Plotter, centre: np.ndarray, up: np.ndarray) -> None:
    """A directional light from the image's upper left, ``LIGHT_ELEVATION`` above the horizon."""
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


# -------------------------------------------------------------------------------- views
def _default_azimuth(
    glyphs: list[_Glyph], centre: np.ndarray, up: np.ndarray, north: np.ndarray
) -> float:
    """Viewer azimuth, degrees clockwise from grid north: opposite the first camera (210 when
    there is none or it looks straight down)."""
    if glyphs:
        to_cam = glyphs[0].centre - centre
        e, n = to_cam @ np.cross(north, up), to_cam @ north
        if np.hypot(e, n) > 1e-3 * np.linalg.norm(to_cam):
            return float(np.degrees(np.arctan2(e, n)) + 180.0)
    return 210.0


def _view_dem(
    plotter: pv.Plotter,
    view: str,
    points: np.ndarray,
    centre: np.ndarray,
    up: np.ndarray,
    north: np.ndarray,
    azimuth: float,
    elevation: float,
) -> None:
    """Look at ``centre`` in an oblique or a top view that just holds ``points`` (the DEM and
    the camera glyphs, not far cameras themselves)."""
    east = np.cross(north, up)
    width, height = plotter.window_size
    aspect = width / height
    if view == "top":
        fwd, screen_up = -up, north
    else:
        az, el = np.radians(azimuth), np.radians(elevation)
        fwd = -(np.cos(el) * (np.sin(az) * east + np.cos(az) * north) + np.sin(el) * up)
        screen_up = up
    right = np.cross(fwd, screen_up)
    right /= np.linalg.norm(right)
    screen_up = np.cross(right, fwd)
    p = points - centre
    x, y, z = p @ right, p @ screen_up, p @ fwd
    cam = plotter.camera
    margin = 1.08
    if view == "top":
        cam.enable_parallel_projection()
        cam.parallel_scale = margin * max(np.abs(y).max(), np.abs(x).max() / aspect)
        dist = 2.0 * float(np.abs(p).max()) + 1.0
    else:
        tan_v = np.tan(np.radians(VIEW_ANGLE) / 2) / margin
        cam.view_angle = VIEW_ANGLE
        dist = float(np.max(np.maximum(np.abs(x) / (tan_v * aspect), np.abs(y) / tan_v) - z))
    cam.focal_point = centre
    cam.position = centre - dist * fwd
    cam.up = screen_up


def _view_from_camera(
    plotter: pv.Plotter,
    camera: PinholeCamera,
    rect: tuple[float, float, float, float],
    origin: np.ndarray,
) -> None:
    """Look through ``camera``: its centre, axis, image 'up' (-v) and the field of view of
    ``rect``, whose centre is put at the middle of the snapshot."""
    a = camera.world_to_image_axes
    u0, v0, u1, v1 = rect
    (tl, tr), (tt, tb) = _pixel_tangents(camera, np.array([u0, u1]), np.array([v0, v1]))
    half = (tb - tt) / 2  # tangent of half the vertical field of view
    width, height = plotter.window_size
    cam = plotter.camera
    c = camera.center - origin
    cam.position = c
    cam.focal_point = c + a[2]
    cam.up = -a[1]
    cam.view_angle = float(np.degrees(2 * np.arctan(half)))
    # Shift the projection so that the rectangle's centre (off the optical axis when the
    # principal point is off-centre) lands in the middle of the snapshot.
    cam.SetWindowCenter((tl + tr) / 2 / (half * width / height), -(tt + tb) / 2 / half)
