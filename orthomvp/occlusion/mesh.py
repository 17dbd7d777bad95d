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
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import row_norms
from orthomvp.optional import require
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


def grid_triangles(valid: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
    """Triangles (as flat post indices, (n, 3) int32) of a grid, two per cell, skipping holes;
    only of the cells ``where`` (rows - 1, cols - 1) is True, when given.

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
    if valid.all() and where is None:
        return tris
    first, second = cell_triangles(valid)
    if where is not None:
        first, second = first & where, second & where
    return tris[np.concatenate([first.ravel(), second.ravel()])]


def cell_triangles(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which cells (rows - 1, cols - 1) of a grid with ``valid`` posts have their first
    triangle ((c, r), (c, r+1), (c+1, r)) and their second ((c+1, r), (c, r+1), (c+1, r+1)):
    those whose three posts are all valid (:func:`grid_triangles` lists the first triangles of
    all cells, then the second ones)."""
    return (
        valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:],
        valid[:-1, 1:] & valid[1:, :-1] & valid[1:, 1:],
    )


def terrain_mesh(
    terrain: Terrain,
    values: np.ndarray | None = None,
    origin: np.ndarray | None = None,
    *,
    where: np.ndarray | None = None,
) -> TerrainMesh:
    """Triangulate ``terrain`` (or other ``values`` on its grid) in the world frame; only the
    cells ``where`` (rows - 1, cols - 1) bool is True, when given.

    ``origin`` defaults to the world position of the valid post nearest the grid centre. Faces
    are wound so that their normals point up (away from the body centre, or +z in a map frame).
    """
    of_type(terrain, Terrain, "terrain")
    t = terrain if values is None else terrain.with_values(values)
    pts = t.world_points().reshape(-1, 3)
    valid = t.valid
    tris = grid_triangles(valid, where)
    if len(tris) == 0:
        raise InputError(f"{terrain.name}: no grid cell has four valid posts; nothing to mesh")
    if origin is None:
        rows, cols = t.shape
        r, c = np.nonzero(valid)
        k = np.argmin((r - (rows - 1) / 2) ** 2 + (c - (cols - 1) / 2) ** 2)
        origin = pts[r[k] * cols + c[k]]
    origin = np.array(origin, dtype=np.float64)  # a copy: pts changes below
    if valid.all() and where is None:  # every post is a vertex, in grid order: no remapping
        used, faces, local = np.arange(len(pts)), tris, pts
        local -= origin  # pts is this function's own array
    else:
        used, faces = _in_use(tris, len(pts))
        local = pts[used] - origin
    return TerrainMesh(local, _wound_up(t, local, faces, origin), origin, used, t.shape)


