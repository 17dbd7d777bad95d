"""Orbital line-scan (pushbroom) cameras over a DEM: a USGS CSM line scanner on a circular
orbit, its attitude fixed in the orbit frame, looking across track at a given emission angle.

The sensor flies perpendicular to the view's azimuth (for azimuth 270, a camera west of the
tile looking east, it flies from north to south); one image line is exposed per
``gsd / ground speed`` seconds, so pixels are about ``gsd`` metres square at the tile centre.
"""

from __future__ import annotations

import numpy as np

from orthomvp.camera.csm import CsmDistortion, LineScanCamera
from orthomvp.camera.csm.ephemeris import matrix_wxyz
from orthomvp.camera.csm.geometry import Ellipsoid, FocalPlane, Trajectory
from orthomvp.geometry.terrain import Terrain
from orthomvp.synthetic.cameras import ViewSpec
from orthomvp.synthetic.surface import MOON_RADIUS, local_frame

GM_MOON = 4.9028e12
"""The Moon's gravitational parameter, m^3/s^2 (sets the orbital speed)."""
PIXEL_PITCH = 0.01
"""Detector pixel pitch, mm."""
NODES = 41
"""Ephemeris and pointing nodes over the image's time span and its margins."""
NODE_MARGIN = 4
"""Nodes before the first and after the last line, so that every line's states are
interpolated with the full Lagrange order."""
VIEWS = (ViewSpec("linescan", 55.0, 200.0),)
"""The line-scan views of ``orthomvp synth KIND --sensor linescan``: the geometry of the
crater's oblique frame at the centre line."""


def _orbit(
    c0: np.ndarray, along: np.ndarray, look: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions, velocities (m, m/s) and camera-to-body quaternions (x, y, z, w) at times
    ``t`` (s) of the circular orbit through ``c0`` (at t = 0) heading ``along``, the camera's
    axis pointing along ``look`` at t = 0 and its y axis (image lines) along track."""
    r = float(np.linalg.norm(c0))
    chat = c0 / r
    along = along - (along @ chat) * chat
    along /= np.linalg.norm(along)
    omega = np.sqrt(GM_MOON / r**3)
    pole = np.cross(chat, along)
    a = omega * t
    pos = r * (np.cos(a)[:, None] * chat + np.sin(a)[:, None] * along)
    vel = r * omega * (-np.sin(a)[:, None] * chat + np.cos(a)[:, None] * along)
    y0 = along - (along @ look) * look
    y0 /= np.linalg.norm(y0)
    r0 = np.column_stack([np.cross(y0, look), y0, look])
    quats = []
    for angle in a:  # the attitude turns with the orbit, about its pole
        k = np.array([[0, -pole[2], pole[1]], [pole[2], 0, -pole[0]], [-pole[1], pole[0], 0]])
        turn = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)
        q = matrix_wxyz(turn @ r0)
        if quats and q @ quats[-1] < 0:  # continuous signs for the interpolation
            q = -q
        quats.append(q)
    return pos, vel, np.array(quats)[:, [1, 2, 3, 0]]


def orbital_line_scanner(
    terrain: Terrain, view: ViewSpec, gsd: float, margin: float = 6.0
) -> LineScanCamera:
    """A line scanner placed as ``view`` says over the centre of a body-frame ``terrain``
    (its sensor at the view's emission angle, azimuth and altitude when it images the centre,
    at the median height), with ground sample distance ``gsd`` metres there and an image just
    large enough (plus ``margin`` pixels) to hold the whole DEM."""
    rows, cols = terrain.shape
    up, east, north = local_frame(
        *terrain.pixel_to_lonlat(np.array((cols - 1) / 2), np.array((rows - 1) / 2))
    )
    heights = terrain.values[terrain.valid]
    target = (terrain.radii[0] + float(np.median(heights))) * up
    em, az = np.radians(view.emission), np.radians(view.azimuth)
    horiz = np.sin(az) * east + np.cos(az) * north
    dist = view.altitude / np.cos(em)
    c0 = target + dist * (np.sin(em) * horiz + np.cos(em) * up)
    look = (target - c0) / dist
    along = np.cross(horiz, up)
    omega = np.sqrt(GM_MOON / np.linalg.norm(c0) ** 3)
    pole = np.cross(c0, along)
    pole /= np.linalg.norm(pole)
    speed = omega * np.linalg.norm(target - (target @ pole) * pole)  # of the footprint
    period = gsd / speed  # seconds per line
    f_pixels = dist / gsd

    def camera(first: float, lines: int, samples: int, sample_origin: float) -> LineScanCamera:
        span = lines * period
        step = span / (NODES - 1 - 2 * NODE_MARGIN)
        t0 = first - NODE_MARGIN * step
        pos, vel, quats = _orbit(c0, along, look, t0 + step * np.arange(NODES))
        plane = FocalPlane(
            focal_length=f_pixels * PIXEL_PITCH,
            i_trans_s=np.array([0.0, 1.0 / PIXEL_PITCH, 0.0]),
            i_trans_l=np.array([0.0, 0.0, 1.0 / PIXEL_PITCH]),
            sample_origin=sample_origin,
            line_origin=0.0,
            sample_summing=1.0,
            line_summing=1.0,
            starting_sample=0.0,
            starting_line=0.0,
            distortion=CsmDistortion("radial", np.zeros(3)),
        )
        return LineScanCamera(
            lines,
            samples,
            focal_plane=plane,
            ellipsoid=Ellipsoid(MOON_RADIUS, MOON_RADIUS),
            trajectory=Trajectory(pos, vel, t0, step, quats, t0, step),
            int_time_lines=np.array([0.5]),
            int_time_start_times=np.array([first]),
            int_times=np.array([period]),
        )

    # a provisional camera three times the tile's size, centred on it, finds the image's extent
    extent = 3 * int(np.ceil(max(rows, cols) * np.mean(terrain.post_spacing()) / gsd))
    probe = camera(-extent / 2 * period, extent, extent, extent / 2)
    c = np.concatenate([np.arange(cols), np.full(rows, cols - 1), np.arange(cols), np.zeros(rows)])
    r = np.concatenate([np.zeros(cols), np.arange(rows), np.full(cols, rows - 1), np.arange(rows)])
    edge = np.concatenate([c, c]).astype(float), np.concatenate([r, r]).astype(float)
    h = np.repeat([heights.min(), heights.max()], len(c))
    uv, _ = probe.project(terrain.to_world(*edge, h))
    lo, hi = np.nanmin(uv, axis=0) - margin, np.nanmax(uv, axis=0) + margin
    samples, lines = (int(np.ceil(v)) for v in hi - lo)
    first = float(probe.image_time(np.array(lo[1])))  # new CSM line 0 = the probe's line lo[1]
    return camera(first, lines, samples, extent / 2 - lo[0])
