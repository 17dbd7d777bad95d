"""``orthomvp fit``: refine the DEM with the multi-view plane fitter (MVP)."""

from __future__ import annotations

from pathlib import Path

import click

from orthomvp.cli.command import Command
from orthomvp.cli.options import (
    PATH,
    POSITIVE,
    DemInput,
    Number,
    Output,
    check_outputs,
    dem_argument,
    dem_options,
    eps_option,
    levels_option,
    output_option,
    overwrite_option,
    pairs_argument,
    quiet,
    usage_error,
)
from orthomvp.cli.ortho import view_inputs

MAX_DECONVOLVE = 10
"""as :data:`orthomvp.mvp.fit.MAX_DECONVOLVE` (not imported: --help stays fast)"""


@click.command(
    cls=Command,
    exclusive=[("reject_below", "no_reject")],
    short_help="refine the DEM with the multi-view plane fitter (MVP)",
)
@dem_argument
@pairs_argument(minimum=2)
@output_option("FITTED.tif", "the refined DEM")
@click.option(
    "--normals",
    type=PATH,
    metavar="N.tif",
    help="write the fitted normals: n_theta, n_phi (eq. 11, degrees) and the tilt from the "
    "local vertical (degrees)",
)
@click.option("--cost", type=PATH, metavar="C.tif", help="write the final cost (eq. 20)")
@click.option("--views", type=PATH, metavar="V.tif", help="write the number of views used")
@click.option(
    "--uncertainty",
    type=PATH,
    metavar="U.tif",
    help="write the 1-sigma height uncertainty (metres) and a converged flag (band 2)",
)
@click.option(
    "--hwin",
    type=click.IntRange(min=1),
    default=10,
    metavar="POSTS",
    help="window half-size in posts",
)
@click.option(
    "--sigma",
    type=POSITIVE,
    metavar="POSTS",
    show_default="hwin / 2",
    help="Gaussian window sigma in posts",
)
@levels_option("coarse-to-fine pyramid levels (1 = off)")
@click.option(
    "--reject-below",
    type=Number(min=-1, max=1),
    default=0.5,
    metavar="RHO",
    help="drop a view whose patch correlates with the other views' mean below RHO (a correlation)",
)
@click.option("--no-reject", is_flag=True, help="keep every view (no outliers)")
@click.option(
    "--deconvolve",
    type=click.IntRange(min=0, max=MAX_DECONVOLVE),
    default=1,
    metavar="STEPS",
    help="Van Cittert steps from plane heights to surface heights (0 = plane heights; each "
    "step may amplify noise once more)",
)
@eps_option
@overwrite_option
@dem_options
@click.option(
    "--tile",
    type=click.IntRange(min=2),
    default=1024,
    metavar="POSTS",
    help="fit the DEM in tiles of POSTS x POSTS posts, each from windows of the DEM and the "
    "images (memory grows with the tile, not with the DEM or the images)",
)
@click.option(
    "--threads",
    type=click.IntRange(min=1),
    metavar="N",
    show_default="one per core",
    help="fit N tiles at a time in threads (fewer tiles than threads share them)",
)
@click.option(
    "--processes", type=click.IntRange(min=1), metavar="N", help="fit tiles in N worker processes"
)
@click.option(
    "--dask",
    metavar="local:N|tcp://HOST:PORT",
    help="fit tiles on a Dask cluster: a local one of N worker processes, or the scheduler at "
    "HOST:PORT (every worker reads the inputs at the same paths)",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["cog", "gtiff"]),
    default="cog",
    help="outputs as Cloud-Optimized GeoTIFFs or tiled GeoTIFFs with internal overviews",
)
@click.option(
    "--compress",
    type=click.Choice(["deflate", "zstd", "lzw", "none"]),
    default="deflate",
    help="compression of the outputs",
)
def fit(
    dem: DemInput,
    pairs: list[tuple[Path, Path]],
    output: Path,
    normals: Path | None,
    cost: Path | None,
    views: Path | None,
    uncertainty: Path | None,
    hwin: int,
    sigma: float | None,
    levels: int,
    reject_below: float,
    no_reject: bool,
    deconvolve: int,
    eps: float | None,
    overwrite: bool,
    tile: int,
    threads: int | None,
    processes: int | None,
    dask: str | None,
    fmt: str,
    compress: str,
) -> None:
    """Fit a plane (height, normal) at every DEM post to the images in which the post is
    visible, so that the images projected onto it agree (MVP paper eqs. 11-21; coarse to
    fine, Levenberg-Marquardt, outlier views dropped). Writes the refined DEM (heights in the
    input's convention, NaN where fewer than 2 views see a post) and, on request, the other
    per-post results, all on the DEM grid, tile by tile in bounded memory (the same results as
    in one piece)."""
    from orthomvp.engine import FitOutputs, dask_client, plan_fit, run_fit
    from orthomvp.mvp import FitOptions

    outputs = [
        Output("-o", output),
        Output("--normals", normals),
        Output("--cost", cost),
        Output("--views", views),
        Output("--uncertainty", uncertainty),
    ]
    check_outputs(outputs, view_inputs(dem, pairs), overwrite)
    if sum(x is not None for x in (threads, processes, dask)) > 1:
        raise usage_error("give one of --threads, --processes and --dask")
    cluster = _dask_cluster(dask)
    options = FitOptions(
        hwin=hwin,
        sigma=sigma,
        levels=levels,
        reject_below=None if no_reject else reject_below,
        deconvolve=deconvolve,
    )
    outputs = FitOutputs(
        heights=output,
        normals=normals,
        cost=cost,
        views=views,
        uncertainty=uncertainty,
        format=fmt,
        compress=compress,
    )
    plan = plan_fit(
        dem.path,
        pairs,
        options,
        tile=tile,
        eps=eps,
        dem_crs=dem.crs,
        radius_values=dem.radius_values,
        world=dem.world,
        progress=not quiet(),
    )
    if cluster is None:
        report = run_fit(plan, outputs, threads=threads, processes=processes, progress=not quiet())
    else:
        with dask_client(**cluster) as client:
            report = run_fit(plan, outputs, client=client, progress=not quiet())
    print(report.line(output))


def _dask_cluster(spec: str | None) -> dict | None:
    """:func:`~orthomvp.engine.dask_client` arguments from ``--dask`` (None without it)."""
    if spec is None:
        return None
    if spec.startswith("local:"):
        count = spec.removeprefix("local:")
        if not count.isdigit() or int(count) < 1:
            raise usage_error(f"--dask local:N needs a number of workers N >= 1, got {spec!r}")
        return {"workers": int(count)}
    if "://" not in spec:
        raise usage_error(
            f"--dask takes local:N or a scheduler address tcp://HOST:PORT, got {spec!r}"
        )
    return {"address": spec}
