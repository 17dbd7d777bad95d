"""The USGS CSM frame camera (``USGS_ASTRO_FRAME_SENSOR_MODEL``): one exposure from one
position and pointing, usgscsm's focal plane and lens distortion (conventions in
:mod:`orthomvp.camera.csm.geometry`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.camera.csm.ephemeris import xyzw_matrix
from orthomvp.camera.csm.geometry import CsmImage, Ellipsoid, FocalPlane, as_points
from orthomvp.errors import InputError

MODEL_NAME = "USGS_ASTRO_FRAME_SENSOR_MODEL"


@dataclass(frozen=True, eq=False)
class CsmFrameCamera(CsmImage):
    """A USGS CSM frame camera: ``position`` (3,) body-fixed metres, ``velocity`` (3,) m/s,
    ``quaternion`` (4,) camera-to-body, scalar-last (x, y, z, w) as in usgscsm's state."""

    focal_plane: FocalPlane
    ellipsoid: Ellipsoid
    position: np.ndarray
    velocity: np.ndarray
    quaternion: np.ndarray

    def __post_init__(self) -> None:
        super().__post_init__()
        for name, n in (("position", 3), ("velocity", 3), ("quaternion", 4)):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != (n,) or not np.isfinite(value).all():
                raise InputError(f"{name} must be {n} finite numbers")
            object.__setattr__(self, name, value)
        if not np.linalg.norm(self.quaternion) > 0:
            raise InputError("quaternion must not be zero")

    @property
    def rotation(self) -> np.ndarray:
        """Camera-to-body rotation (3, 3)."""
        return xyzw_matrix(self.quaternion)

    @property
    def boresight(self) -> np.ndarray:
        """Unit direction (3,), body-fixed, of the optical axis: the way depth grows (the
        camera frame's z axis, signed as :meth:`csm_ground_to_image` measures depth)."""
        return self.look_sign * self.focal_plane.axis_sign * self.rotation[:, 2]

    def csm_locus(self, line: np.ndarray, sample: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor position and unit look directions (..., 3) of CSM (line, sample)."""
        line, sample = np.broadcast_arrays(
            np.asarray(line, np.float64), np.asarray(sample, np.float64)
        )
        look = self.focal_plane.camera_look(line, sample)
        direction = look @ self.rotation.T
        return np.broadcast_to(self.position, direction.shape).copy(), direction

    def csm_ground_to_image(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """CSM (line, sample) and depth along the optical axis (metres) of ground points
        (..., 3); NaN behind the camera."""
        xyz = as_points(xyz, "ground to image", 3)
        cam = (xyz - self.position) @ self.rotation
        dx, dy = self.focal_plane.view(cam)
        fp = self.focal_plane
        line = fp.detector_line(dx, dy)
        sample = fp.detector_sample(dx, dy)
        depth = self.look_sign * self.focal_plane.axis_sign * cam[..., 2]
        front = (depth > 0) & np.isfinite(line)
        return (
            np.where(front, line, np.nan),
            np.where(front, sample, np.nan),
            np.where(front, depth, np.nan),
        )

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``uv`` (..., 2) of world points (..., 3), metres, and their depth along the
        optical axis, metres; NaN uv behind the camera."""
        line, sample, depth = self.csm_ground_to_image(xyz)
        return self._to_uv(line, sample), depth

    def ray(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The camera position and unit directions (..., 3) of the rays through pixels ``uv``."""
        origin, direction = self.csm_locus(*self._to_csm(as_points(uv, "ray", 2)))
        return origin, self.look_sign * direction

    def origins(self, uv: np.ndarray) -> np.ndarray:
        """The camera position (..., 3) for every pixel ``uv`` (..., 2)."""
        uv = as_points(uv, "origins", 2)
        return np.broadcast_to(self.position, uv.shape[:-1] + (3,)).copy()

    def image_to_ground(self, uv: np.ndarray, height: np.ndarray | float = 0.0) -> np.ndarray:
        """World points (..., 3) seen at pixels ``uv`` on the ellipsoid inflated by ``height``."""
        return self.csm_image_to_ground(*self._to_csm(as_points(uv, "image to ground", 2)), height)

    def gsd(self, xyz: np.ndarray) -> np.ndarray:
        """Metres per pixel at world points (..., 3): range over the focal length in pixels."""
        xyz = as_points(xyz, "gsd", 3)
        return np.linalg.norm(xyz - self.position, axis=-1) / self.focal_plane.focal_pixels
