"""``orthomvp mesh``: the DEM as a body-fixed Cartesian mesh (PLY, OBJ, GLB)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click

from orthomvp.cli.command import Command
from orthomvp.cli.options import (
    PATH,
    DemInput,
    Output,
    check_outputs,
    dem_argument,
    dem_options,
    error_limit_option,
    output_option,
    overwrite_options,
    say,
    usage_error,
)

MESH_SUFFIXES = (".ply", ".obj", ".glb")
"""as :data:`orthomvp.present.export.EXPORT_FORMATS` (not imported: --help stays fast)"""
COLOUR_KINDS = ("image", "visibility", "error")
"""what a texture raster holds, as :data:`orthomvp.present.colours.COLOUR_KINDS` (not
imported: --help stays fast)"""


@click.command(
    cls=Command,
    exclusive=[("texture", "error_against")],
    short_help="export the DEM as a Cartesian mesh (PLY, OBJ, GLB)",
)
@dem_argument
@output_option("OUT", "OUT.ply, OUT.obj or OUT.glb")
@click.option(
    "--texture",
    type=PATH,
    metavar="RASTER",
    help="a raster to colour the mesh (see --colour-by): on the DEM grid, or any georeferenced "
    "raster (finer, coarser, another extent or CRS), sampled at the posts (the texel under "
    "each post; posts outside it get the no-data colour)",
)
@click.option(
    "--error-against",
    type=PATH,
    metavar="TRUTH.tif",
    help="colour by the height error DEM - TRUTH in metres (TRUTH on the DEM grid)",
)
@click.option(
    "--colour-by",
    type=click.Choice(COLOUR_KINDS),
    show_default="image; error with --error-against",
    help="what --texture holds: image (grey or RGB, stretched), visibility (codes 0-3 of "
    "`orthomvp visibility`, in the figures' colours) or error (metres: blue below zero, red "
    "above)",
)
@error_limit_option("error colours saturate at +-M metres")
@click.option(
    "--local-origin",
    is_flag=True,
    help="write vertices relative to the mesh's local origin (printed, except with -q) instead of "
    "body-fixed coordinates",
)
@click.option(
    "--decimate",
    type=click.IntRange(min=4),
    metavar="TRIANGLES",
    help="simplify to about this many triangles (Open3D quadric decimation)",
)
@overwrite_options
@dem_options
def mesh(
    dem: DemInput,
    output: Path,
    texture: Path | None,
    error_against: Path | None,
    colour_by: str | None,
    error_limit: float | None,
    local_origin: bool,
    decimate: int | None,
    overwrite: bool,
    replace_input: bool,
) -> None:
    """Triangulate the DEM in body-fixed Cartesian metres (two triangles per grid cell, holes
    skipped) and export it. PLY gets vertex colours, OBJ (with OUT.mtl and OUT.png beside it)
    and GLB an image texture, from --texture or --error-against: one texel per post, or at a
    finer --texture's own resolution (an integer number of texels per post, at most 4096 a
    side)."""
    from orthomvp.occlusion.mesh import terrain_mesh
    from orthomvp.present.colours import error_colour_limit, height_error
    from orthomvp.present.export import export_mesh
    from orthomvp.present.texture import finer_grid, on_dem_grid

    kind = colour_by or ("error" if error_against else "image")
    if error_against and kind != "error":
        raise usage_error(f"--error-against colours by height error, not by {kind}")
    if colour_by and not (texture or error_against):
        raise usage_error("--colour-by needs a raster: give --texture (or --error-against)")
    if error_limit is not None and kind != "error":
        raise usage_error("--error-limit applies to error colours only (--colour-by error)")
    inputs = [("DEM", dem.path), ("--texture", texture), ("--error-against", error_against)]
    outputs = [Output("-o", output, MESH_SUFFIXES, "a mesh")]
    if output.suffix.lower() == ".obj" and (texture or error_against) and decimate is None:
        outputs += [  # its material and texture image, beside it
            Output("-o", output.with_suffix(".mtl"), (".mtl",), "its material"),
            Output("-o", output.with_suffix(".png"), (".png",), "its texture image"),
        ]
    check_outputs(outputs, inputs, overwrite, replace_input)
    if output.suffix.lower() == ".ply" and decimate is None:
        _stream(dem, output, texture, error_against, kind, error_limit, local_origin)
        return
    terrain = dem.read()
    tmesh = terrain_mesh(terrain)
    if error_against:
        truth = replace(dem, path=error_against, world=terrain.world).read()
        colours = height_error(terrain, truth)
    else:
        colours = on_dem_grid(texture, terrain) if texture else None
    image = None  # OBJ and GLB: an image texture at a finer texture's own resolution
    if texture and decimate is None:
        image = finer_grid(texture, terrain)
    export_mesh(
        tmesh,
        output,
        texture=colours,
        local=local_origin,
        target_triangles=decimate,
        colour_kind=kind,
        error_limit=error_limit,
        texture_image=image,
        overwrite=True,  # (the outputs were checked with the command's options)
    )
    note = f", decimated to about {decimate:,} triangles" if decimate else ""
    say(f"wrote {output}: {len(tmesh.vertices):,} vertices, {len(tmesh.faces):,} triangles{note}")
    if kind == "error":
        limit = error_colour_limit(colours, limit=error_limit)
        say(f"error colours: blue -{limit:.3g} m, white 0, red +{limit:.3g} m (clipped beyond)")
    if local_origin:
        say("local origin (body-fixed metres): {:.3f} {:.3f} {:.3f}".format(*tmesh.origin))


def _stream(
    dem: DemInput,
    output: Path,
    texture: Path | None,
    error_against: Path | None,
    kind: str,
    error_limit: float | None,
    local_origin: bool,
) -> None:
    """A PLY of any DEM size, block by block (:mod:`orthomvp.present.mesh_stream`)."""
    from orthomvp.codes import WorldFrame
    from orthomvp.engine.grid import scan_dem, with_world
    from orthomvp.geometry.datum import HeightOptions
    from orthomvp.present.mesh_stream import code_colours, image_stretch, write_ply_stream
    from orthomvp.present.mesh_stream import error_against as error_colours_of
    from orthomvp.present.texture import TextureSampler

    world = WorldFrame.BODY if dem.world == "auto" else WorldFrame(dem.world)
    heights = HeightOptions(dem.vertical_datum, dem.height_offset)
    source = with_world(scan_dem(dem.path, dem.crs, dem.radius_values, heights=heights), world)
    source.preview.check_convention()  # heights against radii, as the .obj / .glb path does
    colours, limit = None, None
    if error_against:
        truth = scan_dem(error_against, dem.crs, dem.radius_values, heights=heights)
        truth = with_world(truth, world)
        truth.preview.check_convention()
        colours, limit = error_colours_of(truth, source, error_limit)
    elif texture:
        sampler = TextureSampler(texture, source.shape, source.transform, source.crs)
        colours = code_colours(sampler) if kind == "visibility" else image_stretch(sampler)
    n_vert, n_face, origin = write_ply_stream(source, output, colours=colours, local=local_origin)
    say(f"wrote {output}: {n_vert:,} vertices, {n_face:,} triangles")
    if limit is not None:
        say(f"error colours: blue -{limit:.3g} m, white 0, red +{limit:.3g} m (clipped beyond)")
    if local_origin:
        say("local origin (body-fixed metres): {:.3f} {:.3f} {:.3f}".format(*origin))
