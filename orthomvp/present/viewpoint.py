"""Where things stand in a 3D snapshot: the DEM's local up and grid north, camera glyphs
(frusta), and the viewer's placement for the oblique, top and from-camera views.

Positions are in the snapshot's local frame (world metres minus the mesh origin, see
:mod:`orthomvp.present.snapshot`); angles in degrees. The functions set a VTK camera (a pyvista
Plotter's ``camera``) but import no plotting library themselves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera import Camera, PinholeCamera
from orthomvp.codes import View
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.mesh import TerrainMesh

if TYPE_CHECKING:
    import pyvista as pv

VIEW_ANGLE = 30.0  # vertical field of view of the oblique view, degrees
GLYPH_DISTANCE = 1.2  # far cameras are drawn this many DEM radii from the DEM centre
GLYPH_SIZE = 0.25  # depth of a camera glyph, in DEM radii
GLYPH_OPENING = 0.4  # least half-size of a camera glyph's image rectangle (tangent)
Rect = tuple[float, float, float, float]
"""(u0, v0, u1, v1): a camera's pixel rectangle, outer pixel edges."""


def grid_frame(terrain: Terrain, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit 'up' at ``origin`` and 'grid north' (towards row 0, made horizontal), world frame."""
    up = terrain.up_vectors(origin)
    rows, cols = terrain.shape
    c, r = (cols - 1) / 2, (rows - 1) / 2
    h = np.full(2, np.nanmedian(terrain.values))
    ends = terrain.to_world(np.array([c, c]), np.array([r + 1, r - 1]), h)
    north = ends[1] - ends[0]
    north -= (north @ up) * up
    return up, north / np.linalg.norm(north)


def image_rect(camera: Camera, tmesh: TerrainMesh, name: str = "the camera") -> Rect:
    """The image's outer pixel edges, or, without an image size, the pixel rectangle that holds
    the projection of ``tmesh``; InputError naming ``name`` and the cause when the camera
    does not see the DEM at all."""
    if camera.width is not None and camera.height is not None:
        return -0.5, -0.5, camera.width - 0.5, camera.height - 0.5
    verts = tmesh.world_vertices
    uv, depth = camera.project(verts[:: max(1, len(verts) // 20000)])
    uv = uv[np.isfinite(uv).all(axis=1)]
    if not (depth > 0).any():
        raise InputError(
            f"{name} looks away from the DEM: every post is behind it (check its rotation, or "
            "that it belongs to this DEM)"
        )
    if not len(uv):
        raise InputError(f"{name} does not see the DEM: no post projects through its lens model")
    (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
    return float(u0), float(v0), float(u1), float(v1)


def pixel_tangents(camera: PinholeCamera, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, ...]:
    """Tangents of the angles right of and below the optical axis of pixels (u, v) (no lens
    distortion)."""
    return (u * camera.pitch - camera.cu) / camera.fu, (v * camera.pitch - camera.cv) / camera.fv


@dataclass
class Glyph:
    """A camera's frustum glyph in the local frame: ``points`` (apex, 4 image corners, end of
    the optical axis) and the true camera centre ``centre``."""

    points: np.ndarray
    centre: np.ndarray

    @property
    def far(self) -> bool:
        """True when the glyph stands in for a camera elsewhere."""
        return not np.array_equal(self.points[0], self.centre)


def camera_glyph(
    camera: Camera,
    rect: Rect,
    origin: np.ndarray,
    centre: np.ndarray,
    radius: float,
) -> Glyph:
    """The frustum glyph of a camera: apex at the camera, or, for a camera farther than
    ``GLYPH_DISTANCE`` DEM radii from the DEM centre, at that distance on its line of sight to
    the centre; image rectangle ``GLYPH_SIZE`` radii deep, widened to at least ``GLYPH_OPENING``
    (a tangent) a side. ``origin`` is the local frame's origin (world); ``centre`` and
    ``radius`` describe the DEM's bounding sphere in the local frame."""
    if not isinstance(camera, PinholeCamera):
        return _ray_glyph(camera, rect, origin, centre, radius)
    c = camera.center - origin
    offset = c - centre
    dist = float(np.linalg.norm(offset))
    apex = (
        c if dist <= GLYPH_DISTANCE * radius else centre + offset * (GLYPH_DISTANCE * radius / dist)
    )
    a = camera.world_to_image_axes  # rows: image u, v, w axes in the world frame
    u0, v0, u1, v1 = rect
    tu, tv = pixel_tangents(camera, np.array([u0, u1, u1, u0]), np.array([v0, v0, v1, v1]))
    # A far camera's true frustum is a needle: widen the rectangle about its centre until its
    # half-size is at least GLYPH_OPENING.
    cu, cv = (tu[0] + tu[1]) / 2, (tv[0] + tv[2]) / 2
    scale = max(1.0, GLYPH_OPENING / max(abs(tu[1] - cu), abs(tv[2] - cv)))
    tu, tv = cu + scale * (tu - cu), cv + scale * (tv - cv)
    depth = GLYPH_SIZE * radius
    corners = apex + depth * (tu[:, None] * a[0] + tv[:, None] * a[1] + a[2])
    return Glyph(np.vstack([apex, corners, apex + 1.6 * depth * a[2]]), c)


