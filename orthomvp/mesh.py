"""DEM to Cartesian triangle mesh (numpy arrays; export and colours: :mod:`orthomvp.present`).

The mesh lives in a *local* frame: world coordinates minus ``origin`` (a float64 point near the
DEM centre). Ray casting is float32, and at lunar radius float32 resolves only 0.12 m, while
local coordinates of a DEM tile keep millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.errors import InputError
from orthomvp.optional import require
from orthomvp.terrain import Terrain
from orthomvp.validate import of_type

if TYPE_CHECKING:
    import trimesh


@dataclass
class TerrainMesh:
    """A DEM triangulated in the world frame.

    ``vertices`` (n, 3) float64 are local: world metres minus ``origin`` (3,). ``faces`` (m, 3)
    int32 index the vertices, wound so that normals point up. ``vertex_post`` gives, for each
    vertex, its flat post index ``r * cols + c`` in the DEM grid of ``grid_shape`` (rows, cols).
    Each grid cell with four valid corners gives two triangles; a triangle with a hole at any
    corner is left out.
    """

    vertices: np.ndarray
    faces: np.ndarray
    origin: np.ndarray
    vertex_post: np.ndarray
    grid_shape: tuple[int, int]

    @property
    def world_vertices(self) -> np.ndarray:
        """Vertex coordinates in the world frame, float64 (n, 3)."""
        return self.vertices + self.origin

    @cached_property
    def mesh(self) -> trimesh.Trimesh:
        """The local-frame mesh as a ``trimesh.Trimesh`` (vertex normals, inspection, export),
        built on first use; needs trimesh."""
        trimesh = require("trimesh", "a trimesh view of the DEM mesh")
        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)

    @property
    def uv(self) -> np.ndarray:
        """Texture coordinates in [0, 1] from grid position (u along columns, v up the rows)."""
        rows, cols = self.grid_shape
        r, c = np.divmod(self.vertex_post, cols)
        return np.column_stack([(c + 0.5) / cols, 1.0 - (r + 0.5) / rows])


def grid_triangles(valid: np.ndarray) -> np.ndarray:
    """Triangles (as flat post indices, (n, 3) int32) of a grid, two per cell, skipping holes.

    Cell (c, r)-(c+1, r+1) splits along the diagonal from (c+1, r) to (c, r+1).
    """
    rows, cols = valid.shape
    if rows * cols >= 2**31:
        raise InputError(f"a mesh of {rows} x {cols} posts is too large (2**31 posts at most)")
    idx = np.arange(rows * cols, dtype=np.int32).reshape(rows, cols)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    d, e = idx[1:, :-1], idx[1:, 1:]
    cells = (rows - 1) * (cols - 1)
    tris = np.empty((2, rows - 1, cols - 1, 3), np.int32)
    for k, corners in enumerate(((a, d, b), (b, d, e))):
        for j, corner in enumerate(corners):
            tris[k, ..., j] = corner
    tris = tris.reshape(2 * cells, 3)
    if valid.all():
        return tris
    v = valid.ravel()
    return tris[v[tris[:, 0]] & v[tris[:, 1]] & v[tris[:, 2]]]


def terrain_mesh(
    terrain: Terrain, values: np.ndarray | None = None, origin: np.ndarray | None = None
) -> TerrainMesh:
    """Triangulate ``terrain`` (or other ``values`` on its grid) in the world frame.

    ``origin`` defaults to the world position of the valid post nearest the grid centre. Faces
    are wound so that their normals point up (away from the body centre, or +z in a map frame).
    """
    of_type(terrain, Terrain, "terrain")
    t = terrain if values is None else terrain.with_values(values)
    pts = t.world_points().reshape(-1, 3)
    valid = t.valid
    tris = grid_triangles(valid)
    if len(tris) == 0:
        raise InputError(f"{terrain.name}: no grid cell has four valid posts; nothing to mesh")
    if origin is None:
        rows, cols = t.shape
        r, c = np.nonzero(valid)
        k = np.argmin((r - (rows - 1) / 2) ** 2 + (c - (cols - 1) / 2) ** 2)
        origin = pts[r[k] * cols + c[k]]
    origin = np.array(origin, dtype=np.float64)  # a copy: pts changes below
    if valid.all():  # every post is a vertex, in grid order: no remapping
        used, faces, local = np.arange(len(pts)), tris, pts
        local -= origin  # pts is this function's own array
    else:
        in_use = np.zeros(len(pts), bool)
        in_use[tris.ravel()] = True
        used = np.flatnonzero(in_use)
        faces = (np.cumsum(in_use, dtype=np.int32) - 1)[tris]
        local = pts[used] - origin
    # Wind faces so that the normals point up. All faces share one winding (the grid is regular);
    # decide it by an area-weighted vote of faces spread over the grid, since a single face can
    # be degenerate (posts at a pole coincide) and then tells nothing.
    v = local[faces[:: max(1, len(faces) // 1000)]]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    if np.einsum("ij,ij->", n, t.up_vectors(v.mean(axis=1) + origin)) < 0:
        faces = np.ascontiguousarray(faces[:, ::-1])  # Embree shares contiguous faces
    return TerrainMesh(local, faces, origin, used, t.shape)
