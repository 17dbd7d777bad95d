"""The arguments and options that several commands share, each defined once: the DEM and how
to read it, images and cameras, the visibility tolerance, interpolation, pyramid levels, error
colour limits and the output file; and the value types they check."""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from orthomvp.codes import Interp, WorldFrame
from orthomvp.io.output_checks import Output

if TYPE_CHECKING:
    from orthomvp.camera import Camera
    from orthomvp.geometry.terrain import Terrain

F = TypeVar("F", bound=Callable[..., Any])
PATH = click.Path(path_type=Path)
"""A file or directory name; its existence is checked where it is read, with a clear message."""


class FilePath(click.Path):
    """The name of an output file: one ending in ``/`` (which names a directory, and which
    ``Path`` would drop) is refused."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and value.endswith(("/", os.sep)):
            self.fail(f"{value}: ends in '/', so names a directory; give a file name", param, ctx)
        return super().convert(value, param, ctx)


OUT_FILE = FilePath(path_type=Path)
"""An output file's name (see :class:`FilePath`)."""


class PrefixPath(click.Path):
    """The prefix of a table and its plot (PREFIX.csv, PREFIX.png): a prefix given that names
    a directory (``.``, one ending in ``/``, an existing directory) is refused."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        path = super().convert(value, param, ctx)
        given = not (  # (a folder named as the default is no mistake of the user's)
            ctx is not None
            and param is not None
            and ctx.get_parameter_source(param.name) == click.core.ParameterSource.DEFAULT
        )
        if (
            given
            and isinstance(path, Path)
            and (
                str(value).endswith(("/", os.sep)) or path.name in ("", ".", "..") or path.is_dir()
            )
        ):
            example = Path(value) / "results"
            self.fail(
                f"{value} names a directory; -o is the PREFIX of the files written, PREFIX.csv "
                f"and PREFIX.png (e.g. -o {example})",
                param,
                ctx,
            )
        return path


def prefix_files(prefix: Path) -> tuple[Path, Path]:
    """The table and plot of an output ``prefix``: PREFIX.csv and PREFIX.png (the suffixes
    added to the whole name, so ``eps0.5`` gives ``eps0.5.csv``; a ``.csv`` or ``.png`` given
    with it is taken for the one of the pair it names, so ``check.csv`` gives ``check.csv``
    and ``check.png``)."""
    name = prefix.name
    if Path(name).suffix.lower() in (".csv", ".png") and Path(name).stem:
        name = Path(name).stem
    return prefix.with_name(name + ".csv"), prefix.with_name(name + ".png")


CAMERA_HELP = (
    "camera model, any of: ASP .tsai or .pinhole; our .json; an Orthority exterior file (.csv, "
    ".geojson; the row of IMAGE, the one .yaml beside it) or RPC .yaml; an OpenSfM "
    "reconstruction.json or ODM shots.geojson (the shot of IMAGE); a USGS CSM ISD or model "
    "state .json (line scan, frame, push frame); an RPC camera: the image itself when its "
    "GeoTIFF holds RPC metadata, an _RPC.TXT or an .RPB file; a spiceinit'd ISIS3 .cub (the cube "
    "itself: LRO NAC and WAC, MRO CTX, Kaguya TC, Mars Express HRSC, Apollo Metric, MESSENGER "
    "MDIS, Dawn FC)"
)
"""What a CAMERA may be: every kind of :data:`orthomvp.camera.FORMATS` (not imported: --help
stays fast; a test checks that every kind is named)."""


class Number(click.FloatRange):
    """A finite number (NaN and infinities refused) within optional bounds; --help shows the
    range (``x>0``, ``0<=x<=1``)."""

    name = "float"

    def _describe_range(self) -> str:
        return "finite" if self.min is None and self.max is None else super()._describe_range()

    def convert(
        self, value: Any, param: click.Parameter | None, ctx: click.Context | None
    ) -> float:
        number = click.FLOAT.convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{number} is not a finite number", param, ctx)
        return float(super().convert(number, param, ctx))


POSITIVE = Number(min=0, min_open=True)
"""A finite number > 0."""
NON_NEGATIVE = Number(min=0)
"""A finite number >= 0."""
FINITE = Number()
"""Any finite number."""


class SizeOrZero(click.IntRange):
    """An integer that is 0 (skip) or at least ``minimum``; --help shows ``x=0 or x>=N``."""

    def __init__(self, minimum: int) -> None:
        super().__init__(min=0)
        self.minimum = minimum

    def _describe_range(self) -> str:
        return f"x=0 or x>={self.minimum}"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> int:
        number = super().convert(value, param, ctx)
        if 0 < number < self.minimum:
            self.fail(f"{number} is not 0 (skip) or at least {self.minimum}", param, ctx)
        return number


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
    """Whether ``-q`` asked for warnings and errors only."""
    return bool(click.get_current_context().find_root().params.get("quiet"))


def say(line: str, *, err: bool = False) -> None:
    """Print an informational ``line`` as ``orthomvp: line``, on stdout (stderr with ``err``);
    nothing with ``-q``."""
    if not quiet():
        click.echo(f"orthomvp: {line}", err=err)


quiet_option = click.option(
    "-q", "--quiet", is_flag=True, help="print warnings and errors only (no progress or summary)"
)


# ------------------------------------------------------------------------------------ DEM
@dataclass(frozen=True)
class DemInput:
    """The DEM argument and the options saying how to read it."""

    path: Path | None
    """None only for a command whose DEM may come from ``--odm``, until it does"""
    radius_values: bool = False
    crs: str | None = None
    world: str = "auto"
    """"auto", or a :class:`WorldFrame` value"""
    vertical_datum: str = "auto"
    """"auto" or "ignore" (:mod:`orthomvp.geometry.datum`)"""
    height_offset: float | None = None
    """metres added to the DEM's heights, or None"""

    def plan_options(self) -> dict[str, object]:
        """How the engine's plans (``plan_ortho``, ``plan_check``, ``plan_fit``) read the DEM:
        their ``dem_crs``, ``radius_values``, ``world``, ``vertical_datum`` and
        ``height_offset``."""
        return {
            "dem_crs": self.crs,
            "radius_values": self.radius_values,
            "world": self.world,
            "vertical_datum": self.vertical_datum,
            "height_offset": self.height_offset,
        }

    def read(self, cameras: Sequence[Camera] = (), *, spare: bool = False) -> Terrain:
        """The DEM; ``auto`` picks the world frame from the ``cameras``' centres (see
        :func:`orthomvp.geometry.world.detect_world`), body-fixed when there are none. In the body
        frame every camera must sit above the DEM
        (:func:`orthomvp.geometry.world.check_cameras_above`; with ``spare``, a command that
        can do without them, cameras over another part of the body pass)."""
        from dataclasses import replace

        from orthomvp.camera import camera_centres
        from orthomvp.geometry.terrain import Terrain
        from orthomvp.geometry.world import check_cameras_above, detect_world

        world = WorldFrame.BODY if self.world == "auto" else WorldFrame(self.world)
        heights = {"vertical_datum": self.vertical_datum, "height_offset": self.height_offset}
        if cameras:  # the frame and "above" from the heights as the file holds them
            raw = Terrain.read(self.path, self.radius_values, world, self.crs, **_AS_READ)
            centres, views = camera_centres(cameras)
            if self.world == "auto":
                world = detect_world(raw, centres, views)
            check_cameras_above(replace(raw, world=world), centres, views, spare=spare)
            if self.height_offset is None and self.vertical_datum == "auto":
                from orthomvp.camera.rpc import check_map_frame_heights
                from orthomvp.io.raster import open_raster

                with open_raster(self.path) as src:
                    crs = self.crs or src.crs
                named = [(f"camera {k + 1}", camera) for k, camera in enumerate(cameras)]
                check_map_frame_heights(named, world, crs, as_read=True)
        return Terrain.read(self.path, self.radius_values, world, self.crs, **heights)


