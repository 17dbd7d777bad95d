"""A DEM of any size as a binary PLY mesh, written block by block of rows in bounded memory.

The file is the one :func:`orthomvp.present.export.write_ply` writes for
:func:`orthomvp.occlusion.mesh.terrain_mesh` of the whole DEM: the same vertices (every post of a
triangle, row by row, float64 world metres, or relative to the same local origin), the same
triangles in the same order (the first triangle of every grid cell, then the second, as
:func:`orthomvp.occlusion.mesh.grid_triangles` lists them) and winding, and the same vertex colours.
Only the colour stretch of a float texture (its 1st to 99th percentile) and the automatic
error limit (99th percentile of the absolute error) come from a decimated read when the raster
has more than :data:`STATS_POSTS` posts.

Three passes over the DEM, each holding one block of at most :data:`BLOCK_POSTS` posts: the
used posts per row (for the vertex numbering), the vertices, and the triangles (twice: first
triangles of the cells, then second ones).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import rasterio
from rasterio.enums import Resampling

from orthomvp.engine.grid import DemSource
from orthomvp.errors import InputError
from orthomvp.io.outputs import atomic_path
from orthomvp.io.raster import open_raster
from orthomvp.occlusion.mesh import cell_triangles, grid_triangles, points_down
from orthomvp.present.colours import (
    CODE_RGB,
    error_colour_limit,
    error_colours,
    image_colours,
    visibility_codes,
)
from orthomvp.present.texture import TextureSampler

BLOCK_POSTS = 1 << 22
"""DEM posts (at most) of one block of rows."""

STATS_POSTS = 1 << 24
"""Texture posts beyond which colour statistics come from a decimated read."""

Colours = Callable[[int, int, np.ndarray], np.ndarray]
"""``colours(r0, r1, used)``: RGBA (n, 4) uint8 of the used posts (mask (r1 - r0, cols))."""


def _use(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Posts of ``valid`` (rows, cols) that belong to a triangle of these rows, and the cells'
    first and second triangles that exist (see :func:`orthomvp.occlusion.mesh.cell_triangles`)."""
    t1, t2 = cell_triangles(valid)
    use = np.zeros_like(valid)
    use[:-1, :-1] |= t1
    use[1:, :-1] |= t1 | t2
    use[:-1, 1:] |= t1 | t2
    use[1:, 1:] |= t2
    return use, t1, t2


