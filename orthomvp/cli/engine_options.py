"""The options of the commands that run through the streaming engine (``visibility``,
``ortho``, ``mosaic``, ``fit``, ``check``): the output grid, tiles, parallelism and output
format; and the run itself, from a plan to the files, with the engine's warnings as one line
each."""

from __future__ import annotations

import contextlib
import functools
import sys
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import click

from orthomvp.cli.options import FINITE, POSITIVE, usage_error

if TYPE_CHECKING:
    from orthomvp.engine import Outputs, Plan, RunReport

F = TypeVar("F", bound=Callable[..., Any])

FORMATS = ("cog", "gtiff")
COMPRESSIONS = ("deflate", "zstd", "lzw", "none")
DTYPES = ("float32", "uint8", "uint16", "int16")
"""As :data:`orthomvp.engine.writer.FORMATS`, ``COMPRESSIONS`` and ``NODATA`` (not imported:
--help stays fast; a test checks that they agree)."""


@dataclass(frozen=True)
class EngineInput:
    """The engine options of one command: output grid (``res`` x, y and ``bounds`` left,
    bottom, right, top in the units of ``crs``, default the DEM's), ``tile`` size in posts,
    ``threads``/``processes``/``dask`` (at most one), output ``format``, ``compress`` and
    ``dtype`` (the defaults for a command that writes no raster)."""

    tile: int
    threads: int | None
    processes: int | None
    dask: str | None
    format: str = "cog"
    compress: str = "zstd"
    dtype: str = "float32"
    res: tuple[float, float] | None = None
    bounds: tuple[float, float, float, float] | None = None
    crs: str | None = None

    def run(
        self, plan: Plan, outputs: Outputs, *, progress: bool, runner: Callable | None = None
    ) -> RunReport:
        """Run ``plan`` writing ``outputs`` on the executor these options ask for, through
        ``runner`` (:func:`orthomvp.engine.run_plan`, or :func:`~orthomvp.engine.run_fit` for
        a fit plan)."""
        from orthomvp.engine import run_plan

        runner = runner or run_plan
        with self.workers() as executor:
            return runner(plan, outputs, progress=progress, **executor)

    @contextlib.contextmanager
    def workers(self) -> Iterator[dict[str, Any]]:
        """The keyword arguments of a run on the executor these options ask for: ``client``
        (a Dask client, connected or its local cluster running while inside), or ``threads``
        and ``processes``."""
        if self.dask is None:
            yield {"threads": self.threads, "processes": self.processes}
            return
        from orthomvp.engine import dask_client

        if self.dask.startswith("local:"):
            with dask_client(workers=int(self.dask.removeprefix("local:"))) as client:
                yield {"client": client}
        else:
            with dask_client(address=self.dask) as client:
                yield {"client": client}


def _dask_address(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    if value is None:
        return None
    if value.startswith("local:"):
        count = value.removeprefix("local:")
        if not count.isdigit() or int(count) < 1:
            raise click.BadParameter("local:N needs a number of workers N >= 1", ctx, param)
        return value
    if "://" not in value:
        raise click.BadParameter(
            f"{value!r} is neither local:N nor a scheduler address such as tcp://HOST:8786",
            ctx,
            param,
        )
    return value


def engine_options(*, dtype: bool, grid: bool = True, rasters: bool = True) -> Callable[[F], F]:
    """The engine's options; the command receives them as one :class:`EngineInput` named
    ``engine``. ``dtype``: whether the command writes image values (``--dtype``); ``grid``:
    whether it takes another output grid (``--res``, ``--bounds``, ``--crs``; the fit and the
    check work on the DEM's own grid); ``rasters``: whether it writes rasters (``--format``,
    ``--compress``; the check writes a table and a plot)."""

    def decorate(f: F) -> F:
        @functools.wraps(f)
        def command(**kwargs: Any) -> Any:
            given = [k for k in ("threads", "processes", "dask") if kwargs[k] is not None]
            if len(given) > 1:
                names = " and ".join(f"--{k}" for k in given)
                raise usage_error(
                    f"{names} exclude each other: give one of --threads, --processes and --dask"
                )
            bounds = kwargs.get("bounds")
            if bounds and not (bounds[0] < bounds[2] and bounds[1] < bounds[3]):
                raise usage_error(
                    f"--bounds must be LEFT BOTTOM RIGHT TOP, got {' '.join(map(str, bounds))}"
                )
            engine = EngineInput(
                **{k: kwargs.pop(k) for k in ("res", "bounds", "crs") if grid},
                **{k: kwargs.pop(k) for k in ("tile", "threads", "processes", "dask")},
                **{k: kwargs.pop(k) for k in ("format", "compress") if rasters},
                **({"dtype": kwargs.pop("dtype")} if dtype else {}),
            )
            return f(engine=engine, **kwargs)

        grid_options = [
            click.option(
                "--res",
                type=POSITIVE,
                nargs=2,
                metavar="X Y",
                show_default="the DEM's",
                help="output post size in the output CRS's units",
            ),
            click.option(
                "--bounds",
                type=FINITE,
                nargs=4,
                metavar="LEFT BOTTOM RIGHT TOP",
                show_default="the DEM's",
                help="output extent in the output CRS's units, LEFT < RIGHT and BOTTOM < TOP",
            ),
            click.option(
                "--crs",
                metavar="CRS",
                show_default="the DEM's",
                help="output CRS (anything pyproj reads, on the DEM's body); needs --res",
            ),
        ]
        options = [
            *(grid_options if grid else []),
            click.option(
                "--tile",
                type=click.IntRange(min=2),
                metavar="POSTS",
                show_default="1024, or for ortho, mosaic and check on a small grid its longer side "
                "split among the cores (at least 256)",
                help="output tile size: memory grows with it, not with the DEM or image",
            ),
            click.option(
                "--threads",
                type=click.IntRange(min=1),
                metavar="N",
                show_default="one per core",
                help="tiles in parallel threads",
            ),
            click.option(
                "--processes",
                type=click.IntRange(min=1),
                metavar="N",
                help="tiles in N worker processes instead of threads",
            ),
            click.option(
                "--dask",
                callback=_dask_address,
                metavar="local:N|tcp://HOST:PORT",
                help="tiles on a Dask cluster: a local one of N worker processes, or the "
                "scheduler at an address (workers need orthomvp and the same file paths)",
            ),
        ]
        raster_options = [
            click.option(
                "--format",
                type=click.Choice(FORMATS),
                default="cog",
                help="Cloud-Optimized GeoTIFF, or tiled GeoTIFF with internal overviews",
            ),
            click.option(
                "--compress",
                type=click.Choice(COMPRESSIONS),
                default="zstd",
                help="compression (with the predictor that fits the data type; zstd at level 1, "
                "chosen for speed)",
            ),
        ]
        options += raster_options if rasters else []
        if dtype:
            options.append(
                click.option(
                    "--dtype",
                    type=click.Choice(DTYPES),
                    default="float32",
                    help="output data type of the image values (integers are rounded; nodata "
                    "NaN, 0 or -32768)",
                )
            )
        for option in reversed(options):
            command = option(command)
        return command  # type: ignore[return-value]

    return decorate


@contextlib.contextmanager
def warnings_as_lines() -> Iterator[None]:
    """Warnings raised inside (the engine's halo warning, say) as one stderr line each."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        print(f"orthomvp: warning: {' '.join(str(w.message).split())}", file=sys.stderr)
