"""``orthomvp fit``: refine the DEM with the multi-view plane fitter (MVP)."""

from __future__ import annotations

from pathlib import Path

import click

from orthomvp.cli.command import Command
from orthomvp.cli.engine_options import EngineInput, engine_options
from orthomvp.cli.options import (
    OUT_FILE,
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
    overwrite_options,
    pairs_argument,
    quiet,
    say,
    view_inputs,
)

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
    type=OUT_FILE,
    metavar="N.tif",
    help="write the fitted normals: n_theta, n_phi (eq. 11, degrees) and the tilt from the "
    "local vertical (degrees)",
)
@click.option("--cost", type=OUT_FILE, metavar="C.tif", help="write the final cost (eq. 20)")
@click.option("--views", type=OUT_FILE, metavar="V.tif", help="write the number of views used")
@click.option(
    "--uncertainty",
    type=OUT_FILE,
    metavar="U.tif",
    help="write the 1-sigma height uncertainty (metres) and a converged flag (band 2); it "
    "covers the fit's noise only, not its bias (the window's on curved terrain, a wrong "
    "minimum): where the fit is better or worse determined, not an error bar",
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
@overwrite_options
@dem_options
@engine_options(dtype=False, grid=False)
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
    replace_input: bool,
    engine: EngineInput,
) -> None:
    """Fit a plane (height, normal) at every DEM post to the images in which the post is
    visible, so that the images projected onto it agree (MVP paper eqs. 11-21; coarse to
    fine, Levenberg-Marquardt, outlier views dropped). Writes the refined DEM (heights in the
    input's convention, above the ellipsoid where its vertical datum was converted, its CRS
    saying which; NaN where fewer than 2 views see a post) and, on request, the other
    per-post results, all on the DEM grid, tile by tile in bounded memory (the same results as
    in one piece). Images that see no post of the DEM are left out, with one warning."""
    from orthomvp.engine import FitOutputs, plan_fit, run_fit
    from orthomvp.mvp import FitOptions

    outputs = [
        Output("-o", output),
        Output("--normals", normals),
        Output("--cost", cost),
        Output("--views", views),
        Output("--uncertainty", uncertainty),
    ]
    check_outputs(outputs, view_inputs(dem, pairs), overwrite, replace_input)
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
        format=engine.format,
        compress=engine.compress,
        overwrite=overwrite,
        replace_input=replace_input,
    )
    plan = plan_fit(
        dem.path,
        pairs,
        options,
        tile=engine.tile,
        eps=eps,
        **dem.plan_options(),
        progress=not quiet(),
    )
    report = engine.run(plan, outputs, progress=not quiet(), runner=run_fit)
    say(report.line(output))
