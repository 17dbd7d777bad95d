"""The Apollo 15, 16 and 17 Metric (mapping) cameras (ISIS's ApolloMetricCamera and
ApolloMetricDistortionMap; ALE's ApolloMetricIsisLabelNaifSpiceDriver): frame cameras.

- Time: ``Instrument`` ``StartTime`` (UTC) as ET, the time of the one-record tables.
- Detector: origin at the centre of the original (AlphaCube) image, ISIS's
  AlphaSamples / 2 (1-based), i.e. AlphaSamples / 2 - 0.5 in usgscsm's 0-based pixels.
- The camera looks along -z of its frame (ISIS builds the distortion map with focal-length
  sign -1): the ISD's focal length is negative, as in ALE's ISDs.
- Lens: ISIS's model on focal-plane millimetres, from ``NaifKeywords`` ``INS<id>_PP`` (xp, yp),
  ``OD_K`` (k1, k2, k3) and ``DECENTER`` (j1, j2, t0): with x = x_d - xp, y = y_d - yp,
  r^2 = x^2 + y^2, dr = 1 + k1 r^2 + k2 r^4 + k3 r^6 and dt = j1 r^2 + j2 r^4,
  x_u = dr x - dt sin t0, y_u = dr y + dt cos t0 (:class:`ApolloMetricDistortion`). usgscsm
  has no such model: the ISD carries none, the camera uses this one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from orthomvp.camera.isis.core import Instrument, SpiceCube
from orthomvp.camera.isis.isd import frame_isd, ikid_of

_CAMERAS = {-915240: "Apollo 15", -916240: "Apollo 16", -917240: "Apollo 17"}
_TOLERANCE = 1e-6  # mm, ISIS's convergence tolerance
_ITERATIONS = 50  # ISIS's limit


@dataclass(frozen=True, eq=False)
class ApolloMetricDistortion:
    """ISIS's ApolloMetricDistortionMap: principal point (``xp``, ``yp``, mm), radial ``k1``,
    ``k2``, ``k3`` and decentering ``j1``, ``j2``, ``t0`` (rad) terms; the same interface as
    :class:`orthomvp.camera.csm.distortion.CsmDistortion` (focal-plane mm; ``focal`` unused)."""

    xp: float
    yp: float
    k1: float
    k2: float
    k3: float
    j1: float
    j2: float
    t0: float
    model: str = "apollometric"

    @property
    def coefficients(self) -> np.ndarray:
        """(xp, yp, k1, k2, k3, j1, j2, t0)."""
        return np.array([self.xp, self.yp, self.k1, self.k2, self.k3, self.j1, self.j2, self.t0])

    def _shift(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ISIS's distortion of (x, y) relative to the principal point: dr - 1 and dt terms."""
        rr = x * x + y * y
        dr = self.k1 * rr + self.k2 * rr * rr + self.k3 * rr * rr * rr
        dt = self.j1 * rr + self.j2 * rr * rr
        return x * dr - dt * np.sin(self.t0), y * dr + dt * np.cos(self.t0)

    def undistort(
        self, x: np.ndarray, y: np.ndarray, focal: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted focal-plane (x, y), mm, of distorted ones (ISIS ``SetFocalPlane``)."""
        px = np.asarray(x, dtype=np.float64) - self.xp
        py = np.asarray(y, dtype=np.float64) - self.yp
        sx, sy = self._shift(px, py)
        return px + sx, py + sy

    def distort(
        self, x: np.ndarray, y: np.ndarray, focal: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Distorted focal-plane (x, y), mm, of undistorted ones (ISIS
        ``SetUndistortedFocalPlane``: fixed-point iteration, at most 50 steps to 1e-6 mm);
        NaN where it does not converge."""
        ux, uy = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        xt, yt = ux.copy(), uy.copy()
        finite = np.isfinite(ux) & np.isfinite(uy)
        done = ~finite  # (NaN never converges: without this every call took 50 steps)
        with np.errstate(over="ignore", invalid="ignore"):  # (far off the lens: diverges)
            for _ in range(_ITERATIONS):
                if done.all():
                    break
                sx, sy = self._shift(xt, yt)
                nx, ny = ux - sx, uy - sy
                converged = (np.abs(nx - xt) <= _TOLERANCE) & (np.abs(ny - yt) <= _TOLERANCE)
                xt, yt = np.where(done, xt, nx), np.where(done, yt, ny)
                done = done | converged
        done &= finite
        return np.where(done, xt + self.xp, np.nan), np.where(done, yt + self.yp, np.nan)


def distortion(cube: SpiceCube) -> ApolloMetricDistortion:
    """The lens of an Apollo Metric cube, from its ``NaifKeywords``."""
    ins = f"INS{ikid_of(cube)}"
    pp = cube.naif_array(f"{ins}_PP", 2)
    k = cube.naif_array(f"{ins}_OD_K", 3)
    j1, j2, t0 = cube.naif_array(f"{ins}_DECENTER", 3)
    return ApolloMetricDistortion(pp[0], pp[1], k[0], k[1], k[2], j1, j2, t0)


def isd(cube: SpiceCube) -> dict[str, Any]:
    """The frame ISD of an Apollo Metric cube (no lens model: :func:`distortion`)."""
    ikid = ikid_of(cube)
    if ikid not in _CAMERAS:
        known = ", ".join(f"{v} ({k})" for k, v in _CAMERAS.items())
        raise cube.error(f"Kernels NaifFrameCode = {ikid} is not an Apollo Metric camera: {known}")
    alpha = cube.alpha
    out = frame_isd(
        cube,
        ikid,
        time=cube.utc("Instrument", "StartTime"),
        center=(alpha.lines / 2.0 - 0.5, alpha.samples / 2.0 - 0.5),
    )
    focal = out["focal_length_model"]["focal_length"]
    out["focal_length_model"] = {"focal_length": -abs(focal)}
    out["optical_distortion"] = {"radial": {"coefficients": [0.0, 0.0, 0.0]}}
    return out


INSTRUMENT = Instrument(
    name="Apollo 15/16/17 Metric",
    ids=tuple((f"APOLLO {n}", "METRIC") for n in (15, 16, 17)),
    isd=isd,
    distortion=distortion,
)