_AS_READ: dict[str, Any] = {"vertical_datum": "ignore", "height_offset": None}
"""Terrain.read's options for heights as the file holds them."""


DEM_HELP = (
    "the DEM: a GeoTIFF (or any raster GDAL reads) of heights above the reference surface of "
    "its CRS (or radii: --radius-values)"
)
dem_argument = click.argument("dem", type=PATH, metavar="DEM", help=DEM_HELP)
optional_dem_argument = click.argument(
    "dem", type=PATH, metavar="[DEM]", required=False, help=f"{DEM_HELP}; not with --odm"
)
"""The DEM of a command that can also take it from ``--odm DIR``: None when not given."""


def dem_options(f: F) -> F:
    """--radius-values, --dem-crs, --world, --vertical-datum and --height-offset; the command
    receives them with its ``dem`` argument as one :class:`DemInput` named ``dem``."""

    @functools.wraps(f)
    def command(**kwargs: Any) -> Any:
        dem = DemInput(
            kwargs.pop("dem"),
            radius_values=kwargs.pop("radius_values"),
            crs=kwargs.pop("dem_crs"),
            world=kwargs.pop("world"),
            vertical_datum=kwargs.pop("vertical_datum"),
            height_offset=kwargs.pop("height_offset"),
        )
        if dem.height_offset is not None and dem.vertical_datum == "ignore":
            raise usage_error("give --height-offset or --vertical-datum ignore, not both")
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
        click.option(
            "--vertical-datum",
            type=click.Choice(["auto", "ignore"]),
            default="auto",
            show_default=True,
            help="heights of a DEM whose CRS has a vertical part (e.g. WGS84 + EGM2008 height): "
            "auto converts them with PROJ and the geoid's grid to the heights above the "
            "ellipsoid that RPCs and body-fixed cameras want, and refuses, naming the grid, "
            "when PROJ lacks it; cameras in the DEM's map frame take its heights as they are. "
            "ignore: use the heights as they are",
        ),
        click.option(
            "--height-offset",
            type=FINITE,
            metavar="METRES",
            help="metres added to every DEM height instead of the vertical datum's conversion, "
            "for any camera, RPCs included: e.g. the local geoid undulation (about 28 on the "
            "EGM2008 heights of the ngi-aerial DEM) when PROJ lacks the geoid's grid",
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
camera_argument = click.argument(
    "camera",
    type=PATH,
    required=False,
    metavar="[CAMERA]",
    help="its camera; omit it where IMAGE is its own camera (a GeoTIFF with RPC metadata, a "
    f"spiceinit'd ISIS3 cube). A {CAMERA_HELP}",
)
"""The optional CAMERA of a one-image command: the command takes IMAGE itself where absent."""


def pairs_argument(minimum: int = 1, *, optional: bool = False) -> Callable[[F], F]:
    """The ``IMAGE CAMERA [IMAGE CAMERA ...]`` argument, at least ``minimum`` pairs (or none
    when ``optional``: the views come from ``--odm``); the command receives a list of
    (image, camera) paths named ``pairs``."""

    def pairs(
        ctx: click.Context, param: click.Parameter, value: tuple[Path, ...]
    ) -> list[tuple[Path, Path]]:
        if len(value) % 2:
            raise click.UsageError("needs IMAGE CAMERA pairs: got an odd number of files", ctx)
        if len(value) < 2 * minimum and not (optional and not value):
            raise click.UsageError(f"needs at least {minimum} IMAGE CAMERA pairs", ctx)
        return list(zip(value[::2], value[1::2], strict=True))

    return click.argument(
        "pairs",
        type=PATH,
        nargs=-1,
        required=not optional,
        callback=pairs,
        metavar="[IMAGE CAMERA ...]" if optional else "IMAGE CAMERA ...",
        help=f"at least {minimum} image{'s' if minimum > 1 else ''}, each followed by its "
        f"{CAMERA_HELP.replace('of IMAGE', 'of the image')}"
        + ("; not with --odm" if optional else ""),
    )


# ---------------------------------------------------------------------- shared options
def output_option(metavar: str, help: str) -> Callable[[F], F]:  # noqa: A002
    """The required ``-o/--output`` file."""
    return click.option("-o", "--output", type=OUT_FILE, required=True, metavar=metavar, help=help)


def prefix_option(default: str) -> Callable[[F], F]:
    """The ``-o/--output`` prefix of a table and its plot (PREFIX.csv and PREFIX.png)."""
    return click.option(
        "-o",
        "--output",
        type=PrefixPath(path_type=Path),
        default=Path(default),
        metavar="PREFIX",
        help="output prefix: writes PREFIX.csv and PREFIX.png (-o out.csv names the same pair)",
    )


eps_option = click.option(
    "--eps",
    type=POSITIVE,
    metavar="POSTS",
    show_default="max(3, image ground sample distance in posts); see the README",
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


overwrite_option = click.option(
    "--overwrite",
    is_flag=True,
    help="replace output files that exist (without it an existing output is refused)",
)
replace_input_option = click.option(
    "--replace-input",
    is_flag=True,
    help="with --overwrite, let an output replace one of this command's inputs (every input is "
    "read in full first)",
)


def overwrite_options(f: F) -> F:
    """--overwrite and --replace-input, as the command's ``overwrite`` and ``replace_input``."""
    return overwrite_option(replace_input_option(f))


# --------------------------------------------------------------------- output checks
def check_outputs(
    outputs: Sequence[Output],
    inputs: Sequence[tuple[str, Path | None]] = (),
    overwrite: bool = False,
    replace_input: bool = False,
) -> None:
    """:func:`orthomvp.io.output_checks.check_outputs` (the rules the API follows too), its
    refusals as usage errors naming the options."""
    from orthomvp.errors import InputError
    from orthomvp.io.output_checks import check_outputs as check

    try:
        check(outputs, inputs, overwrite, replace_input)
    except InputError as exc:
        raise usage_error(str(exc)) from None


def own_camera(image: Path) -> Camera:
    """The camera IMAGE carries (its RPC metadata, a spiceinit'd cube's tables), for a command
    whose CAMERA was left out; a usage error that says so where IMAGE carries none (an
    IMAGE that is not there is named as a missing raster, as any missing input is)."""
    from orthomvp.camera import read_camera
    from orthomvp.errors import InputError
    from orthomvp.io.files import check_regular

    check_regular(image, "raster")
    try:
        return read_camera(image)
    except InputError as exc:
        raise usage_error(f"no CAMERA given, and IMAGE is not its own camera: {exc}") from None


def view_inputs(dem: DemInput, pairs: Sequence[tuple[Path, Path]]) -> list[tuple[str, Path]]:
    """The input files of a command reading ``dem`` and (image, camera) ``pairs``, labelled
    for :func:`check_outputs`."""
    inputs = [("DEM", dem.path)]
    for k, (image, camera) in enumerate(pairs, start=1):
        n = f" {k}" if len(pairs) > 1 else ""
        inputs += [(f"IMAGE{n}", image), (f"CAMERA{n}", camera)]
    return inputs


def check_outdir(
    path: Path, option: str, *, overwrite: bool = False, refresh: Sequence[str] = ()
) -> None:
    """:func:`orthomvp.io.output_checks.check_folder` (the rule the API follows too), its
    refusals as usage errors naming ``option`` and --overwrite."""
    from orthomvp.errors import InputError
    from orthomvp.io.output_checks import Flags, check_folder

    try:
        check_folder(path, option, overwrite=overwrite, refresh=refresh, flags=Flags())
    except InputError as exc:
        raise usage_error(str(exc)) from None
