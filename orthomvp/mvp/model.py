"""The plane model of a batch of posts: homographies from patch offsets to image pixels and
their derivatives with respect to the fitted parameters.

Per post the parameters are theta = (h, alpha, beta): the height in the DEM's convention and a
tilt of the normal, n = n0 + alpha t1 + beta t2, with n0 a starting normal and (t1, t2)
orthonormal tangents (well conditioned at the poles and in the map frame, where eq. 11's angles
are singular). At pyramid level L a patch step is 2**L posts and a pixel 2**L level-0 pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.mvp.plane import PostLines, plane_map, tangent_basis


@dataclass
class PlaneModel:
    """The homographies of a batch of posts and their parameter derivatives: height lines,
    starting normals ``n0`` (B, 3) with tangents ``t1``, ``t2`` (from ``n0`` unless given),
    projection matrices ``F`` (K, 3, 4), or per post (B, K, 3, 4) (local approximations of
    cameras that are not pinholes, :mod:`orthomvp.mvp.local`), and the post spacing in
    metres."""

    lines: PostLines
    n0: np.ndarray
    F: np.ndarray
    spacing: float
    t1: np.ndarray | None = None
    t2: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.t1 is None or self.t2 is None:
            self.t1, self.t2 = tangent_basis(self.n0)

    def take(self, index: np.ndarray) -> PlaneModel:
        """The model of a subset of the posts."""
        return PlaneModel(
            self.lines.take(index),
            self.n0[index],
            self.F if self.F.ndim == 3 else self.F[index],
            self.spacing,
            self.t1[index],
            self.t2[index],
        )

    def normal(self, theta: np.ndarray) -> np.ndarray:
        n = self.n0 + theta[:, 1:2] * self.t1 + theta[:, 2:3] * self.t2
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def _outer(self, level: int) -> tuple[np.ndarray, np.ndarray]:
        """Left factor T F ((B,) K, 3, 4) (level-0 pixels to level pixels) and right factor Z
        (B, 3, 3) (patch offsets in steps to grid pixels)."""
        s = 2.0**level
        T = np.diag([1 / s, 1 / s, 1.0])
        Z = np.zeros((len(self.lines.c), 3, 3))
        Z[:, 0, 0] = Z[:, 1, 1] = s
        Z[:, 0, 2], Z[:, 1, 2], Z[:, 2, 2] = self.lines.c, self.lines.r, 1.0
        return T @ self.F, Z

    def homographies(
        self, theta: np.ndarray, level: int, derivatives: bool = True
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """H (B, K, 3, 3) from patch offsets to level pixels, and dH (B, K, 3, 3, 3)."""
        TF, Z = self._outer(level)
        n = self.n0 + theta[:, 1:2] * self.t1 + theta[:, 2:3] * self.t2
        G = plane_map(self.lines, theta[:, 0], n) @ Z
        # batched matmul: einsum over these 3x4 by 4x3 products is 4x slower
        left = TF if TF.ndim == 4 else TF[None]
        H = left @ G[:, None]
        if not derivatives:
            return H, None
        dG = (
            np.stack(
                [
                    plane_map(self.lines, np.ones(len(n)), n)
                    - plane_map(self.lines, np.zeros(len(n)), n),
                    plane_map(self.lines, theta[:, 0], self.t1),
                    plane_map(self.lines, theta[:, 0], self.t2),
                ],
                axis=1,
            )
            @ Z[:, None]
        )
        dH = left[:, :, None] @ dG[:, None]
        return H, dH

    def inside(
        self, theta: np.ndarray, level: int, hwin: int, sizes: list[tuple[int, int]], margin: float
    ) -> np.ndarray:
        """(B, K): the patch's corners land inside view k's level image, in front of it."""
        H, _ = self.homographies(theta, level, derivatives=False)
        corners = np.array([[-hwin, -hwin, 1], [hwin, -hwin, 1], [-hwin, hwin, 1], [hwin, hwin, 1]])
        p = np.swapaxes(H @ corners.T.astype(float), -1, -2)
        w = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = p[..., 0] / w, p[..., 1] / w
        size = np.array(sizes, float)
        m = margin / 2.0**level
        ok = (
            (w > 0)
            & (u >= m)
            & (v >= m)
            & (u <= size[None, :, None, 0] - 1 - m)
            & (v <= size[None, :, None, 1] - 1 - m)
        )
        return ok.all(axis=-1)
