"""DEM to Cartesian triangle mesh, and mesh export for inspection (PLY, OBJ, GLB).

The mesh lives in a *local* frame: world coordinates minus ``origin`` (a float64 point near the
DEM centre). Ray casting is float32, and at lunar radius float32 resolves only 0.12 m, while
local coordinates of a DEM tile keep millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from orthomvp.errors import InputError
from orthomvp.palette import VIS_RGB
from orthomvp.raster import atomic_path
from orthomvp.terrain import Terrain

EXPORT_FORMATS = (".ply", ".obj", ".glb")
COLOUR_KINDS = ("image", "visibility", "error")
ERROR_CMAP = "RdBu_r"
"""Matplotlib colour map of height errors: negative blue, zero white, positive red."""
NAN_GREY = "#808080"
"""Colour of posts without a value (NaN), mid grey."""


@dataclass
class TerrainMesh:
    """A DEM triangulated in the world frame.

    ``mesh.vertices`` are local (world minus ``origin``), float64. ``vertex_post`` gives, for
    each vertex, its flat post index ``r * cols + c`` in the DEM grid. Each grid cell with four
    valid corners gives two triangles; a triangle with a hole at any corner is left out.
    """

    mesh: trimesh.Trimesh
    origin: np.ndarray
    vertex_post: np.ndarray
    grid_shape: tuple[int, int]

    @property
    def world_vertices(self) -> np.ndarray:
        """Vertex coordinates in the world frame, float64 (n, 3)."""
        return self.mesh.vertices + self.origin

    @property
    def uv(self) -> np.ndarray:
        """Texture coordinates in [0, 1] from grid position (u along columns, v up the rows)."""
        rows, cols = self.grid_shape
        r, c = np.divmod(self.vertex_post, cols)
        return np.column_stack([(c + 0.5) / cols, 1.0 - (r + 0.5) / rows])


def grid_triangles(valid: np.ndarray) -> np.ndarray:
    """Triangles (as flat post indices, (n, 3)) of a grid, two per cell, skipping holes.

    Cell (c, r)-(c+1, r+1) splits along the diagonal from (c+1, r) to (c, r+1).
    """
    rows, cols = valid.shape
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    d, e = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tris = np.concatenate([np.column_stack([a, d, b]), np.column_stack([b, d, e])])
    ok = valid.ravel()[tris].all(axis=1)
    return tris[ok]


def terrain_mesh(
    terrain: Terrain, values: np.ndarray | None = None, origin: np.ndarray | None = None
) -> TerrainMesh:
    """Triangulate ``terrain`` (or other ``values`` on its grid) in the world frame.

    ``origin`` defaults to the world position of the valid post nearest the grid centre. Faces
    are wound so that their normals point up (away from the body centre, or +z in a map frame).
    """
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
    origin = np.asarray(origin, dtype=np.float64)
    in_use = np.zeros(len(pts), bool)
    in_use[tris.ravel()] = True
    used = np.flatnonzero(in_use)
    faces = (np.cumsum(in_use) - 1)[tris]
    local = pts[used] - origin
    # Wind faces so that the normals point up. All faces share one winding (the grid is regular);
    # decide it by an area-weighted vote of faces spread over the grid, since a single face can
    # be degenerate (posts at a pole coincide) and then tells nothing.
    v = local[faces[:: max(1, len(faces) // 1000)]]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    if np.einsum("ij,ij->", n, t.up_vectors(v.mean(axis=1) + origin)) < 0:
        faces = faces[:, ::-1]
    mesh = trimesh.Trimesh(local, faces, process=False, validate=False)
    return TerrainMesh(mesh, origin, used, t.shape)


def colours_from_raster(
    data: np.ndarray, tmesh: TerrainMesh, kind: str = "image", limit: float | None = None
) -> np.ndarray:
    """Per-vertex RGBA uint8 colours (n, 4) from a raster on the DEM grid.

    ``data`` is (rows, cols), (rows, cols, bands) or band-first (bands, rows, cols) as read by
    :func:`orthomvp.raster.read_image`. ``kind`` says what it holds:

    - ``"image"``: grey or RGB (the first three bands). uint8 is taken as it is; other data is
      stretched between its 1st and 99th percentiles; NaN becomes mid grey.
    - ``"visibility"``: one band of codes 0-3 (:mod:`orthomvp.visibility`; NaN counts as 0), in
      the fixed colours of :data:`orthomvp.palette.VIS_RGB`.
    - ``"error"``: one band of height errors in metres, coloured by the diverging map
      :data:`ERROR_CMAP` from ``-limit`` (blue) through 0 (white) to ``+limit`` (red), clipped;
      ``limit`` defaults to :func:`error_colour_limit`; NaN becomes mid grey.
    """
    if kind not in COLOUR_KINDS:
        raise InputError(f"colour kind must be one of {', '.join(COLOUR_KINDS)}, not {kind!r}")
    arr = _on_grid(data, tmesh.grid_shape)
    if kind != "image" and arr.shape[-1] != 1:
        raise InputError(f"a {kind} raster has one band, this one has {arr.shape[-1]}")
    if kind == "visibility":
        codes = np.where(np.isfinite(arr[..., 0]), arr[..., 0], 0)
        if not np.isin(codes, list(VIS_RGB)).all():
            raise InputError(
                "the visibility raster holds values other than the codes 0 (outside), "
                "1 (visible), 2 (occluded) and 3 (facing away)"
            )
        rgb = vis_palette()[codes.astype(np.intp).ravel()[tmesh.vertex_post]]
    elif kind == "error":
        from matplotlib import colormaps
        from matplotlib.colors import Normalize

        err = arr[..., 0].astype(np.float64).ravel()
        lim = error_colour_limit(err, limit)
        cmap = colormaps[ERROR_CMAP].with_extremes(bad=NAN_GREY)
        rgb = cmap(Normalize(-lim, lim, clip=True)(err[tmesh.vertex_post]), bytes=True)[:, :3]
    else:
        arr = arr[..., :3] if arr.shape[-1] >= 3 else np.repeat(arr[..., :1], 3, axis=-1)
        if arr.dtype != np.uint8:
            f = arr.astype(np.float64)
            finite = np.isfinite(f)
            if not finite.any():
                raise InputError("texture raster holds no valid values")
            lo, hi = np.percentile(f[finite], [1, 99])
            f = np.clip((f - lo) / max(hi - lo, 1e-12), 0, 1) * 255
            f[~finite] = 128
            arr = f.astype(np.uint8)
        rgb = arr.reshape(-1, 3)[tmesh.vertex_post]
    return np.column_stack([rgb, np.full(len(rgb), 255, np.uint8)])


def vis_palette() -> np.ndarray:
    """RGB uint8 (4, 3) of the visibility codes 0-3: :data:`orthomvp.palette.VIS_RGB`."""
    return np.array([VIS_RGB[k] for k in range(4)], np.uint8)


def error_colour_limit(error: np.ndarray, limit: float | None = None) -> float:
    """The half-range in metres of the error colour scale: ``limit`` when given (it must be
    positive), else the 99th percentile of ``|error|`` over its finite values (at least 1 mm)."""
    if limit is not None:
        if not limit > 0:
            raise InputError(f"the error colour limit must be positive metres, got {limit}")
        return float(limit)
    err = np.abs(np.asarray(error, dtype=np.float64))
    finite = np.isfinite(err)
    if not finite.any():
        raise InputError("the error raster holds no valid values")
    return max(float(np.percentile(err[finite], 99)), 1e-3)


def height_error(terrain: Terrain, truth: Terrain) -> np.ndarray:
    """``terrain - truth`` (rows, cols) in the DEMs' value units (metres), NaN where either has
    a hole; the two must share one grid (shape, georeference and CRS)."""
    same = (
        terrain.shape == truth.shape
        and terrain.transform.almost_equals(truth.transform)
        and terrain.crs == truth.crs
    )
    if not same:
        rows, cols = truth.shape
        raise InputError(
            f"{truth.name}: the truth DEM ({cols} x {rows} posts) is not on the grid of "
            f"{terrain.name} ({terrain.shape[1]} x {terrain.shape[0]} posts, same georeference "
            "and CRS needed): resample it onto the DEM grid first"
        )
    return terrain.values - truth.values


def _on_grid(data: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A raster as (rows, cols, bands), from (rows, cols), (rows, cols, bands) or band-first
    (bands, rows, cols); InputError unless it is on the grid of ``shape`` (rows, cols)."""
    arr = np.asarray(data)
    if arr.ndim == 2:
        arr = arr[..., None]
    elif arr.ndim == 3 and arr.shape[1:] == shape and arr.shape[:2] != shape:
        arr = np.moveaxis(arr, 0, -1)
    if arr.ndim != 3 or arr.shape[:2] != shape:
        size = arr.shape[1:] if arr.ndim == 3 and arr.shape[0] < 5 else arr.shape[:2]
        raise InputError(
            f"the raster is {size[-1]} x {size[0]} (columns x rows) but the DEM grid is "
            f"{shape[1]} x {shape[0]}: give a raster on the DEM grid"
        )
    return arr


