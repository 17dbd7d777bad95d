"""The USGS CSM push-frame camera (``USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL``): the image is a
stack of framelets, each a short frame exposure at its own time (``starting_ephemeris_time``
+ exposure / 2 + framelet number x ``interframe_delay``), from the interpolated trajectory.

Ground to image searches the framelet whose centre sees the point closest to the framelet's
middle (usgscsm's secant on framelet numbers, vectorised); where framelets overlap, this is
not the inverse of image to ground (as in usgscsm).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from orthomvp.camera.csm.geometry import (
    EDGE,
    CsmImage,
    Ellipsoid,
    FocalPlane,
    Trajectory,
    as_points,
)
from orthomvp.errors import InputError

MODEL_NAME = "USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL"
_MAX_ITERATIONS = 20  # usgscsm's


@dataclass(frozen=True, eq=False)
class PushFrameCamera(CsmImage):
    """A USGS CSM push-frame camera. ``lines`` is the full image's line count as the ISD
    gives it; the model's image has ``reduced_lines`` lines (framelets less their overlap).
    Times are seconds relative to ``center_time``; ``starting_time`` is relative too."""

    focal_plane: FocalPlane
    ellipsoid: Ellipsoid
    trajectory: Trajectory
    starting_time: float
    exposure_duration: float
    interframe_delay: float
    framelet_height: int
    framelets_flipped: bool = False
    framelet_order_reversed: bool = False
    overlap_lines: int = 0
    center_time: float = 0.0

    def __post_init__(self) -> None:
        if self.framelet_height <= self.overlap_lines or self.framelet_height <= 0:
            raise InputError("framelet_height must be positive and exceed num_lines_overlap")
        if self.lines < self.framelet_height:
            raise InputError("the image must hold at least one framelet")
        if self.width is None and self.height is None and (self.col0, self.row0) == (0, 0):
            object.__setattr__(self, "height", self.reduced_lines)
            object.__setattr__(self, "width", int(self.samples))
        super().__post_init__()
        times = self._framelet_time(np.array([0, self.framelet_count - 1]))
        lo, hi = self.trajectory.time_range
        slack = max(self.trajectory.dt_ephem, self.trajectory.dt_quat)  # as the line scanner
        if times.min() < lo - slack or times.max() > hi + slack:
            raise InputError(
                f"the framelet times [{times.min():.6g}, {times.max():.6g}] s lie outside the "
                f"ephemeris [{lo:.6g}, {hi:.6g}] s"
            )

    @property
    def summed_height(self) -> int:
        """Lines per framelet in the model's image (overlap removed, summing applied)."""
        return int((self.framelet_height - self.overlap_lines) // self.focal_plane.line_summing)

    @property
    def framelet_count(self) -> int:
        """Number of framelets."""
        return self.lines // self.framelet_height

    @property
    def reduced_lines(self) -> int:
        """Lines of the model's image (usgscsm ``m_nReducedLines``)."""
        return self.framelet_count * (self.framelet_height - self.overlap_lines)

    def _framelet_time(self, framelet: np.ndarray) -> np.ndarray:
        if self.framelet_order_reversed:
            framelet = self.reduced_lines // self.summed_height - framelet - 1
        return self.starting_time + 0.5 * self.exposure_duration + framelet * self.interframe_delay

    def image_time(self, line: np.ndarray) -> np.ndarray:
        """Exposure times (s, relative to ``center_time``) of CSM lines (``getImageTime``)."""
        framelet = np.trunc(np.asarray(line, dtype=np.float64) / self.summed_height)
        return self._framelet_time(framelet)

    def _valid_line(self, line: np.ndarray) -> np.ndarray:
        return (line >= -EDGE) & (line <= self.reduced_lines + EDGE)

    @cached_property
    def look_sign(self) -> int:
        """+1 if usgscsm's locus direction points into the scene, -1 if away (see
        :mod:`orthomvp.camera.csm.geometry`)."""
        origin, direction = self.csm_locus(
            np.array(self.reduced_lines / 2.0), np.array(self.samples / 2.0)
        )
        return self._look_sign(origin, direction)

    def csm_locus(self, line: np.ndarray, sample: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor positions and unit look directions (..., 3) of CSM (line, sample); NaN
        where the line is outside the image."""
        line, sample = np.broadcast_arrays(
            np.asarray(line, np.float64), np.asarray(sample, np.float64)
        )
        flat_line = line.ravel()
        t = self.image_time(flat_line)
        framelet_line = np.fmod(flat_line, self.summed_height)
        if self.framelets_flipped:
            framelet_line = self.summed_height - framelet_line
        framelet_line = framelet_line + self.overlap_lines // 2
        look = self.focal_plane.camera_look(framelet_line, sample.ravel())
        direction = np.einsum("mij,mj->mi", self.trajectory.rotation(t), look)
        origin = self.trajectory.position(t)
        bad = ~self._valid_line(flat_line)
        origin[bad], direction[bad] = np.nan, np.nan
        return origin.reshape(line.shape + (3,)), direction.reshape(line.shape + (3,))

    def _view(self, framelet: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, ...]:
        """Distorted focal-plane x, y and depth of ``xyz`` (M, 3) seen from framelets (M,)."""
        t = self._framelet_time(framelet)
        cam = np.einsum(
            "mji,mj->mi", self.trajectory.rotation(t), xyz - self.trajectory.position(t)
        )
        dx, dy = self.focal_plane.view(cam)
        return dx, dy, self.look_sign * self.focal_plane.axis_sign * cam[:, 2]

    def _frame_distance(self, framelet: np.ndarray, xyz: np.ndarray) -> np.ndarray:
        """usgscsm ``calcFrameDistance``: detector line offset from the framelet's middle
        (undistorted focal plane, as usgscsm)."""
        t = self._framelet_time(framelet)
        cam = np.einsum(
            "mji,mj->mi", self.trajectory.rotation(t), xyz - self.trajectory.position(t)
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = self.focal_plane.focal_length / cam[:, 2]
        line = self.focal_plane.detector_line(cam[:, 0] * scale, cam[:, 1] * scale)
        return line - self.overlap_lines // 2 - self.summed_height / 2.0

    def csm_ground_to_image(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """CSM (line, sample) and camera-frame depth (metres) of ground points (..., 3); NaN
        where not imaged (line outside the image, behind the sensor)."""
        return self._in_chunks(xyz)

    def _ground_to_image_block(self, xyz: np.ndarray) -> np.ndarray:
        n = self.reduced_lines // self.summed_height
        start = np.zeros(len(xyz))
        end = np.full(len(xyz), n - 1.0)
        d_start = self._frame_distance(start, xyz)
        d_end = self._frame_distance(end, xyz)
        active = np.ones(len(xyz), dtype=bool)
        for _ in range(_MAX_ITERATIONS):
            active &= (start != end) & (d_start != d_end) & np.isfinite(d_end)
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            offset = d_end[idx] * (end[idx] - start[idx]) / (d_end[idx] - d_start[idx])
            start[idx], d_start[idx] = end[idx], d_end[idx]
            end[idx] = np.clip(np.round(end[idx] - offset), 0, n)
            d_end[idx] = self._frame_distance(end[idx], xyz[idx])
        dx, dy, depth = self._view(end, xyz)
        fp = self.focal_plane
        line = fp.detector_line(dx, dy) + end * self.summed_height - self.overlap_lines // 2
        sample = fp.detector_sample(dx, dy)
        ok = self._valid_line(line) & (depth > 0) & np.isfinite(sample)
        return np.where(ok[:, None], np.stack([line, sample, depth], -1), np.nan)

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``uv`` (..., 2) of world points (..., 3), metres, and their depth, metres;
        NaN uv where not imaged."""
        line, sample, depth = self.csm_ground_to_image(xyz)
        return self._to_uv(line, sample), depth

    def ray(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins (the sensor at the framelet's time) and unit directions (..., 3) of the rays
        through pixels ``uv`` (..., 2); NaN for lines outside the image."""
        origin, direction = self.csm_locus(*self._to_csm(as_points(uv, "ray", 2)))
        return origin, self.look_sign * direction

    def origins(self, uv: np.ndarray) -> np.ndarray:
        """The sensor positions (..., 3), metres, at the framelet times of pixels ``uv``."""
        line, _ = self._to_csm(as_points(uv, "origins", 2))
        t = self.image_time(line)
        pos = self.trajectory.position(t.ravel()).reshape(t.shape + (3,))
        return np.where(self._valid_line(line)[..., None], pos, np.nan)

    def image_to_ground(self, uv: np.ndarray, height: np.ndarray | float = 0.0) -> np.ndarray:
        """World points (..., 3) seen at pixels ``uv`` on the ellipsoid inflated by ``height``."""
        return self.csm_image_to_ground(*self._to_csm(as_points(uv, "image to ground", 2)), height)

    def gsd(self, xyz: np.ndarray) -> np.ndarray:
        """Metres per pixel at world points (..., 3): range from the sensor at the point's
        framelet time over the focal length in pixels; NaN where not imaged."""
        line, _, _ = self.csm_ground_to_image(xyz)
        t = self.image_time(np.nan_to_num(line))
        pos = self.trajectory.position(t.ravel()).reshape(t.shape + (3,))
        rng = np.linalg.norm(np.asarray(xyz, np.float64) - pos, axis=-1)
        return np.where(np.isfinite(line), rng / self.focal_plane.focal_pixels, np.nan)
