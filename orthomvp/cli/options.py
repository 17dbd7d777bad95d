"""The arguments and options that several commands share, each defined once: the DEM and how
to read it, images and cameras, the visibility tolerance, interpolation, pyramid levels, error
colour limits and the output file; and the value types they check."""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from orthomvp.codes import Interp, WorldFrame

if TYPE_CHECKING:
    from orthomvp.camera import PinholeCamera
    from orthomvp.terrain import Terrain

F = TypeVar("F", bound=Callable[..., Any])
PATH = click.Path(path_type=Path)
"""A file or directory name; its existence is checked where it is read, with a clear message."""

CAMERA_HELP = (
    "camera model: .tsai, .pinhole, .json, or an Orthority exterior file (.csv, .geojson; the "
    "row of IMAGE, the one .yaml beside it)"
)


class PositiveFloat(click.FloatRange):
    """A number > 0 (NaN refused); --help shows the range."""

    name = "float"

    def __init__(self) -> None:
        super().__init__(min=0, min_open=True)

    def convert(
        self, value: Any, param: click.Parameter | None, ctx: click.Context | None
    ) -> float:
        number = click.FLOAT.convert(value, param, ctx)
        if not number > 0:
            self.fail(f"{number} is not positive", param, ctx)
        return number


POSITIVE = PositiveFloat()


def enum_choice(enum: type[Enum], *extra: str) -> dict[str, Any]:
    """``type`` and ``callback`` of an option choosing one of a string enum's values (or one of
    ``extra``, passed on as is)."""
    values = [*extra, *(member.value for member in enum)]

    def convert(ctx: click.Context, param: click.Parameter, value: str | None) -> Any:
        return value if value is None or value in extra else enum(value)

    return {"type": click.Choice(values), "callback": convert}


def usage_error(message: str) -> click.UsageError:
    """A usage error of the running command (reported as ``orthomvp: error: COMMAND: ...``)."""
    return click.UsageError(message, click.get_current_context())


def quiet() -> bool:
    """Whether ``-q`` asked for no progress bars or notes."""
    return bool(click.get_current_context().find_root().params.get("quiet"))


quiet_option = click.option("-q", "--quiet", is_flag=True, help="no progress bars or notes")


# ------------------------------------------------------------------------------------ DEM
@dataclass(frozen=True)
class DemInput:
    """The DEM argument and the options saying how to read it."""

    path: Path
    radius_values: bool = False
    crs: str | None = None
    world: str = "auto"
    """"auto", or a :class:`WorldFrame` value"""

    def read(self, cameras: Sequence[PinholeCamera] = ()) -> Terrain:
        """The DEM; ``auto`` picks the world frame from the ``cameras``' centres (see
        :func:`orthomvp.world.detect_world`), body-fixed when there are none."""
        from dataclasses import replace

        import numpy as np

        from orthomvp.terrain import Terrain
        from orthomvp.world import detect_world

        world = WorldFrame.BODY if self.world == "auto" else WorldFrame(self.world)
        terrain = Terrain.read(
            self.path, radius_values=self.radius_values, world=world, crs=self.crs
        )
        if self.world == "auto" and cameras:
            centres = np.array([camera.center for camera in cameras])
            terrain = replace(terrain, world=detect_world(terrain, centres))
        return terrain


dem_argument = click.argument(
    "dem",
    type=PATH,
    metavar="DEM",
    help="the DEM: a GeoTIFF (or any raster GDAL reads) of heights above the reference "
    "surface of its CRS (or radii: --radius-values)",
)


def dem_options(f: F) -> F:
    """--radius-values, --dem-crs and --world; the command receives them with its ``dem``
    argument as one :class:`DemInput` named ``dem``."""

    @functools.wraps(f)
    def command(**kwargs: Any) -> Any:
        dem = DemInput(
            kwargs.pop("dem"),
            radius_values=kwargs.pop("radius_values"),
            crs=kwargs.pop("dem_crs"),
            world=kwargs.pop("world"),
        )
        return f(dem=dem, **kwargs)

    options = (
        click.option(
            "--radius-values",
            is_flag=True,
            help="DEM values are radii from the body centre in metres (the MVP paper's "
            "convention) instead of heights above the CRS's reference surface",
        ),
        click.option(
            "--dem-crs",
            metavar="CRS",
            help="CRS of the DEM (PROJ string, WKT or e.g. IAU_2015:30100); overrides the "
            "file's, needed when the file has none",
        ),
        click.option(
            "--world",
            default="auto",
            **enum_choice(WorldFrame, "auto"),
            help="world frame of the cameras: body-fixed Cartesian metres, or the DEM's "
            "projected CRS taken as Cartesian (easting, northing, height); auto picks it from "
            "the camera centres and the DEM (body for geographic CRSs and when no camera is "
            "given) and asks for body or map when that is ambiguous",
        ),
    )
    for option in reversed(options):
        command = option(command)
    return command  # type: ignore[return-value]


# -------------------------------------------------------------------- images and cameras
image_argument = click.argument(
    "image",
    type=PATH,
    metavar="IMAGE",
    help="the image: any raster GDAL reads, or an ISIS3 .cub (gives the image size)",
)
camera_argument = click.argument("camera", type=PATH, metavar="CAMERA", help=f"its {CAMERA_HELP}")


def pairs_argument(minimum: int = 1) -> Callable[[F], F]:
    """The ``IMAGE CAMERA [IMAGE CAMERA ...]`` argument, at least ``minimum`` pairs; the
    command receives a list of (image, camera) paths named ``pairs``."""

    def pairs(
        ctx: click.Context, param: click.Parameter, value: tuple[Path, ...]
    ) -> list[tuple[Path, Path]]:
        if len(value) % 2:
            raise click.UsageError("needs IMAGE CAMERA pairs: got an odd number of files", ctx)
        if len(value) < 2 * minimum:
            raise click.UsageError(f"needs at least {minimum} IMAGE CAMERA pairs", ctx)
        return list(zip(value[::2], value[1::2], strict=True))

    return click.argument(
        "pairs",
        type=PATH,
        nargs=-1,
        required=True,
        callback=pairs,
        metavar="IMAGE CAMERA ...",
        help=f"at least {minimum} image{'s' if minimum > 1 else ''}, each followed by its "
        f"{CAMERA_HELP.replace('of IMAGE', 'of the image')}",
    )


# ---------------------------------------------------------------------- shared options
def output_option(metavar: str, help: str) -> Callable[[F], F]:  # noqa: A002
    """The required ``-o/--output`` file."""
    return click.option("-o", "--output", type=PATH, required=True, metavar=metavar, help=help)


eps_option = click.option(
    "--eps",
    type=POSITIVE,
    metavar="POSTS",
    show_default="max(4, image ground sample distance in posts); see the README",
    help="visibility tolerance in DEM posts",
)
interp_option = click.option(
    "--interp",
    default=Interp.BILINEAR.value,
    **enum_choice(Interp),
    help="image interpolation",
)


def levels_option(help: str) -> Callable[[F], F]:  # noqa: A002
    """``--levels``: coarse-to-fine pyramid levels of the plane fit."""
    return click.option("--levels", type=click.IntRange(min=1), default=3, metavar="N", help=help)


def error_limit_option(help: str) -> Callable[[F], F]:  # noqa: A002
    """``--error-limit M``: where height error colours saturate."""
    return click.option(
        "--error-limit",
        type=POSITIVE,
        metavar="M",
        show_default="the 99th percentile of |error|",
        help=help,
    )
