"""The USGS CSM line scanner (``USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL``), vectorised.

Each image line is exposed at its own time (``line_scan_rate``: piecewise-constant line
durations), from the sensor position and pointing interpolated there (usgscsm's Lagrange
polynomials of order 8 on uniform nodes). Ground to image solves for the line by usgscsm's
secant iteration, for all points at once; points whose line falls outside the image (no
exposure time there) get NaN, never an extrapolated pixel.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from orthomvp.camera.csm.geometry import (
    CHUNK,
    EDGE,
    CsmImage,
    Ellipsoid,
    FocalPlane,
    Trajectory,
    as_points,
)
from orthomvp.errors import InputError

MODEL_NAME = "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL"
PRECISION = 1e-6
"""usgscsm's desired precision of ground to image, lines."""
_MAX_SECANT = 15  # usgscsm's iteration limit
_CONVERGED = 1e-3  # lines: a larger final correction means the iteration failed (NaN)
_MAX_POLISH = 4  # exact Newton steps after the table's iteration (one suffices on orbits)
_POLISH_MARGIN = 0.5  # lines beyond the image where a table solution is still polished
GSD_LINES = 0.05
"""Lines to which :meth:`LineScanCamera.gsd` finds where a point is imaged (the range changes
by far less than a pixel over them)."""
TABLE_KNOTS = 1024
"""Fewest knots of the sensor-state table (one per line for longer images)."""


