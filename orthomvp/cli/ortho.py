"""``orthomvp visibility``, ``ortho`` and ``mosaic``: per-post visibility of an image, its
occlusion-aware orthophoto, and the orthophoto of many images with hidden posts filled from
other views."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np

from orthomvp.cli.command import Command
from orthomvp.cli.options import (
    FINITE,
    PATH,
    POSITIVE,
    DemInput,
    Output,
    camera_argument,
    check_outputs,
    dem_argument,
    dem_options,
    eps_option,
    image_argument,
    interp_option,
    output_option,
    overwrite_option,
    pairs_argument,
    quiet,
    usage_error,
)
from orthomvp.codes import Interp

if TYPE_CHECKING:
    from orthomvp.terrain import Terrain
    from orthomvp.visibility import Visibility


@click.command(
    cls=Command, short_help="per-post visibility of one image: the epsilon round-trip test"
)
@dem_argument
@image_argument
@camera_argument
@output_option("VIS.tif", "the visibility codes (uint8 GeoTIFF on the DEM grid)")
@eps_option
@overwrite_option
@dem_options
def visibility(
    dem: DemInput, image: Path, camera: Path, output: Path, eps: float | None, overwrite: bool
) -> None:
    """Classify every DEM post for one camera: 0 no data / outside the image, 1 visible,
    2 occluded by terrain, 3 facing away. Written as a uint8 GeoTIFF on the DEM grid."""
    from orthomvp.camera import load_view
    from orthomvp.ortho import check_orthophoto_memory
    from orthomvp.raster import write_geotiff
    from orthomvp.visibility import compute_visibility

    check_outputs([Output("-o", output)], view_inputs(dem, [(image, camera)]), overwrite)
    _, model = load_view(image, camera)
    terrain = dem.read([model])
    check_orthophoto_memory(terrain.shape, 0, DEM_TOO_LARGE)
    vis = compute_visibility(terrain, model, eps=eps, progress=not quiet())
    warn_partial(vis, terrain, str(image))
    write_geotiff(output, vis.codes, terrain.transform, terrain.crs, nodata=0)
    counts = ", ".join(f"{v:,} {k}" for k, v in vis.counts().items())
    print(f"wrote {output}: {counts}")


@click.command(cls=Command, short_help="occlusion-aware orthophoto of one image")
@dem_argument
@image_argument
@camera_argument
@output_option("ORTHO.tif", "the orthophoto (float32, all bands, NaN = nodata)")
@click.option(
    "--visibility",
    "visibility_out",
    type=PATH,
    metavar="VIS.tif",
    help="also write the visibility codes on the output grid",
)
@interp_option
@click.option(
    "--no-occlusion",
    is_flag=True,
    help="naive orthophoto: every post inside the image gets a value (ghosts included)",
)
@click.option(
    "--res",
    type=POSITIVE,
    nargs=2,
    metavar="X Y",
    show_default="the DEM's",
    help="output pixel size in DEM CRS units (degrees for a geographic DEM)",
)
@click.option(
    "--bounds",
    type=FINITE,
    nargs=4,
    metavar="LEFT BOTTOM RIGHT TOP",
    show_default="the DEM's",
    help="output extent in DEM CRS units, LEFT < RIGHT and BOTTOM < TOP",
)
@eps_option
@overwrite_option
@dem_options
def ortho(
    dem: DemInput,
    image: Path,
    camera: Path,
    output: Path,
    visibility_out: Path | None,
    interp: Interp,
    no_occlusion: bool,
    res: tuple[float, float] | None,
    bounds: tuple[float, float, float, float] | None,
    eps: float | None,
    overwrite: bool,
) -> None:
    """Orthorectify IMAGE through CAMERA onto the DEM grid (all bands, float32, NaN =
    nodata). Posts that are not visible (occluded, facing away, outside) are nodata unless
    --no-occlusion asks for the naive orthophoto."""
    from orthomvp.camera import load_view
    from orthomvp.errors import InputError
    from orthomvp.mesh import terrain_mesh
    from orthomvp.ortho import check_orthophoto_memory, orthorectify
    from orthomvp.raster import write_geotiff
    from orthomvp.raycast import RayCaster

    if bounds and not (bounds[0] < bounds[2] and bounds[1] < bounds[3]):
        raise usage_error(
            f"--bounds must be LEFT BOTTOM RIGHT TOP, got {' '.join(map(str, bounds))}"
        )
    outputs = [Output("-o", output), Output("--visibility", visibility_out)]
    check_outputs(outputs, view_inputs(dem, [(image, camera)]), overwrite)
    pixels, model = load_view(image, camera)
    terrain = dem.read([model])
    try:
        _, shape = terrain.output_grid(res, bounds)
    except InputError as exc:
        raise usage_error(str(exc)) from None
    advice = "choose a coarser --res or a smaller --bounds" if res or bounds else DEM_TOO_LARGE
    check_orthophoto_memory(shape, pixels.shape[0], advice)
    caster = RayCaster(terrain_mesh(terrain))
    grid = terrain.regrid(res, bounds) if res or bounds else terrain
    result = orthorectify(
        grid,
        pixels,
        model,
        occlusion=not no_occlusion,
        eps=eps,
        interp=interp,
        caster=caster,
        progress=not quiet(),
        post_scale=post_scale(grid, terrain),
    )
    warn_partial(result.visibility, grid, str(image))
    write_geotiff(output, result.data, result.transform, result.crs, nodata=np.nan)
    if visibility_out:
        codes = result.visibility.codes
        write_geotiff(visibility_out, codes, grid.transform, grid.crs, nodata=0)
    filled = int(np.isfinite(result.data).all(axis=0).sum())
    print(f"wrote {output}: {filled:,} of {grid.values.size:,} posts filled")


@click.command(
    cls=Command,
    short_help="one orthophoto from many images, occluded posts filled from other views",
)
@dem_argument
@pairs_argument()
@output_option("MOSAIC.tif", "the mosaic (float32, all bands, NaN = nodata)")
@click.option(
    "--source",
    type=PATH,
    metavar="SOURCE.tif",
    help="also write which image each post came from",
)
@interp_option
@eps_option
@overwrite_option
@dem_options
def mosaic(
    dem: DemInput,
    pairs: list[tuple[Path, Path]],
    output: Path,
    source: Path | None,
    interp: Interp,
    eps: float | None,
    overwrite: bool,
) -> None:
    """Orthorectify every IMAGE CAMERA pair (mvpgui order) onto the DEM grid; each post
    takes its value from the visible view with the smallest emission angle. --source records
    which image (1-based, in command-line order; 0 = none) each post came from."""
    from orthomvp.camera import load_view
    from orthomvp.ortho import check_orthophoto_memory
    from orthomvp.ortho import mosaic as make_mosaic
    from orthomvp.raster import write_geotiff

    outputs = [Output("-o", output), Output("--source", source)]
    check_outputs(outputs, view_inputs(dem, pairs), overwrite)
    views = [load_view(image, camera) for image, camera in pairs]
    terrain = dem.read([v[1] for v in views])
    check_orthophoto_memory(terrain.shape, 2 * views[0][0].shape[0], DEM_TOO_LARGE)
    result = make_mosaic(terrain, views, eps=eps, interp=interp, progress=not quiet())
    write_geotiff(output, result.data, result.transform, result.crs, nodata=np.nan)
    if source:
        write_geotiff(source, result.source, result.transform, result.crs, nodata=0)
    counts = np.bincount(result.source.ravel(), minlength=len(views) + 1)
    parts = ", ".join(f"{counts[k]:,} from {pairs[k - 1][0]}" for k in range(1, len(views) + 1))
    print(f"wrote {output}: {parts}; {counts[0]:,} posts visible in no image")


DEM_TOO_LARGE = "the DEM is too large to process in one piece: cut it into tiles"


def view_inputs(dem: DemInput, pairs: list[tuple[Path, Path]]) -> list[tuple[str, Path]]:
    """The input files of a command reading ``dem`` and (image, camera) ``pairs``, labelled
    for :func:`~orthomvp.cli.options.check_outputs`."""
    inputs = [("DEM", dem.path)]
    for k, (image, camera) in enumerate(pairs, start=1):
        n = f" {k}" if len(pairs) > 1 else ""
        inputs += [(f"IMAGE{n}", image), (f"CAMERA{n}", camera)]
    return inputs


def warn_partial(vis: Visibility, terrain: Terrain, what: str) -> None:
    """A warning on stderr when the image covers only part of the DEM's valid posts."""
    outside = int(((vis.codes == 0) & terrain.valid).sum())
    if outside:
        share = 100 * (1 - outside / int(terrain.valid.sum()))
        print(
            f"orthomvp: warning: {what} covers {share:.1f}% of the DEM's posts; the rest is nodata",
            file=sys.stderr,
        )


def post_scale(grid: Terrain, terrain: Terrain) -> float:
    """Size of one output post in DEM posts (for the epsilon test on a resampled grid)."""
    return float(np.mean(grid.post_spacing()) / np.mean(terrain.post_spacing()))
