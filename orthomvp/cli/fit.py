"""``orthomvp fit``: refine the DEM with the multi-view plane fitter (MVP)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

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
) -> None:
    """Fit a plane (height, normal) at every DEM post to the images in which the post is
    visible, so that the images projected onto it agree (MVP paper eqs. 11-21; coarse to
    fine, Levenberg-Marquardt, outlier views dropped). Writes the refined DEM (heights in the
    input's convention, NaN where fewer than 2 views see a post) and, on request, the other
    per-post results, all on the DEM grid."""
    from orthomvp.camera import load_view
    from orthomvp.mvp import FitOptions, fit_dem
    from orthomvp.mvp.fit import check_fit_memory
    from orthomvp.raster import write_geotiff

    outputs = [
        Output("-o", output),
        Output("--normals", normals),
        Output("--cost", cost),
        Output("--views", views),
        Output("--uncertainty", uncertainty),
    ]
    check_outputs(outputs, view_inputs(dem, pairs), overwrite)
    options = FitOptions(
        hwin=hwin,
        sigma=sigma,
        levels=levels,
        reject_below=None if no_reject else reject_below,
        deconvolve=deconvolve,
    )
    loaded = [load_view(image, camera) for image, camera in pairs]
    terrain = dem.read([v[1] for v in loaded])
    check_fit_memory(terrain.shape, len(loaded), hwin, advice="choose a smaller --hwin")
    res = fit_dem(
        terrain,
        [v[0] for v in loaded],
        [v[1] for v in loaded],
        options=options,
        eps=eps,
        progress=not quiet(),
    )
    t, crs = terrain.transform, terrain.crs
    write_geotiff(output, res.heights.astype(np.float32), t, crs, nodata=np.nan)
    if normals:
        up = terrain.up_vectors(terrain.world_points())
        tilt = np.degrees(np.arccos(np.clip(np.sum(res.normals * up, axis=-1), -1, 1)))
        bands = np.stack([res.n_theta, res.n_phi, tilt]).astype(np.float32)
        names = ["n_theta_deg", "n_phi_deg", "tilt_deg"]
        write_geotiff(normals, bands, t, crs, nodata=np.nan, band_names=names)
    if cost:
        write_geotiff(cost, res.cost.astype(np.float32), t, crs, nodata=np.nan)
    if views:
        write_geotiff(views, res.views.astype(np.uint8), t, crs)
    if uncertainty:
        bands = np.stack([res.sigma_h, np.where(res.resolved, res.converged, np.nan)])
        names = ["sigma_h_m", "converged"]
        write_geotiff(
            uncertainty, bands.astype(np.float32), t, crs, nodata=np.nan, band_names=names
        )
    ok = res.resolved
    shift = res.heights[ok] - res.initial[ok]
    print(
        f"wrote {output}: {int(ok.sum()):,} of {ok.size:,} posts fitted "
        f"({int(res.converged.sum()):,} converged); change from the input: median "
        f"{np.median(shift):+.2f}, RMS {np.sqrt(np.mean(shift**2)):.2f}; median uncertainty "
        f"{np.nanmedian(res.sigma_h[ok]):.2f}"
    )
