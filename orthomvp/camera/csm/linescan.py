"""The USGS CSM line scanner (``USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL``), vectorised.

Each image line is exposed at its own time (``line_scan_rate``: piecewise-constant line
durations), from the sensor position and pointing interpolated there (usgscsm's Lagrange
polynomials of order 8 on uniform nodes). Ground to image solves for the line by usgscsm's
secant iteration, for all points at once; points whose line falls outside the image (no
exposure time there) get NaN, never an extrapolated pixel.

Speed: the iteration runs on a table of sensor states sampled once per line (finer for short
images), interpolated linearly, from a first line given by an affine fit of a pixel lattice.
Where the table reproduces the ephemeris within :data:`TABLE_PIXELS` (orbital images) it
serves rays and origins too; otherwise ground to image ends with Newton steps on the exact
model and rays use the exact ephemeris. On blocks of :data:`KERNEL_POINTS` points or more the
table is evaluated by numba kernels (:mod:`orthomvp.camera.csm.table_kernel`), and where the
table serves the whole iteration runs point by point there, lens distortion included: the
numpy iteration's values bit for bit, which stays their test oracle.
:meth:`LineScanCamera.imaging` gives the visibility test a point's pixel, ray origin and
direction and GSD from that one search.
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
KERNEL_POINTS = 4096
"""Fewest points for which the sensor-state table is evaluated by the numba kernel of
:mod:`orthomvp.camera.csm.table_kernel` (the same values as numpy, bit for bit), which pays
for its load (numba's import and the cached kernel, about 0.3 s once a process) on the
blocks of an orthophoto."""
KERNEL_DISTORTIONS = {
    "radial": 1,
    "lrolrocnac": 2,
    "transverse": 3,
    "kaguyalism": 4,
    "dawnfc": 5,
    "radtan": 6,
}
"""Each of usgscsm's lens distortion models (:data:`orthomvp.camera.csm.distortion.MODELS`)
by its code in the kernel (no distortion is 0; :data:`orthomvp.camera.csm.table_kernel.RADIAL`
and the others)."""
GSD_LINES = 1e-3
"""Lines to which :meth:`LineScanCamera.gsd` finds where a point is imaged (usually the first
Newton step; the range moves by far less than 1e-6 of itself over them)."""
TABLE_KNOTS = 1024
"""Fewest knots of the sensor-state table (one per line for longer images)."""
TABLE_PIXELS = 1e-4
"""Largest interpolation error (pixels) of the sensor-state table for which it stands in for
the ephemeris everywhere; beyond it, ground to image polishes with the exact model and rays
use it."""


@dataclass(frozen=True, eq=False)
class LineScanCamera(CsmImage):
    """A USGS CSM line-scan camera (conventions in :mod:`orthomvp.camera.csm.geometry`).

    ``int_time_lines``, ``int_time_start_times``, ``int_times``: the ISD's ``line_scan_rate``
    rows (first CSM line of a segment, its start time in seconds relative to ``center_time``,
    seconds per line); the time of CSM line L in segment i is start_i + dt_i (L - line_i + 0.5).
    ``center_time``: the ISD's ``center_ephemeris_time`` (ephemeris seconds).
    """

    _WINDOW_FREE = (
        "look_sign",
        "_table",
        "_table_rows",
        "table_error",
        "_use_table",
        "_first_guess",
        "_kernel_args",
    )

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

    def csm_locus(self, line: np.ndarray, sample: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor positions and unit look directions (..., 3) of CSM (line, sample) (usgscsm
        ``imageToRemoteImagingLocus``); NaN where the line is outside the image."""
        line, sample = np.broadcast_arrays(
            np.asarray(line, np.float64), np.asarray(sample, np.float64)
        )
        flat = line.ravel()
        look = self.focal_plane.camera_look(np.zeros_like(flat), sample.ravel())
        origin, rotation = self._states(flat)
        direction = np.einsum("mij,mj->mi", rotation, look)
        if self._use_table:  # the interpolated rotation is orthonormal to ~1e-10 only
            direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        bad = ~self._valid_line(flat)
        origin[bad], direction[bad] = np.nan, np.nan
        return origin.reshape(line.shape + (3,)), direction.reshape(line.shape + (3,))

    def _line_error(
        self, line: np.ndarray, xyz: np.ndarray, *, table: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """usgscsm ``calcDetectorLineErr``: the detector line offset (M,) at which ``xyz``
        (M, 3) appears when seen at the time of CSM ``line`` (M,), and the distorted
        focal-plane x, y and camera-frame depth (M, 3); the sensor states from
        :meth:`_states` (``table``: from :attr:`_table` whatever :attr:`_use_table` says)."""
        if (table or self._use_table) and len(line) >= KERNEL_POINTS:
            from orthomvp.camera.csm.table_kernel import camera_coordinates

            cam = camera_coordinates(*self._table_rows, line, xyz)  # the same values
            cam = [cam[:, 0], cam[:, 1], cam[:, 2]]
        else:
            pos, rot = self._states(line, table=table or None)
            rel = (xyz - pos).T
            cam = [
                rot[:, 0, i] * rel[0] + rot[:, 1, i] * rel[1] + rot[:, 2, i] * rel[2]
                for i in range(3)
            ]
        dx, dy = self.focal_plane.view(np.stack(cam, -1))
        view = np.stack([dx, dy, self.look_sign * self.focal_plane.axis_sign * cam[2]], -1)
        return self.focal_plane.detector_line(dx, dy), view

    @cached_property
    def _table(self) -> tuple[float, np.ndarray, np.ndarray]:
        """Sensor states sampled along the image: the knot spacing in CSM lines (one line,
        finer for images of fewer than :data:`TABLE_KNOTS` lines), the positions (metres)
        and camera-to-body rotations (row-major) at the knots, (knots, 12), and their
        differences to the next knot, (knots - 1, 12)."""
        step = min(1.0, self.lines / TABLE_KNOTS)
        knots = np.linspace(0.0, float(self.lines), round(self.lines / step) + 1)
        t = self.image_time(knots)
        states = np.vstack(
            [self.trajectory.position(t).T, self.trajectory.rotation(t).reshape(-1, 9).T]
        )
        return float(knots[1] - knots[0]), states, np.diff(states, axis=1)

    @cached_property
    def _table_rows(self) -> tuple[np.ndarray, np.ndarray, float]:
        """:attr:`_table`'s knots and differences one row per knot, (knots, 12) and
        (knots - 1, 12), C-contiguous, and the knot spacing: as the kernel
        (:mod:`orthomvp.camera.csm.table_kernel`) takes them."""
        step, states, diffs = self._table
        return np.ascontiguousarray(states.T), np.ascontiguousarray(diffs.T), step

    def _states(
        self, line: np.ndarray, *, table: bool | None = None, columns: int = 12
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sensor positions (M, 3), metres, and camera-to-body rotations (M, 3, 3) at CSM
        lines (M,): from the interpolated ephemeris, or (``table``; None: where
        :attr:`_use_table`) linearly between the knots of :attr:`_table` (extrapolated
        beyond the image); ``columns=3``: positions only (rotations None)."""
        if not (self._use_table if table is None else table):
            t = self.image_time(line)
            pos = self.trajectory.position(t)
            return pos, self.trajectory.rotation(t) if columns > 3 else None
        step, states, diffs = self._table
        x = line / step
        k = np.clip(np.floor(np.nan_to_num(x)), 0, diffs.shape[1] - 1).astype(np.int64)
        s = np.take(diffs[:columns], k, axis=1)  # (columns, M): one row per component
        s *= x - k
        s += np.take(states[:columns], k, axis=1)
        return s[:3].T, s[3:].T.reshape(-1, 3, 3) if columns > 3 else None

    @cached_property
    def table_error(self) -> float:
        """The largest error of :attr:`_table`'s interpolation against the ephemeris, in
        pixels: at the midpoints between knots, the position error over half the sensor's
        altitude plus the rotation error (Frobenius), times the focal length in pixels;
        infinite for a sensor not above the ellipsoid."""
        step, states, _ = self._table
        mid = (np.arange(states.shape[1] - 1) + 0.5) * step
        pos_t, rot_t = self._states(mid, table=True)
        pos, rot = self._states(mid, table=False)
        radius = max(self.ellipsoid.semi_major, self.ellipsoid.semi_minor)
        altitude = np.linalg.norm(pos, axis=1) - radius
        if not (altitude > 0).all():
            return float("inf")
        err = np.linalg.norm(pos_t - pos, axis=1) / (altitude / 2)
        err += np.linalg.norm((rot_t - rot).reshape(-1, 9), axis=1)
        return float(np.max(err) * self.focal_plane.focal_pixels)

    @cached_property
    def _use_table(self) -> bool:
        """Whether :attr:`_table` stands in for the ephemeris everywhere (its
        :attr:`table_error` within :data:`TABLE_PIXELS`: orbital images, a knot per line)."""
        return self.table_error <= TABLE_PIXELS

    @cached_property
    def _first_guess(self) -> tuple[np.ndarray, float] | None:
        """The line as an affine function of body-fixed metres, fitted by least squares to
        the lines of a 9 x 9 lattice of pixels seen at three heights (+-5% of the range and
        0), and the secant slope of the table's :meth:`_line_error` at the image centre: a
        first line and a first Newton step for ground to image (None if the lattice misses
        the body)."""
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
        e, _ = self._line_error(mid, np.stack([ground0, ground0]), table=True)
        slope = float(e[1] - e[0])
        if not np.isfinite(coef).all() or not np.isfinite(slope) or slope == 0:
            return None
        return np.concatenate([coef, ground0]), slope

    def _kernel_applies(self, points: int) -> bool:
        """Whether ground to image of ``points`` points runs in the numba kernel of
        :mod:`orthomvp.camera.csm.table_kernel` (the same values as the numpy iteration, bit
        for bit): the table stands in for the ephemeris, and there are at least
        :data:`KERNEL_POINTS` points."""
        return points >= KERNEL_POINTS and self._use_table

    @cached_property
    def _kernel_args(self) -> tuple[tuple[np.ndarray, np.ndarray, float], np.ndarray, np.ndarray]:
        """The table, focal plane and search as the kernel's ``ground_to_image`` takes them."""
        fp = self.focal_plane
        lens = 0 if fp.distortion.is_identity else KERNEL_DISTORTIONS[fp.distortion.model]
        plane = np.array(
            [fp.focal_length, float(self.look_sign * fp.axis_sign), *fp.i_trans_l,
             fp.line_origin, fp.starting_line, fp.line_summing, *fp.i_trans_s,
             fp.sample_origin, fp.starting_sample, fp.sample_summing, lens,
             *np.pad(fp.distortion.coefficients, (0, 20))[:20]],
            dtype=np.float64,
        )  # fmt: skip
        guess = self._first_guess
        first = np.full(8, np.nan) if guess is None else np.append(guess[0], guess[1])
        search = np.array(
            [*first, PRECISION, _CONVERGED, float(self.lines), EDGE, _MAX_SECANT,
             fp.focal_pixels],
            dtype=np.float64,
        )  # fmt: skip
        return self._table_rows, plane, search

    def _table_line(
        self, xyz: np.ndarray, precision: float = PRECISION
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """usgscsm's secant iteration on the line, on the table's :meth:`_line_error`, from
        :attr:`_first_guess` (or the first and last lines), to ``precision`` lines: the line
        (M,) whose exposure sees each point on the detector line (NaN without convergence),
        the point's detector line offset and view (focal x, y, depth) there, and the last
        secant slope."""
        guess = self._first_guess
        if guess is None:  # from the first and last lines
            t0, t1 = np.zeros(len(xyz)), np.full(len(xyz), float(self.lines))
            e0 = self._line_error(t0, xyz, table=True)[0]
        else:  # from the affine guess and one Newton step with the centre's slope
            (coef, ground0), slope = (guess[0][:4], guess[0][4:]), guess[1]
            rel = xyz - ground0  # no BLAS: the same rounding for any number of points
            t0 = rel[:, 0] * coef[0] + rel[:, 1] * coef[1] + rel[:, 2] * coef[2] + coef[3]
            e0 = self._line_error(t0, xyz, table=True)[0]
            t1 = t0 - e0 / slope
        e1, v1 = self._line_error(t1, xyz, table=True)
        active = np.abs(e1) > precision
        for _ in range(_MAX_SECANT):
            active &= (e1 != e0) & np.isfinite(e1)
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            t2 = t1[idx] - e1[idx] * (t1[idx] - t0[idx]) / (e1[idx] - e0[idx])
            e2, v1[idx] = self._line_error(t2, xyz[idx], table=True)
            t0[idx], e0[idx] = t1[idx], e1[idx]
            t1[idx], e1[idx] = t2, e2
            active[idx] = np.abs(e2) > precision
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = (e1 - e0) / (t1 - t0)
        return np.where(np.abs(e1) <= precision, t1, np.nan), e1, v1, slope

    def csm_ground_to_image(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """CSM (line, sample) and camera-frame depth (metres) of ground points (..., 3)
        (usgscsm ``groundToImage``: secant iteration on the line); NaN where the point is
        not imaged (line outside the image, behind the sensor, no convergence)."""
        return self._in_chunks(xyz)

    def _ground_to_image_block(self, xyz: np.ndarray) -> np.ndarray:
        """The secant iteration on the table; unless :attr:`_use_table`, then Newton steps
        on the exact :meth:`_line_error` (with the table's slope) until its offset is within
        :data:`PRECISION`, as usgscsm's iteration ends. The line is usgscsm's: the line of
        that exposure plus the point's detector line offset."""
        if self._kernel_applies(len(xyz)):
            from orthomvp.camera.csm.table_kernel import ground_to_image

            return ground_to_image(*self._kernel_args, xyz)[0]
        line, update, view, slope = self._table_line(xyz)
        if self._use_table:
            last = update
        else:
            last = np.full(len(xyz), np.nan)
            todo = np.flatnonzero((line >= -_POLISH_MARGIN) & (line <= self.lines + _POLISH_MARGIN))
            for _ in range(_MAX_POLISH):
                if todo.size == 0:
                    break
                last[todo], view[todo] = self._line_error(line[todo], xyz[todo])
                more = np.abs(last[todo]) > PRECISION
                line[todo[more]] -= last[todo[more]] / slope[todo[more]]
                todo = todo[more & np.isfinite(line[todo])]
        sample = self.focal_plane.detector_sample(view[:, 0], view[:, 1])
        out = np.stack([line + last, sample, view[:, 2]], -1)
        ok = (
            self._valid_line(out[:, 0])
            & (np.abs(last) <= _CONVERGED)
            & (out[:, 2] > 0)
            & np.isfinite(sample)
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
        pos = self._states(line.ravel(), columns=3)[0].reshape(line.shape + (3,))
        return np.where(self._valid_line(line)[..., None], pos, np.nan)

    def imaging(self, xyz: np.ndarray) -> tuple[np.ndarray, ...]:
        """Everything the visibility test needs of world points ``xyz`` (..., 3), metres, from
        one ground to image: the pixels ``uv`` (..., 2) and depths of :meth:`project`, the
        sensor positions (..., 3) at the times of those lines (:meth:`origins`), the unit ray
        directions (..., 3) from there to the points, and the GSD (metres per pixel across
        the line of sight: the range from there over the focal length in pixels); NaN where
        not imaged. The ray from the sensor position through the point's pixel passes
        through the point to the precision of ground to image (:data:`PRECISION` lines), so
        the direction to the point is the model's ray (:meth:`ray`) without a second
        evaluation, and the range is :meth:`gsd`'s at the exact line rather than at
        :data:`GSD_LINES`."""
        xyz = as_points(xyz, "imaging", 3)
        flat = xyz.reshape(-1, 3)
        if self._kernel_applies(len(flat)):
            from orthomvp.camera.csm.table_kernel import ground_to_image

            out, rays = ground_to_image(*self._kernel_args, flat, rays=True)
            line, sample, depth = out[:, 0], out[:, 1], out[:, 2]
            origin, direction, gsd = rays[:, :3], rays[:, 3:6], rays[:, 6]
        else:
            line, sample, depth = self.csm_ground_to_image(flat)
            origin = self._states(np.nan_to_num(line), columns=3)[0]
            origin[~np.isfinite(line)] = np.nan
            to_point = flat - origin
            x, y, z = to_point[:, 0], to_point[:, 1], to_point[:, 2]
            rng = np.sqrt(x * x + y * y + z * z)
            direction = to_point / rng[:, None]
            gsd = rng / self.focal_plane.focal_pixels
        shape = xyz.shape[:-1]
        return (
            self._to_uv(line.reshape(shape), sample.reshape(shape)),
            depth.reshape(shape),
            origin.reshape(xyz.shape),
            direction.reshape(xyz.shape),
            gsd.reshape(shape),
        )

    def image_to_ground(self, uv: np.ndarray, height: np.ndarray | float = 0.0) -> np.ndarray:
        """World points (..., 3) seen at pixels ``uv`` (..., 2) on the ellipsoid inflated by
        ``height`` metres; NaN where the ray misses it."""
        return self.csm_image_to_ground(*self._to_csm(as_points(uv, "image to ground", 2)), height)

    def gsd(self, xyz: np.ndarray) -> np.ndarray:
        """Metres per pixel at world points (..., 3) across the line of sight: range from the
        sensor at the time the point is imaged (its line found on the table to
        :data:`GSD_LINES`) over the focal length in pixels; NaN where not imaged."""
        xyz = as_points(xyz, "gsd", 3)
        flat = xyz.reshape(-1, 3)
        out = np.empty(len(flat))
        for start in range(0, len(flat), CHUNK):
            block = flat[start : start + CHUNK]
            line, _, view, _ = self._table_line(block, GSD_LINES)
            rng = np.linalg.norm(block - self._states(line, table=True, columns=3)[0], axis=-1)
            ok = self._valid_line(line) & (view[:, 2] > 0)
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