def _in_use(tris: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The points (of ``n``) that triangles ``tris`` (m, 3) use, ascending, and the triangles
    as indices into them (int32): what ``np.unique(tris, return_inverse=True)`` gives, in
    linear time."""
    in_use = np.zeros(n, bool)
    in_use[tris.ravel()] = True
    return np.flatnonzero(in_use), (np.cumsum(in_use, dtype=np.int32) - 1)[tris]


def _wound_up(t: Terrain, local: np.ndarray, faces: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """``faces`` wound so that their normals point up."""
    if points_down(t, local, faces, origin):
        faces = faces[:, ::-1]
    return np.ascontiguousarray(faces, dtype=np.int32)  # what Embree shares


def points_down(t: Terrain, local: np.ndarray, faces: np.ndarray, origin: np.ndarray) -> bool:
    """Whether the normals of ``faces`` (indices into ``local`` vertices, world metres minus
    ``origin``) point down on ``t``'s body or map. All faces of a grid share one winding;
    decided by an area-weighted vote of up to about 1000 faces spread over them, since a
    single face can be degenerate (posts at a pole coincide) and then tells nothing."""
    v = local[faces[:: max(1, len(faces) // 1000)]]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return bool(np.einsum("ij,ij->", n, t.up_vectors(v.mean(axis=1) + origin)) < 0)


STEP_SLOPE = 3.0
"""Rise over run between two neighbouring posts (71.6 degrees) above which the occluder
surface takes the step between them as a wall halfway between them (:func:`occluder_mesh`)."""


def occluder_mesh(
    terrain: Terrain, origin: np.ndarray | None = None, *, where: np.ndarray | None = None
) -> TerrainMesh:
    """The surface that visibility casts on: the DEM mesh, with every step between two
    neighbouring posts steeper than :data:`STEP_SLOPE` made a wall halfway between them.

    The point halfway along a step takes the higher post's height, and the centre of a cell with
    a step on any edge the highest of its four posts; such a cell is a fan of eight triangles
    about its centre, so the step stands at full height from the line halfway between the posts,
    where a wall between posts stands (the DEM posts as cells, pixel-is-area), instead of a
    slope spread over the whole cell that lets the wall's shadow fall short. Posts keep their
    own heights. Cells without a step keep the plain mesh's two triangles
    (:func:`terrain_mesh`); a neighbour of a stepped cell fans about its diagonal's midpoint
    through the midpoint of the edge they share (at the mean of its posts where the edge is no
    step), which leaves its surface that of the plain mesh and the mesh without cracks; a cell
    with a hole keeps its plain triangles and closes such an edge with the triangle from its
    posts to the midpoint. A DEM without a step gets :func:`terrain_mesh`'s mesh. Heights are
    DEM heights or means of two: never above the DEM's highest post. Each edge's slope uses only
    its two posts, so the surface over a window of the DEM is that of the whole DEM (tiling
    gives the same result). With steps, ``vertex_post`` indexes the refined grid of (2 rows - 1,
    2 cols - 1) points (posts, edge midpoints, cell centres). ``where`` (rows - 1, cols - 1)
    bool keeps only those cells' triangles: the same triangles as in the whole mesh, but on
    the grid's edge, where a cell's split depends on its neighbours. Why: see
    :func:`orthomvp.occlusion.visibility.default_eps`."""
    of_type(terrain, Terrain, "terrain")
    v = terrain.values
    rows, cols = v.shape
    p = terrain.world_points()

    def halfway(a: np.ndarray, b: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> tuple:
        """Heights halfway between posts a and b, and whether the edge is a step."""
        rise = np.abs(a - b)
        span = row_norms(pa - pb)
        with np.errstate(invalid="ignore"):
            step = rise > STEP_SLOPE * np.sqrt(np.maximum(span * span - rise * rise, 0.0))
        return np.where(step, np.maximum(a, b), (a + b) / 2), step

    fine = np.empty((2 * rows - 1, 2 * cols - 1))
    fine[::2, ::2] = v
    fine[1::2, ::2], down = halfway(v[:-1], v[1:], p[:-1], p[1:])  # (rows - 1, cols)
    fine[::2, 1::2], across = halfway(v[:, :-1], v[:, 1:], p[:, :-1], p[:, 1:])  # (rows, cols - 1)
    stepped = down[:, :-1] | down[:, 1:] | across[:-1] | across[1:]  # per cell
    top = np.maximum(np.maximum(v[:-1, :-1], v[:-1, 1:]), np.maximum(v[1:, :-1], v[1:, 1:]))
    fine[1::2, 1::2] = np.where(stepped, top, (v[:-1, 1:] + v[1:, :-1]) / 2)
    if not stepped.any():
        return terrain_mesh(terrain, origin=origin, where=where)
    # an edge is split at its midpoint when a cell on either side has a step
    split_down = np.zeros(down.shape, bool)
    split_down[:, :-1] |= stepped
    split_down[:, 1:] |= stepped
    split_across = np.zeros(across.shape, bool)
    split_across[:-1] |= stepped
    split_across[1:] |= stepped
    width = 2 * cols - 1

    def corners(cells: np.ndarray) -> tuple[np.ndarray, ...]:
        """Fine-grid indices of flat ``cells``' corners (r, c), (r, c+1), (r+1, c),
        (r+1, c+1) and centre."""
        cr, cc = np.divmod(cells, cols - 1)
        a = 2 * cr * width + 2 * cc
        return a, a + 2, a + 2 * width, a + 2 * width + 2, a + width + 1

    fan = split_across[:-1] | split_across[1:] | split_down[:, :-1] | split_down[:, 1:]
    fan &= np.isfinite(fine[1::2, 1::2])  # a cell with a hole does not fan
    tris = []
    for fanned in (True, False):
        cells = np.flatnonzero(fan == fanned if where is None else (fan == fanned) & where)
        a, b, d, e, m = corners(cells)
        # the cell's sides in one turn: (from, midpoint, to, split)
        sides = (
            (a, a + 1, b, split_across[:-1].ravel()[cells]),
            (b, m + 1, e, split_down[:, 1:].ravel()[cells]),
            (e, d + 1, d, split_across[1:].ravel()[cells]),
            (d, m - 1, a, split_down[:, :-1].ravel()[cells]),
        )
        if not fanned:
            tris += [np.stack([a, d, b], -1), np.stack([b, d, e], -1)]
        for s0, mid, s1, split in sides:
            if fanned:
                tris += [
                    np.stack([m, mid, s0], -1)[split],
                    np.stack([m, s1, mid], -1)[split],
                    np.stack([m, s1, s0], -1)[~split],
                ]
            else:  # only a cell with a hole has split sides here: it closes them
                tris.append(np.stack([s0, s1, mid], -1)[split])
    tris = np.concatenate(tris)
    finite = np.isfinite(fine).ravel()
    if not finite.all():
        tris = tris[finite[tris].all(axis=1)]
    if len(tris) == 0:
        raise InputError(f"{terrain.name}: no grid cell has four valid posts; nothing to mesh")
    used, faces = _in_use(tris, fine.size)
    fr, fc = np.divmod(used, width)
    pts = terrain.to_world(fc / 2.0, fr / 2.0, fine.ravel()[used])
    if origin is None:  # the meshed point nearest the grid centre
        k = np.argmin((fr - (rows - 1)) ** 2 + (fc - (cols - 1)) ** 2)
        origin = pts[k]
    origin = np.asarray(origin, dtype=np.float64)
    local = pts - origin
    return TerrainMesh(local, _wound_up(terrain, local, faces, origin), origin, used, fine.shape)