def export_mesh(
    tmesh: TerrainMesh,
    path: str | Path,
    texture: np.ndarray | None = None,
    local: bool = False,
    target_triangles: int | None = None,
    colour_kind: str = "image",
    error_limit: float | None = None,
) -> None:
    """Write the mesh as PLY (vertex colours), OBJ or GLB (image texture, UVs from the grid).

    Vertices are in the world frame (body-fixed metres) unless ``local`` is set. ``texture`` is a
    raster on the DEM grid, coloured as ``colour_kind`` says (see :func:`colours_from_raster`,
    whose ``limit`` is ``error_limit``). OBJ writes its material (NAME.mtl) and texture image
    (NAME.png) beside it; GLB embeds the image and keeps float32 vertices local, the origin
    being its node's transform. With ``target_triangles`` the mesh is first decimated with
    Open3D; the colours then travel as vertex colours in every format. Files are written
    atomically.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in EXPORT_FORMATS:
        raise InputError(f"{path}: mesh format must be one of {', '.join(EXPORT_FORMATS)}")
    colours = (
        None if texture is None else colours_from_raster(texture, tmesh, colour_kind, error_limit)
    )
    if target_triangles is not None:
        mesh = decimate(tmesh.mesh, target_triangles, colours)
    else:
        mesh = trimesh.Trimesh(tmesh.mesh.vertices, tmesh.mesh.faces, process=False)
        if colours is not None and suffix == ".ply":
            mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)
        elif colours is not None:
            from PIL import Image

            rows, cols = tmesh.grid_shape
            img = np.full((rows * cols, 3), 128, np.uint8)
            img[tmesh.vertex_post] = colours[:, :3]
            image = Image.fromarray(img.reshape(rows, cols, 3))
            # Name the material (and so the OBJ's texture file) after the output file, so that
            # two meshes exported to one directory do not share one 'material_0.png'. A white
            # diffuse colour (glTF base colour factor) and no specular shine leave the texture's
            # colours as they are; trimesh's default 0.4 grey would darken them.
            white, black = (255, 255, 255, 255), (0, 0, 0, 255)
            material = trimesh.visual.material.SimpleMaterial(
                image=image, diffuse=white, ambient=white, specular=black, name=path.stem
            )
            mesh.visual = trimesh.visual.TextureVisuals(uv=tmesh.uv, material=material)
    offset = np.zeros(3) if local else tmesh.origin
    if suffix == ".glb":
        # glTF vertices are float32 (0.12 m at lunar radius): keep them local and carry the
        # offset, in full precision, as the node's transform.
        scene = trimesh.Scene()
        scene.add_geometry(mesh, transform=trimesh.transformations.translation_matrix(offset))
        with atomic_path(path) as tmp:
            tmp.write_bytes(scene.export(file_type="glb"))
        return
    mesh.vertices = mesh.vertices + offset
    if suffix == ".obj":
        _export_obj(mesh, path)
    else:
        write_ply(mesh, path)


def write_ply(mesh: trimesh.Trimesh, path: str | Path) -> None:
    """Write ``mesh`` as binary PLY with float64 vertices (trimesh writes float32: 0.12 m at
    lunar radius) and its vertex colours (RGBA uint8), if any, atomically."""
    fields = [("xyz", "<f8", 3)]
    props = [f"property double {a}" for a in "xyz"]
    colours = mesh.visual.vertex_colors if mesh.visual.kind == "vertex" else None
    if colours is not None:
        fields.append(("rgba", "u1", 4))
        props += [f"property uchar {c}" for c in ("red", "green", "blue", "alpha")]
    vert = np.empty(len(mesh.vertices), fields)
    vert["xyz"] = mesh.vertices
    if colours is not None:
        vert["rgba"] = colours
    face = np.empty(len(mesh.faces), [("n", "u1"), ("idx", "<i4", 3)])
    face["n"] = 3
    face["idx"] = mesh.faces
    header = [
        "ply",
        "format binary_little_endian 1.0",
        f"element vertex {len(vert)}",
        *props,
        f"element face {len(face)}",
        "property list uchar int vertex_indices",
        "end_header\n",
    ]
    with atomic_path(path) as tmp:
        tmp.write_bytes("\n".join(header).encode("ascii") + vert.tobytes() + face.tobytes())


def _export_obj(mesh: trimesh.Trimesh, path: Path) -> None:
    """OBJ with its material and texture image beside it, each file written atomically."""
    from trimesh.exchange.obj import export_obj

    text, files = export_obj(
        mesh, include_texture=True, return_texture=True, mtl_name=f"{path.stem}.mtl"
    )
    for name, blob in files.items():
        with atomic_path(path.parent / name) as tmp:
            tmp.write_bytes(blob)
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def decimate(
    mesh: trimesh.Trimesh, target_triangles: int, colours: np.ndarray | None = None
) -> trimesh.Trimesh:
    """Quadric decimation with Open3D to about ``target_triangles`` faces.

    ``colours`` (n, 4) uint8 per vertex are carried over: each remaining vertex takes the
    colour of the nearest vertex of ``mesh``. Unlike Open3D's averaging of merged vertices,
    this keeps categorical colours (visibility codes) within their table.
    """
    import open3d as o3d
    from scipy.spatial import cKDTree

    if target_triangles < 4:
        raise InputError("decimation target must be at least 4 triangles")
    o3 = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(mesh.vertices)),
        o3d.utility.Vector3iVector(np.asarray(mesh.faces, dtype=np.int32)),
    )
    small = o3.simplify_quadric_decimation(target_number_of_triangles=int(target_triangles))
    out = trimesh.Trimesh(
        np.asarray(small.vertices), np.asarray(small.triangles), process=False, validate=False
    )
    if colours is not None:
        _, nearest = cKDTree(mesh.vertices).query(out.vertices)
        out.visual = trimesh.visual.ColorVisuals(out, vertex_colors=colours[nearest])
    return out