def _blocks(rows: int, cols: int) -> Iterator[tuple[int, int]]:
    step = max(1, BLOCK_POSTS // max(cols, 1))
    for r0 in range(0, rows, step):
        yield r0, min(r0 + step, rows)


def _used_rows(dem: DemSource, r0: int, r1: int) -> tuple[np.ndarray, np.ndarray]:
    """Values of post rows [r0, r1) and which of them are used (reading a row around)."""
    rows, cols = dem.shape
    a, b = max(r0 - 1, 0), min(r1 + 1, rows)
    values = dem.read((a, b, 0, cols))
    use, _, _ = _use(np.isfinite(values))
    return values[r0 - a : r1 - a], use[r0 - a : r1 - a]


def _origin(dem: DemSource) -> np.ndarray:
    """The world position of the valid post nearest the grid centre (as terrain_mesh picks):
    from windows about the centre, growing while they hold at most :data:`BLOCK_POSTS` posts,
    else from one pass over the blocks of rows."""
    rows, cols = dem.shape
    cr, cc = (rows - 1) / 2, (cols - 1) / 2
    k = 8
    while (2 * k + 2) ** 2 <= BLOCK_POSTS:
        window = (
            max(int(cr) - k, 0),
            min(int(cr) + k + 2, rows),
            max(int(cc) - k, 0),
            min(int(cc) + k + 2, cols),
        )
        found = _nearest(dem, window, cr, cc)
        if found is not None and (found[0] <= k or window == (0, rows, 0, cols)):
            return found[1]
        k *= 2
    best = None
    for r0, r1 in _blocks(rows, cols):
        found = _nearest(dem, (r0, r1, 0, cols), cr, cc)
        if found is not None and (best is None or found[0] < best[0]):
            best = found  # ties: the first in row order, as terrain_mesh's argmin
    if best is None:
        raise InputError(f"{dem.path}: no grid cell has four valid posts; nothing to mesh")
    return best[1]


def _nearest(
    dem: DemSource, window: tuple[int, int, int, int], cr: float, cc: float
) -> tuple[float, np.ndarray] | None:
    """The distance in posts from (``cc``, ``cr``) to the nearest valid post of ``window`` (the
    first in row order among equals) and its world position; None without one."""
    r0, _, c0, _ = window
    values = dem.read(window)
    r, c = np.nonzero(np.isfinite(values))
    if not len(r):
        return None
    d2 = (r + r0 - cr) ** 2 + (c + c0 - cc) ** 2
    j = int(np.argmin(d2))
    point = dem.geometry().to_world(
        np.float64(c[j] + c0), np.float64(r[j] + r0), values[r[j], c[j]]
    )
    return float(np.sqrt(d2[j])), point


def _winding(dem: DemSource, origin: np.ndarray) -> bool:
    """Whether the triangles must be flipped so that their normals point up
    (:func:`orthomvp.occlusion.mesh.points_down`), voted on a block of 64 rows at the grid centre,
    or on the first block of rows with a triangle where the centre has none."""
    rows, cols = dem.shape
    mid = max(rows // 2 - 32, 0)
    geo = dem.geometry()
    for r0, r1 in [(mid, min(mid + 64, rows)), *_blocks(rows, cols)]:
        values = dem.read((r0, min(r1 + 1, rows), 0, cols))
        tris = grid_triangles(np.isfinite(values))
        if len(tris):
            r, c = np.mgrid[r0 : r0 + len(values), 0:cols].astype(np.float64)
            local = geo.to_world(c, r, values).reshape(-1, 3) - origin
            return points_down(geo, local, tris, origin)
    raise InputError(f"{dem.path}: no grid cell has four valid posts; nothing to mesh")


def image_stretch(texture: TextureSampler) -> Colours:
    """Colours of a ``texture`` raster at the DEM's posts, as the ``mesh`` command gives them
    (:func:`~orthomvp.present.colours.image_colours` of the raster read as float32: grey or
    RGB, stretched from the 1st to the 99th percentile of its values at the posts, NaN posts
    and posts outside it grey). A raster on the DEM grid takes its statistics from its own
    values (:func:`_sample`), any other from its values at the DEM's posts (every post, or
    a regular subset of about :data:`STATS_POSTS`)."""
    if texture.count == 2:
        raise InputError("the texture raster must have 1 band (grey) or 3 or more (RGB), not 2")
    bands = list(range(1, min(texture.count, 3) + 1))
    if texture.on_grid:
        with open_raster(texture.path) as src:
            sample = _sample(src, bands)
    else:
        sample = _posts_sample(texture, bands)
    filled = np.isfinite(sample).all(axis=1)
    if not filled.any():
        raise InputError("the texture raster holds no valid values at the DEM's posts")
    stretch = tuple(np.percentile(sample[filled], [1, 99]))

    def colours(r0: int, r1: int, used: np.ndarray) -> np.ndarray:
        values = texture.read(r0, r1, bands)
        out = np.full((int(used.sum()), 4), 255, np.uint8)
        out[:, :3] = image_colours(values, "texture raster", stretch=stretch)[used.ravel()]
        return out

    return colours


def _sample(src: rasterio.DatasetReader, bands: list[int]) -> np.ndarray:
    """Values (n, bands) of ``bands`` (GDAL's scale and offset applied): all posts, or a
    decimated read of large rasters."""
    rows, cols = src.height, src.width
    step = max(1, int(np.ceil(np.sqrt(rows * cols / STATS_POSTS))))
    shape = (len(bands), -(-rows // step), -(-cols // step))
    data = src.read(bands, out_shape=shape, masked=True, resampling=Resampling.nearest)
    values = np.ma.filled(data.astype(np.float32), np.nan).astype(np.float64)
    values = values.reshape(len(bands), -1)
    scales = np.array([src.scales[b - 1] for b in bands])[:, None]  # as read_values: GDAL's
    offsets = np.array([src.offsets[b - 1] for b in bands])[:, None]  # scale and offset
    return (values * scales + offsets).T


def _posts_sample(texture: TextureSampler, bands: list[int]) -> np.ndarray:
    """Values (n, bands) of ``bands`` of the ``texture`` at the DEM's posts: every post, or
    every ``step``-th post of every ``step``-th row of a grid of more than
    :data:`STATS_POSTS`."""
    rows, cols = texture.shape
    step = max(1, int(np.ceil(np.sqrt(rows * cols / STATS_POSTS))))
    r, c = np.mgrid[0:rows:step, 0:cols:step]
    return texture.at(c.ravel(), r.ravel(), bands).astype(np.float64).T


def code_colours(texture: TextureSampler) -> Colours:
    """Colours of a visibility raster (codes 0-3) at the DEM's posts (code 0, no data, outside
    the raster)."""

    def colours(r0: int, r1: int, used: np.ndarray) -> np.ndarray:
        data = texture.read(r0, r1, [1])[0]
        codes = visibility_codes(data, data.shape)
        out = np.full((int(used.sum()), 4), 255, np.uint8)
        out[:, :3] = CODE_RGB[codes[used]]
        return out

    return colours


def error_against(truth: DemSource, dem: DemSource, limit: float | None) -> tuple[Colours, float]:
    """Colours of the height error ``dem - truth`` (metres; both on one grid), and the colour
    limit in metres (``limit``, else the 99th percentile of the absolute error)."""
    if truth.shape != dem.shape or truth.transform != dem.transform or truth.crs != dem.crs:
        raise InputError(f"{truth.path}: the truth DEM is not on the grid of {dem.path}")
    if limit is None:
        with open_raster(dem.path) as a, open_raster(truth.path) as b:
            limit = error_colour_limit(_sample(a, [1])[:, 0] - _sample(b, [1])[:, 0])

    def colours(r0: int, r1: int, used: np.ndarray) -> np.ndarray:
        cols = dem.shape[1]
        err = dem.read((r0, r1, 0, cols))[used] - truth.read((r0, r1, 0, cols))[used]
        out = np.full((len(err), 4), 255, np.uint8)
        out[:, :3] = error_colours(err, limit)
        return out

    return colours, float(limit)


def write_ply_stream(
    dem: DemSource, path: str | Path, *, colours: Colours | None = None, local: bool = False
) -> tuple[int, int, np.ndarray]:
    """Write the mesh of ``dem`` to ``path`` (binary PLY, atomically), with vertex ``colours``
    (see :data:`Colours`) and vertices relative to the local origin when ``local``; returns the
    vertex and triangle counts and the origin (world metres)."""
    path = Path(path)
    rows, cols = dem.shape
    per_row = np.zeros(rows, np.int64)
    faces = [0, 0]
    for r0, r1 in _blocks(rows, cols):
        _, use = _used_rows(dem, r0, r1)
        per_row[r0:r1] = use.sum(axis=1)
        b = min(r1 + 1, rows)
        _, t1, t2 = _use(np.isfinite(dem.read((r0, b, 0, cols))))
        faces[0] += int(t1.sum())
        faces[1] += int(t2.sum())
    start = np.concatenate([[0], np.cumsum(per_row)])
    n_vert, n_face = int(start[-1]), sum(faces)
    if n_face == 0:
        raise InputError(f"{dem.path}: no grid cell has four valid posts; nothing to mesh")
    origin = _origin(dem)
    flip = _winding(dem, origin)
    props = [f"property double {a}" for a in "xyz"]
    vert_type = [("xyz", "<f8", 3)]
    if colours is not None:
        props += [f"property uchar {c}" for c in ("red", "green", "blue", "alpha")]
        vert_type.append(("rgba", "u1", 4))
    header = "\n".join(
        [
            "ply",
            "format binary_little_endian 1.0",
            f"element vertex {n_vert}",
            *props,
            f"element face {n_face}",
            "property list uchar int vertex_indices",
            "end_header\n",
        ]
    ).encode("ascii")
    size = len(header) + n_vert * np.dtype(vert_type).itemsize + n_face * 13
    geo = dem.geometry()
    with atomic_path(path, size=size) as tmp, open(tmp, "wb") as out:
        out.write(header)
        for r0, r1 in _blocks(rows, cols):
            values, use = _used_rows(dem, r0, r1)
            r, c = np.nonzero(use)
            p = geo.to_world(c.astype(np.float64), (r + r0).astype(np.float64), values[r, c])
            vert = np.empty(len(r), vert_type)
            vert["xyz"] = (p - origin) if local else (p - origin) + origin
            if colours is not None:
                vert["rgba"] = colours(r0, r1, use)
            out.write(vert.tobytes())
        for which in (1, 2):
            for r0, r1 in _blocks(rows - 1, cols):
                out.write(_faces(dem, r0, r1, which, start, flip).tobytes())
    return n_vert, n_face, origin


def _faces(
    dem: DemSource, r0: int, r1: int, which: int, start: np.ndarray, flip: bool
) -> np.ndarray:
    """The first (``which`` 1) or second triangles of the cells of rows [r0, r1), as PLY face
    records with global vertex numbers."""
    rows, cols = dem.shape
    a, b = max(r0 - 1, 0), min(r1 + 2, rows)
    values = dem.read((a, b, 0, cols))
    use, t1, t2 = _use(np.isfinite(values))
    rank = np.cumsum(use, axis=1) - 1 + start[a:b, None]  # vertex number of each used post
    cells = (t1 if which == 1 else t2)[r0 - a : r1 - a]
    r, c = np.nonzero(cells)
    r = r + (r0 - a)
    if which == 1:
        tri = np.column_stack([rank[r, c], rank[r + 1, c], rank[r, c + 1]])
    else:
        tri = np.column_stack([rank[r, c + 1], rank[r + 1, c], rank[r + 1, c + 1]])
    face = np.empty(len(tri), [("n", "u1"), ("idx", "<i4", 3)])
    face["n"] = 3
    face["idx"] = tri[:, ::-1] if flip else tri
    return face