def _ray_glyph(
    camera: Camera, rect: Rect, origin: np.ndarray, centre: np.ndarray, radius: float
) -> Glyph:
    """The glyph of a camera without one centre (a line scanner, RPC) from its own rays: apex
    at the mean ray origin of the image's corners and centre (moved in as for a far frame
    camera), corners along the corner rays, axis along the centre's ray, widened to at least
    ``GLYPH_OPENING``; the drawing of :func:`camera_glyph` stands for the whole sensor path."""
    u0, v0, u1, v1 = rect
    uv = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1], [(u0 + u1) / 2, (v0 + v1) / 2]])
    uv = np.clip(uv, [u0 + 0.5, v0 + 0.5], [u1 - 0.5, v1 - 0.5])  # outer pixel centres
    starts, dirs = camera.ray(uv)
    if not np.isfinite(dirs).all():
        raise InputError("a camera without rays at its image corners cannot be drawn")
    c = starts.mean(axis=0) - origin
    offset = c - centre
    dist = float(np.linalg.norm(offset))
    apex = (
        c if dist <= GLYPH_DISTANCE * radius else centre + offset * (GLYPH_DISTANCE * radius / dist)
    )
    axis = dirs[4] / np.linalg.norm(dirs[4])
    tangent = dirs[:4] / (dirs[:4] @ axis)[:, None] - axis  # offsets at unit depth
    scale = max(1.0, GLYPH_OPENING / float(np.abs(tangent).max()))
    depth = GLYPH_SIZE * radius
    corners = apex + depth * (axis + scale * tangent)
    return Glyph(np.vstack([apex, corners, apex + 1.6 * depth * axis]), c)


def default_azimuth(
    glyphs: list[Glyph], centre: np.ndarray, up: np.ndarray, north: np.ndarray
) -> float:
    """Viewer azimuth, degrees clockwise from grid north: opposite the first camera (210 when
    there is none or it looks straight down)."""
    if glyphs:
        to_cam = glyphs[0].centre - centre
        e, n = to_cam @ np.cross(north, up), to_cam @ north
        if np.hypot(e, n) > 1e-3 * np.linalg.norm(to_cam):
            return float(np.degrees(np.arctan2(e, n)) + 180.0)
    return 210.0


def view_dem(
    plotter: pv.Plotter,
    view: View,
    points: np.ndarray,
    centre: np.ndarray,
    up: np.ndarray,
    north: np.ndarray,
    azimuth: float,
    elevation: float,
) -> None:
    """Look at ``centre`` in an oblique view (from ``azimuth`` degrees clockwise from grid
    north, ``elevation`` degrees up) or a top view (grid north up, orthographic) that just holds
    ``points`` (the DEM and the camera glyphs, not far cameras themselves)."""
    east = np.cross(north, up)
    width, height = plotter.window_size
    aspect = width / height
    if view == View.TOP:
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
    if view == View.TOP:
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


def frame_view(
    camera: Camera, rect: Rect
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[float, float, float, float]]:
    """Where ``camera``, a frame camera (one centre), looks through ``rect``: its centre, image
    right (+u), down (+v) and axis (unit vectors, world), and the tangents (left, right, top,
    bottom) of ``rect``'s edges at unit depth. A pinhole camera gives them from its model; a
    CSM or ISIS frame camera its centre and axis (``boresight``) from its model, its image axes
    and field of view from its rays through ``rect``'s edges' midpoints (lens distortion
    ignored in both). InputError for rays that fail, or an image mirrored against its axis
    (v not along axis x u), which a view cannot show."""
    u0, v0, u1, v1 = rect
    if isinstance(camera, PinholeCamera):
        a = camera.world_to_image_axes
        (tl, tr), (tt, tb) = pixel_tangents(camera, np.array([u0, u1]), np.array([v0, v1]))
        return camera.center, a[0], a[1], a[2], (tl, tr, tt, tb)
    um, vm = (u0 + u1) / 2, (v0 + v1) / 2
    starts, dirs = camera.ray(np.array([[u0, vm], [u1, vm], [um, v0], [um, v1]]))
    if not np.isfinite(dirs).all():
        raise InputError("the from-camera view needs the camera's rays at its image edges")
    axis = camera.boresight
    t = dirs / (dirs @ axis)[:, None] - axis  # offsets on the image plane at unit depth
    right = (t[1] - t[0]) / np.linalg.norm(t[1] - t[0])
    down = np.cross(axis, right)  # image u x v = w
    if float((t[3] - t[2]) @ down) <= 0:
        raise InputError(
            "the from-camera view cannot show this camera: its image is mirrored (its lines "
            "run against boresight x samples); choose another --view"
        )
    (tl, tr), (tt, tb) = t[:2] @ right, t[2:] @ down
    return starts[0], right, down, axis, (float(tl), float(tr), float(tt), float(tb))


def view_from_camera(
    plotter: pv.Plotter,
    camera: Camera,
    rect: Rect,
    origin: np.ndarray,
) -> None:
    """Look through ``camera``, a frame camera (one centre): its centre, axis, image 'up' (-v)
    and the field of view of ``rect`` (:func:`frame_view`), whose centre is put at the middle
    of the snapshot."""
    centre, right, down, axis, (tl, tr, tt, tb) = frame_view(camera, rect)
    half = (tb - tt) / 2  # tangent of half the vertical field of view
    width, height = plotter.window_size
    cam = plotter.camera
    c = centre - origin
    cam.position = c
    cam.focal_point = c + axis
    cam.up = -down
    cam.view_angle = float(np.degrees(2 * np.arctan(half)))
    # Shift the projection so that the rectangle's centre (off the optical axis when the
    # principal point is off-centre) lands in the middle of the snapshot.
    cam.SetWindowCenter((tl + tr) / 2 / (half * width / height), -(tt + tb) / 2 / half)
