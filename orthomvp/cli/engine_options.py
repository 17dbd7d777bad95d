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

from orthomvp.cli.command import Variadic
from orthomvp.cli.options import FINITE, usage_error

if TYPE_CHECKING:
    from orthomvp.engine import Outputs, Plan, RunReport

F = TypeVar("F", bound=Callable[..., Any])

FORMATS = ("cog", "gtiff")
COMPRESSIONS = ("deflate", "zstd", "lzw", "none")
DTYPES = ("float32", "uint8", "uint16", "int16")
GRIDS = ("camera", "dem")
"""As :data:`orthomvp.engine.writer.FORMATS`, ``COMPRESSIONS`` and ``NODATA``, and
:data:`orthomvp.engine.grid_choice.GRIDS` (not imported: --help stays fast; a test checks that
they agree)."""


class Length(click.ParamType):
    """A resolution: a positive number (the CRS's units) or a length with a unit suffix
    (``5m``, ``0.0003deg``; :func:`orthomvp.engine.units.parse_length`); kept as written."""

    name = "length"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        from orthomvp.engine.units import parse_length
        from orthomvp.errors import InputError

        try:
            parse_length(value)
        except InputError as exc:
            self.fail(str(exc), param, ctx)
        return str(value)


LENGTH = Length()


def _res(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> tuple | None:
    """--res as given: None when absent (a Variadic option gives an empty tuple)."""
    return tuple(value) or None


@dataclass(frozen=True)
class EngineInput:
    """The engine options of one command: output grid (``grid``, the default's kind; ``res``;
    ``bounds`` left, bottom, right, top in the units of ``crs``, default the DEM's: see
    :func:`orthomvp.engine.grid_choice.choose_grid`), ``tile`` size in posts,
    ``threads``/``processes``/``dask`` (at most one), output ``format``, ``compress`` and
    ``dtype`` (the defaults for a command that writes no raster)."""

    tile: int
    threads: int | None
    processes: int | None
    dask: str | None
    format: str = "cog"
    compress: str = "zstd"
    dtype: str = "float32"
    res: tuple[str, ...] | None = None
    """one or two values (x, y), each a number in the output CRS's units or a length with its
    unit ("5m", "0.0003deg"), as :func:`orthomvp.engine.units.parse_length` reads them"""
    bounds: tuple[float, float, float, float] | None = None
    crs: str | None = None
    grid: str = "camera"
    """the default output grid: "camera" (the images' footprint at their ground sample
    distance) or "dem" (the DEM's own)"""

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
            res = kwargs.get("res")
            if res is not None and len(res) > 2:
                raise usage_error(f"--res takes one value or two (X Y), got {len(res)}")
            engine = EngineInput(
                **{k: kwargs.pop(k) for k in ("res", "bounds", "crs", "grid") if grid},
                **{k: kwargs.pop(k) for k in ("tile", "threads", "processes", "dask")},
                **{k: kwargs.pop(k) for k in ("format", "compress") if rasters},
                **({"dtype": kwargs.pop("dtype")} if dtype else {}),
            )
            return f(engine=engine, **kwargs)

        grid_options = [
            click.option(
                "--grid",
                "grid",
                type=click.Choice(GRIDS),
                default="camera",
                help="default output grid: the part of the DEM the images see at their own "
                "ground sample distance (rounded to 1, 2, 2.5 or 5 x 10^k m; edges on the "
                "DEM's lattice of that size), or the DEM's own grid; --res and --bounds "
                "replace either choice",
            ),
            click.option(
                "--res",
                cls=Variadic,
                type=LENGTH,
                metavar="X [Y]",
                callback=_res,
                show_default="the images' ground sample distance (--grid camera) or the DEM's",
                help="output post size: a number in the output CRS's units, or with a unit: "
                "5m, 2.5km, 0.0003deg, 1arcsec (one value for both axes)",
            ),
            click.option(
                "--bounds",
                type=FINITE,
                nargs=4,
                metavar="LEFT BOTTOM RIGHT TOP",
                show_default="the images' footprint (--grid camera) or the DEM's",
                help="output extent in the output CRS's units, LEFT < RIGHT and BOTTOM < TOP",
            ),
            click.option(
                "--crs",
                metavar="CRS",
                show_default="the DEM's",
                help="output CRS (anything pyproj reads, on the DEM's body)",
            ),
        ]
        options = [
            *(grid_options if grid else []),
            click.option(
                "--tile",
                type=click.IntRange(min=2),
                metavar="POSTS",
                show_default="1024; on a grid too small to give each core a tile, its longer "
                "side split among the cores, at least 512 for visibility and ortho, 256 for "
                "mosaic and check; a mosaic's tiles also shrink, to 192 at least, where many "
                "views overlap; fit: always 1024",
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
                    help="output data type of the image values (integers are rounded and "
                    "clipped to the type's range, with a warning when values are clipped or "
                    "rounded to a few levels; nodata NaN, 0 or -32768)",
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