@dataclass(frozen=True, eq=False)
class LineScanCamera(CsmImage):
    """A USGS CSM line-scan camera (conventions in :mod:`orthomvp.camera.csm.geometry`).

    ``int_time_lines``, ``int_time_start_times``, ``int_times``: the ISD's ``line_scan_rate``
    rows (first CSM line of a segment, its start time in seconds relative to ``center_time``,
    seconds per line); the time of CSM line L in segment i is start_i + dt_i (L - line_i + 0.5).
    ``center_time``: the ISD's ``center_ephemeris_time`` (ephemeris seconds).
    """

    focal_plane: FocalPlane
    ellipsoid: Ellipsoid
    trajectory: Trajectory
    int_time_lines: np.ndarray
    int_time_start_times: np.ndarray
    int_times: np.ndarray
    center_time: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        arrays = [
            np.asarray(getattr(self, n), dtype=np.float64).ravel()
            for n in ("int_time_lines", "int_time_start_times", "int_times")
        ]
        if len({a.size for a in arrays}) != 1 or arrays[0].size == 0:
            raise InputError("line_scan_rate rows must each hold 3 numbers")
        if not all(np.isfinite(a).all() for a in arrays) or not (arrays[2] > 0).all():
            raise InputError("line_scan_rate must be finite, with positive line durations")
        for name, a in zip(
            ("int_time_lines", "int_time_start_times", "int_times"), arrays, strict=True
        ):
            object.__setattr__(self, name, a)
        first, last = self.image_time(np.array([0.0, float(self.lines)]))
        lo, hi = self.trajectory.time_range
        # usgscsm extrapolates; its own test ISDs start half a line before the first node
        slack = max(self.trajectory.dt_ephem, self.trajectory.dt_quat)
        if min(first, last) < lo - slack or max(first, last) > hi + slack:
            raise InputError(
                f"the image's times [{min(first, last):.6g}, {max(first, last):.6g}] s lie outside "
                f"the ephemeris [{lo:.6g}, {hi:.6g}] s"
            )

    # --- usgscsm's functions, CSM image coordinates --------------------------------------------
    def image_time(self, line: np.ndarray) -> np.ndarray:
        """Exposure times (s, relative to ``center_time``) of CSM lines (``getImageTime``)."""
        line = np.asarray(line, dtype=np.float64)
        i = np.clip(np.searchsorted(self.int_time_lines, line, side="right") - 1, 0, None)
        return self.int_time_start_times[i] + self.int_times[i] * (
            line - self.int_time_lines[i] + 0.5
        )

    def sensor_position(self, line: np.ndarray) -> np.ndarray:
        """Sensor positions (..., 3), metres, at the times of CSM lines."""
        t = self.image_time(line)
        return self.trajectory.position(t.ravel()).reshape(t.shape + (3,))

    def sensor_velocity(self, line: np.ndarray) -> np.ndarray:
        """Sensor velocities (..., 3), m/s, at the times of CSM lines."""
        t = self.image_time(line)
        return self.trajectory.velocity(t.ravel()).reshape(t.shape + (3,))

    def _valid_line(self, line: np.ndarray) -> np.ndarray:
        return (line >= -EDGE) & (line <= self.lines + EDGE)

    @cached_property
    def look_sign(self) -> int:
        """+1 if usgscsm's locus direction points into the scene, -1 if away (see
        :mod:`orthomvp.camera.csm.geometry`)."""
        origin, direction = self.csm_locus(np.array(self.lines / 2.0), np.array(self.samples / 2.0))
        return self._look_sign(origin, direction)

    def csm_locus(self, line: np.ndarray, sample: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor positions and unit look directions (..., 3) of CSM (line, sample) (usgscsm
        ``imageToRemoteImagingLocus``); NaN where the line is outside the image."""
        line, sample = np.broadcast_arrays(
            np.asarray(line, np.float64), np.asarray(sample, np.float64)
        )
        t = self.image_time(line).ravel()
        look = self.focal_plane.camera_look(np.zeros_like(t), sample.ravel())
        direction = np.einsum("mij,mj->mi", self.trajectory.rotation(t), look)
        origin = self.trajectory.position(t)
        bad = ~self._valid_line(line.ravel())
        origin[bad], direction[bad] = np.nan, np.nan
        return origin.reshape(line.shape + (3,)), direction.reshape(line.shape + (3,))

    def csm_image_to_ground(
        self, line: np.ndarray, sample: np.ndarray, height: np.ndarray | float = 0.0
    ) -> np.ndarray:
        """Ground points (..., 3), metres, of CSM (line, sample) on the ellipsoid inflated by
        ``height`` metres (usgscsm ``imageToGround``); NaN where the ray misses it."""
        origin, direction = self.csm_locus(line, sample)
        return self.ellipsoid.intersect(
            origin, self.look_sign * direction, np.broadcast_to(height, origin.shape[:-1])
        )

    def _line_error(
        self, line: np.ndarray, xyz: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """usgscsm ``calcDetectorLineErr``: the detector line offset at which ``xyz`` (M, 3)
        appears when seen at the time of CSM ``line`` (M,), the distorted focal-plane x, y
        and the camera-frame depth."""
        t = self.image_time(line)
        rel = xyz - self.trajectory.position(t)
        cam = np.einsum("mji,mj->mi", self.trajectory.rotation(t), rel)
        dx, dy = self.focal_plane.view(cam)
        return (
            self.focal_plane.detector_line(dx, dy),
            np.stack([dx, dy], -1),
            self.look_sign * cam[:, 2],
        )

    @cached_property
    def _table(self) -> tuple[float, np.ndarray]:
        """Sensor states sampled along the image for ground to image: the knot spacing in
        CSM lines (one line, finer for images of fewer than :data:`TABLE_KNOTS` lines) and the
        positions (metres) and camera-to-body rotations (row-major) at the knots, (knots, 12)."""
        step = min(1.0, self.lines / TABLE_KNOTS)
        knots = np.linspace(0.0, float(self.lines), round(self.lines / step) + 1)
        t = self.image_time(knots)
        states = np.hstack(
            [self.trajectory.position(t), self.trajectory.rotation(t).reshape(-1, 9)]
        )
        return float(knots[1] - knots[0]), states

    def _table_error(self, line: np.ndarray, xyz: np.ndarray) -> np.ndarray:
        """:meth:`_line_error`'s detector line offset (M,) with the sensor state interpolated
        linearly between the knots of :attr:`_table` (extrapolated beyond the image)."""
        step, states = self._table
        x = line / step
        k = np.clip(np.floor(np.nan_to_num(x)), 0, len(states) - 2).astype(np.int64)
        lo = states[k]
        s = lo + (x - k)[:, None] * (states[k + 1] - lo)
        rel = xyz - s[:, :3]
        cam = [
            s[:, 3 + i] * rel[:, 0] + s[:, 6 + i] * rel[:, 1] + s[:, 9 + i] * rel[:, 2]
            for i in range(3)
        ]
        dx, dy = self.focal_plane.view(np.stack(cam, -1))
        return self.focal_plane.detector_line(dx, dy)

    @cached_property
    def _first_guess(self) -> tuple[np.ndarray, float] | None:
        """The line as an affine function of body-fixed metres, fitted by least squares to
        the lines of a 9 x 9 lattice of pixels seen at three heights (+-5% of the range and
        0), and the secant slope of :meth:`_table_error` at the image centre: a first line
        and a first Newton step for ground to image (None if the lattice misses the body)."""
        line, sample = np.meshgrid(
            np.linspace(0, self.lines, 9), np.linspace(0, self.samples, 9), indexing="ij"
        )
        origin, _ = self.csm_locus(np.array(self.lines / 2), np.array(self.samples / 2))
        ground0 = self.csm_image_to_ground(np.array(self.lines / 2), np.array(self.samples / 2))
        reach = 0.05 * float(np.linalg.norm(origin - ground0))
        pts = [self.csm_image_to_ground(line, sample, h).reshape(-1, 3) for h in (-reach, 0, reach)]
        xyz, lines = np.concatenate(pts), np.tile(line.ravel(), 3)
        ok = np.isfinite(xyz).all(axis=1)
        if ok.sum() < 8 or not np.isfinite(ground0).all():
            return None
        design = np.hstack([xyz[ok] - ground0, np.ones((ok.sum(), 1))])
        coef = np.linalg.lstsq(design, lines[ok], rcond=None)[0]
        mid = np.array([self.lines / 2 - 0.5, self.lines / 2 + 0.5])
        e = self._table_error(mid, np.stack([ground0, ground0]))
        slope = float(e[1] - e[0])
        if not np.isfinite(coef).all() or not np.isfinite(slope) or slope == 0:
            return None
        return np.concatenate([coef, ground0]), slope

    def _table_line(
        self, xyz: np.ndarray, precision: float = PRECISION
    ) -> tuple[np.ndarray, np.ndarray]:
        """usgscsm's secant iteration on the line, on :meth:`_table_error`, from
        :attr:`_first_guess` (or the first and last lines): the line (M,) whose exposure sees
        each point on the detector line (to ``precision`` lines; NaN without convergence) and
        the last secant slope there."""
        guess = self._first_guess
        if guess is None:  # from the first and last lines
            t0, t1 = np.zeros(len(xyz)), np.full(len(xyz), float(self.lines))
            e0, e1 = self._table_error(t0, xyz), self._table_error(t1, xyz)
        else:  # from the affine guess and one Newton step with the centre's slope
            (coef, ground0), slope = (guess[0][:4], guess[0][4:]), guess[1]
            t0 = (xyz - ground0) @ coef[:3] + coef[3]
            e0 = self._table_error(t0, xyz)
            t1 = t0 - e0 / slope
            e1 = self._table_error(t1, xyz)
        active = np.abs(e1) > precision
        for _ in range(_MAX_SECANT):
            active &= (e1 != e0) & np.isfinite(e1)
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            t2 = t1[idx] - e1[idx] * (t1[idx] - t0[idx]) / (e1[idx] - e0[idx])
            e2 = self._table_error(t2, xyz[idx])
            t0[idx], e0[idx] = t1[idx], e1[idx]
            t1[idx], e1[idx] = t2, e2
            active[idx] = np.abs(e2) > precision
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = (e1 - e0) / (t1 - t0)
        return np.where(np.abs(e1) <= precision, t1, np.nan), slope

    def csm_ground_to_image(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """CSM (line, sample) and camera-frame depth (metres) of ground points (..., 3)
        (usgscsm ``groundToImage``: secant iteration on the line); NaN where the point is
        not imaged (line outside the image, behind the sensor, no convergence)."""
        xyz = as_points(xyz, "ground to image", 3)
        flat = xyz.reshape(-1, 3)
        out = np.empty((len(flat), 3))
        for start in range(0, len(flat), CHUNK):
            out[start : start + CHUNK] = self._ground_to_image_block(flat[start : start + CHUNK])
        out = out.reshape(xyz.shape[:-1] + (3,))
        return out[..., 0], out[..., 1], out[..., 2]

    def _ground_to_image_block(self, xyz: np.ndarray) -> np.ndarray:
        """The secant iteration on :meth:`_table_error`, then Newton steps on the exact
        :meth:`_line_error` (with the table's slope) until its offset is within
        :data:`PRECISION`, as usgscsm's iteration ends; the line is then usgscsm's: the line
        of that exposure plus the point's detector line offset."""
        line, slope = self._table_line(xyz)
        out, last = np.full((len(xyz), 3), np.nan), np.full(len(xyz), np.nan)
        todo = np.flatnonzero((line >= -_POLISH_MARGIN) & (line <= self.lines + _POLISH_MARGIN))
        for _ in range(_MAX_POLISH):
            if todo.size == 0:
                break
            update, focal, depth = self._line_error(line[todo], xyz[todo])
            sample = self.focal_plane.detector_sample(focal[:, 0], focal[:, 1])
            out[todo], last[todo] = np.stack([line[todo] + update, sample, depth], -1), update
            more = np.abs(update) > PRECISION
            line[todo[more]] -= update[more] / slope[todo[more]]
            todo = todo[more & np.isfinite(line[todo])]
        ok = (
            self._valid_line(out[:, 0])
            & (np.abs(last) <= _CONVERGED)
            & (out[:, 2] > 0)
            & np.isfinite(out[:, 1])
        )
        return np.where(ok[:, None], out, np.nan)

    # --- the orthomvp Camera protocol --------------------------------------------------------
    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``uv`` (..., 2) of world points ``xyz`` (..., 3), metres, and their depth
        along the camera axis, metres; NaN uv where not imaged (see :meth:`csm_ground_to_image`)."""
        line, sample, depth = self.csm_ground_to_image(xyz)
        return self._to_uv(line, sample), depth

    def ray(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins (the sensor position at the pixel's line time) and unit directions (..., 3)
        of the rays through pixels ``uv`` (..., 2); NaN for lines outside the image."""
        origin, direction = self.csm_locus(*self._to_csm(as_points(uv, "ray", 2)))
        return origin, self.look_sign * direction

    def origins(self, uv: np.ndarray) -> np.ndarray:
        """The sensor positions (..., 3), metres, at the times of the lines of pixels ``uv``;
        NaN for lines outside the image."""
        line, _ = self._to_csm(as_points(uv, "origins", 2))
        pos = self.sensor_position(line)
        return np.where(self._valid_line(line)[..., None], pos, np.nan)

    def image_to_ground(self, uv: np.ndarray, height: np.ndarray | float = 0.0) -> np.ndarray:
        """World points (..., 3) seen at pixels ``uv`` (..., 2) on the ellipsoid inflated by
        ``height`` metres; NaN where the ray misses it."""
        return self.csm_image_to_ground(*self._to_csm(as_points(uv, "image to ground", 2)), height)

    def gsd(self, xyz: np.ndarray) -> np.ndarray:
        """Metres per pixel at world points (..., 3) across the line of sight: range from the
        sensor at the time the point is imaged (found to :data:`GSD_LINES`) over the focal
        length in pixels; NaN where not imaged."""
        xyz = as_points(xyz, "gsd", 3)
        flat = xyz.reshape(-1, 3)
        out = np.empty(len(flat))
        step, states = self._table
        for start in range(0, len(flat), CHUNK):
            block = flat[start : start + CHUNK]
            line, _ = self._table_line(block, GSD_LINES)
            k = np.clip(np.rint(np.nan_to_num(line) / step), 0, len(states) - 1).astype(np.int64)
            rng = np.linalg.norm(block - states[k, :3], axis=-1)
            ok = self._valid_line(line) & (
                np.einsum("mi,mi->m", states[k][:, [5, 8, 11]], block - states[k, :3])
                * self.look_sign
                > 0
            )
            out[start : start + CHUNK] = np.where(ok, rng / self.focal_plane.focal_pixels, np.nan)
        return out.reshape(xyz.shape[:-1])


def posts_per_second(camera: LineScanCamera, *, posts: int = 1_000_000, seed: int = 0) -> float:
    """Ground-to-image throughput of ``camera``: points per second projecting ``posts`` ground
    points (random pixels of the image mapped to the ellipsoid) in one vectorised call."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([-0.5, -0.5], [camera.samples - 0.5, camera.lines - 0.5], size=(posts, 2))
    xyz = camera.image_to_ground(uv)
    start = _time.perf_counter()
    camera.project(xyz)
    return posts / (_time.perf_counter() - start)
