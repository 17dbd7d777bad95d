"""First-hit ray casting against a terrain mesh: Embree (default; the library bundled with
embreex, through :mod:`orthomvp.occlusion.embree`) or Open3D.

The backend's library is loaded when a caster is built. Both backends work
in float32, so the scene is built in the mesh's local frame (see
:mod:`orthomvp.occlusion.mesh`) and each ray origin is first moved, in float64, along its ray to the
near side of the mesh's bounding sphere. The float32 cast then spans only the scene's own size:
for a tile of tens of kilometres the hit points keep millimetres, even 100 km and more from the
camera at lunar radius (tested against exact float64 intersections).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from orthomvp.errors import InputError
from orthomvp.geometry.vectors import column_range
from orthomvp.occlusion.embree import Scene, vertex_buffer
from orthomvp.occlusion.mesh import TerrainMesh
from orthomvp.optional import require

BACKENDS = ("embree", "open3d")
CHUNK = 1 << 17


@dataclass
class Hits:
    """Result of :meth:`RayCaster.first_hit` for n rays.

    ``distance`` along the (unit) ray in metres (inf on a miss), ``triangle`` index into the
    mesh faces (-1), ``barycentric`` (u, v) with hit = (1-u-v) v0 + u v1 + v v2 (NaN), ``points``
    world xyz float64 (NaN), ``mask`` True where the ray hit.
    """

    distance: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    points: np.ndarray
    mask: np.ndarray

    @classmethod
    def none(cls, n: int) -> Hits:
        """The result of ``n`` rays that hit nothing."""
        return cls(
            np.full(n, np.inf),
            np.full(n, -1, np.int64),
            np.full((n, 2), np.nan),
            np.full((n, 3), np.nan),
            np.zeros(n, bool),
        )


class RayCaster:
    """First-hit queries against a :class:`~orthomvp.occlusion.mesh.TerrainMesh`. ``bounds``: a box
    (low, high corners, local frame) holding the mesh, whose bounding sphere rays start at;
    default the mesh's own. Meshes of parts of one surface, with its origin and box, cast as
    the whole does (to an ulp of the hits' distances; a ray through a vertex may meet it on
    one and slip past on the other)."""

    def __init__(
        self,
        tmesh: TerrainMesh,
        backend: str = "embree",
        threads: int | None = None,
        *,
        bounds: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        if backend not in BACKENDS:
            raise InputError(f"ray-casting backend must be one of {BACKENDS}, not {backend!r}")
        if not isinstance(tmesh, TerrainMesh):
            raise InputError(
                f"a ray caster needs a TerrainMesh (orthomvp.occlusion.mesh.terrain_mesh), got "
                f"{type(tmesh).__name__}"
            )
        self.tmesh = tmesh
        self.backend = backend
        self.threads = threads or os.cpu_count() or 1
        verts = np.asarray(tmesh.vertices, dtype=np.float64)
        lo, hi = column_range(verts) if bounds is None else bounds
        self._centre = (lo + hi) / 2
        self._radius = float(np.linalg.norm(hi - lo) / 2) * 1.001 + 1.0
        faces = np.asarray(tmesh.faces, dtype=np.int32)
        if backend == "embree":
            v32 = vertex_buffer(len(verts))
            v32[:] = verts
            self._scene = Scene(v32, faces)  # shares v32 and faces; builds the BVH
        else:
            self._o3d = o3d = require("open3d", "Open3D ray casting")
            self._scene = o3d.t.geometry.RaycastingScene()
            self._scene.add_triangles(
                o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(faces.view(np.uint32))
            )
            # The first query builds the acceleration structure; do it now, on one thread.
            self.raw_cast(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))

    def raw_cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, ...]:
        """The bare backend call on float32 local-frame rays: (t, triangle, u, v), triangle
        -1 on a miss."""
        if self.backend == "embree":
            return self._scene.intersect(origins, directions)
        rays = self._o3d.core.Tensor(np.hstack([origins, directions]).astype(np.float32))
        out = self._scene.cast_rays(rays, nthreads=self.threads)
        tri = out["primitive_ids"].numpy().view(np.int32)  # uint32 max on a miss: -1
        uv = out["primitive_uvs"].numpy()
        return out["t_hit"].numpy(), tri, uv[:, 0], uv[:, 1]

    def first_hit(
        self, origins: np.ndarray, directions: np.ndarray, *, invalid: str = "raise"
    ) -> Hits:
        """First intersection of each ray with the mesh; world-frame float64 in and out.

        ``origins`` and ``directions`` are (n, 3) or (3,), broadcast against each other (one
        origin for many directions or one direction for many origins); directions need not be
        unit length. Only hits in front of the origin count. InputError for other shapes or
        values that are not numbers; rays with a non-finite origin or direction, or a zero
        direction, are refused too (InputError) with ``invalid="raise"``, or are misses with
        ``invalid="miss"`` (the engine's own rays through pixels a camera model cannot map).
        """
        if invalid not in ("raise", "miss"):
            raise InputError(f"invalid must be raise or miss, not {invalid!r}")
        o, d = (
            _rays(v, name, invalid)
            for name, v in (("origins", origins), ("directions", directions))
        )
        try:
            o, d = np.broadcast_arrays(o, d)
        except ValueError:
            raise InputError(
                f"origins {o.shape} and directions {d.shape} do not match: give as many of "
                "each, or one of either"
            ) from None
        norm = np.linalg.norm(d, axis=-1, keepdims=True)
        if invalid == "raise" and not norm.all():
            raise InputError(f"direction {np.flatnonzero(norm[:, 0] == 0)[0]} is zero")
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = d / norm
        n = len(d)
        dist = np.full(n, np.inf)
        tri = np.full(n, -1, np.int64)
        bary = np.full((n, 2), np.nan)
        starts = range(0, n, CHUNK)

        def work(s: int) -> None:
            sl = slice(s, min(s + CHUNK, n))
            self._cast_chunk(o[sl], unit[sl], dist[sl], tri[sl], bary[sl])

        # Chunks run in parallel threads (both backends release the GIL): Embree calls are
        # single-threaded, and for Open3D the float64 work on one chunk overlaps the next cast.
        if self.threads > 1 and n > CHUNK:
            with ThreadPoolExecutor(self.threads) as pool:
                list(pool.map(work, starts))
        else:
            for s in starts:
                work(s)
        mask = tri >= 0
        points = np.full((n, 3), np.nan)  # (inf * unit on a miss would warn)
        points[mask] = o[mask] + dist[mask, None] * unit[mask]
        return Hits(dist, tri, bary, points, mask)

    def _cast_chunk(
        self, o: np.ndarray, d: np.ndarray, dist: np.ndarray, tri: np.ndarray, bary: np.ndarray
    ) -> None:
        """Cast one chunk of rays with unit directions ``d``; fill dist, tri, bary in place."""
        oc = o - (self.tmesh.origin + self._centre)  # relative to the bounding-sphere centre
        if oc.strides[0] == 0:  # one origin for all rays (a broadcast view): keep it (3,)
            oc = oc[:1]
        tc = -(d @ oc[0]) if len(oc) == 1 else -np.einsum("ij,ij->i", oc, d)
        # squared distance of the ray's closest approach to the centre (d is unit length)
        miss2 = np.einsum("ij,ij->i", oc, oc) - tc * tc
        reach = np.flatnonzero(miss2 < self._radius**2)  # NaN directions compare False
        if not reach.size:
            return
        # Start each ray at the sphere's near side (or at its origin when already inside).
        t0 = np.maximum(tc[reach] - np.sqrt(self._radius**2 - miss2[reach]), 0.0)
        start = (oc[0] if len(oc) == 1 else oc[reach]) + t0[:, None] * d[reach] + self._centre
        t, hit_tri, u, v = self.raw_cast(start.astype(np.float32), d[reach].astype(np.float32))
        hit = hit_tri >= 0
        idx = reach[hit]
        dist[idx] = t0[hit] + t[hit]
        tri[idx] = hit_tri[hit]
        bary[idx, 0] = u[hit]
        bary[idx, 1] = v[hit]


def _rays(value: Any, name: str, invalid: str) -> np.ndarray:
    """``value`` as an (n, 3) float64 array (of finite numbers when ``invalid`` is "raise");
    InputError naming ``name``."""
    try:
        array = np.atleast_2d(np.asarray(value, dtype=np.float64))
    except (TypeError, ValueError):
        raise InputError(f"{name} must be numbers, (n, 3) or (3,), got {value!r:.40}") from None
    if array.ndim != 2 or array.shape[1] != 3:
        raise InputError(f"{name} must be (n, 3) or (3,), got shape {np.shape(value)}")
    if invalid == "raise" and not np.isfinite(array).all():  # (one pass; rows only to name one)
        bad = ~np.isfinite(array).all(axis=1)
        raise InputError(f"{name} {np.flatnonzero(bad)[0]} is not finite: {array[bad][0]}")
    return array
