"""Mesh export for inspection in other tools: PLY (vertex colours), OBJ and GLB (image texture),
optionally decimated with Open3D. Colours come from :mod:`orthomvp.present.colours`.

trimesh, Open3D and scipy.spatial are imported only here, when a mesh is written or decimated.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.errors import InputError
from orthomvp.io.output_checks import API_FLAGS, Output, check_outputs
from orthomvp.io.outputs import atomic_path, write_set
from orthomvp.occlusion.mesh import TerrainMesh
from orthomvp.optional import require
from orthomvp.present.colours import NAN_RGB, post_colours
from orthomvp.validate import of_type

if TYPE_CHECKING:
    import trimesh

EXPORT_FORMATS = (".ply", ".obj", ".glb")


def export_mesh(
    tmesh: TerrainMesh,
    path: str | Path,
    texture: np.ndarray | None = None,
    local: bool = False,
    target_triangles: int | None = None,
    colour_kind: str = "image",
    error_limit: float | None = None,
    texture_image: np.ndarray | None = None,
    *,
    overwrite: bool = False,
) -> None:
    """Write the mesh as PLY (vertex colours), OBJ or GLB (image texture, UVs from the grid).

    Vertices are in the world frame (body-fixed metres) unless ``local`` is set. ``texture`` is a
    raster on the DEM grid, coloured as ``colour_kind`` says (see
    :func:`orthomvp.present.colours.post_colours`, whose ``limit`` is ``error_limit``). OBJ
    writes its material (NAME.mtl) and texture image (NAME.png) beside it; GLB embeds the image
    and keeps float32 vertices local, the origin being its node's transform. Their image has
    one texel per post, or is ``texture_image`` when given: a raster over the DEM grid's
    extent ``k`` times finer ((bands, k * rows, k * cols), as
    :func:`orthomvp.present.texture.finer_grid` samples it), coloured as ``texture``. With
    ``target_triangles`` the mesh is first decimated with Open3D; the colours then travel as
    vertex colours in every format. Files are written atomically; a file that exists
    (OBJ's material and image too) is refused with an InputError unless ``overwrite``.
    """
    of_type(tmesh, TerrainMesh, "the mesh", " (orthomvp.occlusion.mesh.terrain_mesh)")
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in EXPORT_FORMATS:
        raise InputError(f"{path}: mesh format must be one of {', '.join(EXPORT_FORMATS)}")
    check_outputs([Output("export_mesh", path, ())], overwrite=overwrite, flags=API_FLAGS)
    trimesh = require("trimesh", "mesh export")
    colours = None
    if texture is not None:
        rgb = post_colours(texture, tmesh.grid_shape, colour_kind, error_limit)[tmesh.vertex_post]
        colours = np.column_stack([rgb, np.full(len(rgb), 255, np.uint8)])
    if target_triangles is not None:
        mesh = decimate(tmesh.mesh, target_triangles, colours)
    else:
        mesh = trimesh.Trimesh(tmesh.vertices, tmesh.faces, process=False)
        if colours is not None and suffix == ".ply":
            mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)
        elif colours is not None:
            image = None
            if texture_image is not None:
                fine = np.shape(texture_image)[-2:]
                image = post_colours(texture_image, fine, colour_kind, error_limit)
                image = image.reshape(*fine, 3)
            mesh.visual = _texture_visuals(tmesh, colours[:, :3], path.stem, image)
    offset = np.zeros(3) if local else tmesh.origin
    if suffix == ".glb":
        # glTF vertices are float32 (0.12 m at lunar radius): keep them local and carry the
        # offset, in full precision, as the node's transform.
        scene = trimesh.Scene()
        scene.add_geometry(mesh, transform=trimesh.transformations.translation_matrix(offset))
        blob = scene.export(file_type="glb")
        with atomic_path(path, size=len(blob)) as tmp:
            tmp.write_bytes(blob)
        return
    mesh.vertices = mesh.vertices + offset
    if suffix == ".obj":
        _export_obj(mesh, path, overwrite)
    else:
        write_ply(mesh, path)


def _texture_visuals(
    tmesh: TerrainMesh, rgb: np.ndarray, name: str, fine: np.ndarray | None = None
) -> trimesh.visual.TextureVisuals:
    """A texture image on the DEM grid (one texel per post, posts outside the mesh
    :data:`~orthomvp.present.colours.NAN_RGB`) from per-vertex ``rgb``, or the RGB image
    ``fine`` (k * rows, k * cols, 3) over the grid's extent, in a material ``name``."""
    from PIL import Image

    trimesh = require("trimesh", "mesh export")
    if fine is None:
        rows, cols = tmesh.grid_shape
        img = np.full((rows * cols, 3), NAN_RGB, np.uint8)
        img[tmesh.vertex_post] = rgb
        fine = img.reshape(rows, cols, 3)
    image = Image.fromarray(fine)
    # Name the material (and so the OBJ's texture file) after the output file, so that two
    # meshes exported to one directory do not share one 'material_0.png'. A white diffuse colour
    # (glTF base colour factor) and no specular shine leave the texture's colours as they are;
    # trimesh's default 0.4 grey would darken them.
    white, black = (255, 255, 255, 255), (0, 0, 0, 255)
    material = trimesh.visual.material.SimpleMaterial(
        image=image, diffuse=white, ambient=white, specular=black, name=name
    )
    return trimesh.visual.TextureVisuals(uv=tmesh.uv, material=material)


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
    blob = "\n".join(header).encode("ascii") + vert.tobytes() + face.tobytes()
    with atomic_path(path, size=len(blob)) as tmp:
        tmp.write_bytes(blob)


def _export_obj(mesh: trimesh.Trimesh, path: Path, overwrite: bool) -> None:
    """OBJ with its material and texture image beside it, atomic as a set: all files are
    renamed only when all were written (see :func:`orthomvp.io.outputs.write_set`); any that
    exists is refused unless ``overwrite``."""
    from trimesh.exchange.obj import export_obj

    text, files = export_obj(
        mesh, include_texture=True, return_texture=True, mtl_name=f"{path.stem}.mtl"
    )
    blobs = {path: text.encode(), **{path.parent / name: blob for name, blob in files.items()}}
    beside = [Output("export_mesh", target, ()) for target in blobs]
    check_outputs(beside, overwrite=overwrite, flags=API_FLAGS)
    write_set({target: functools.partial(Path.write_bytes, data=b) for target, b in blobs.items()})


def decimate(
    mesh: trimesh.Trimesh, target_triangles: int, colours: np.ndarray | None = None
) -> trimesh.Trimesh:
    """Quadric decimation with Open3D to about ``target_triangles`` faces.

    ``colours`` (n, 4) uint8 per vertex are carried over: each remaining vertex takes the
    colour of the nearest vertex of ``mesh``. Unlike Open3D's averaging of merged vertices,
    this keeps categorical colours (visibility codes) within their table.
    """
    if target_triangles < 4:
        raise InputError("decimation target must be at least 4 triangles")
    o3d = require("open3d", "mesh decimation")
    trimesh = require("trimesh", "mesh decimation")
    o3 = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(mesh.vertices)),
        o3d.utility.Vector3iVector(np.asarray(mesh.faces, dtype=np.int32)),
    )
    small = o3.simplify_quadric_decimation(target_number_of_triangles=int(target_triangles))
    out = trimesh.Trimesh(
        np.asarray(small.vertices), np.asarray(small.triangles), process=False, validate=False
    )
    if colours is not None:
        spatial = require("scipy.spatial", "colours of a decimated mesh", "scipy")
        _, nearest = spatial.cKDTree(mesh.vertices).query(out.vertices)
        out.visual = trimesh.visual.ColorVisuals(out, vertex_colors=colours[nearest])
    return out
