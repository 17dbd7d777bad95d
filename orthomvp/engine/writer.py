"""The one writer of a run: tiles arrive in any order and go into tiled GeoTIFFs with windowed
writes. A Cloud-Optimized GeoTIFF's overview levels are made from the tiles as they arrive,
each into a tiled GeoTIFF of its own (:mod:`orthomvp.engine.overviews`), and at the end the
compressed tiles of all of them are laid out as a COG (:mod:`orthomvp.engine.cog`); a tiled
GeoTIFF gets GDAL's overviews at the end. Every output is written to a temporary file beside
its target, and all of a run's outputs are renamed onto their targets only when all of them
succeeded.
"""

from __future__ import annotations

import contextlib
import math
import os
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from affine import Affine
from rasterio.enums import Resampling
from rasterio.windows import Window

from orthomvp.engine.casting import IntegerCast, to_dtype
from orthomvp.engine.cog import assemble
from orthomvp.engine.grid import OutputGrid
from orthomvp.engine.overviews import AVERAGE, halve, window_level
from orthomvp.engine.plan import Plan
from orthomvp.engine.tile import source_dtype
from orthomvp.errors import InputError, OrthoMVPWarning
from orthomvp.io.output_checks import (
    API_FLAGS,
    Output,
    check_names,
    check_outputs,
    check_parent,
)
from orthomvp.io.outputs import atomic_paths, scratch_path
from orthomvp.io.raster import check_written
from orthomvp.io.write_errors import writing
from orthomvp.validate import number, of_type

FORMATS = ("cog", "gtiff")
COMPRESSIONS = ("deflate", "zstd", "lzw", "none")
LEVELS = {"zstd": 1}
"""Compression levels chosen for speed (GDAL's default for the others). zstd at level 1 writes
an orthophoto COG about twice as fast as deflate at GDAL's default level 6, at the same size
(measured on a 3-band float32 ngi-aerial orthophoto: 4.2 s against 7.8 s, 32 MB both)."""
NODATA = {"float32": np.nan, "uint8": 0, "uint16": 0, "int16": -32768}
"""Output data types of orthophotos and mosaics, with their default nodata values."""


@dataclass(frozen=True)
class Outputs:
    """What a run writes: ``ortho`` (orthophoto or mosaic, all bands), ``visibility`` (uint8
    codes of :class:`orthomvp.codes.Code`, one band per view, 0 = nodata), ``source`` (the
    1-based view each post came from, 0 = none; for a mosaic also its flag and the blend
    weights, :func:`source_names`): paths, or None for outputs not wanted.

    ``format`` "cog" (Cloud-Optimized GeoTIFF) or "gtiff" (tiled GeoTIFF with internal
    overviews); ``compress`` one of :data:`COMPRESSIONS` (with the predictor that fits the
    data type, at the level of :data:`LEVELS`, on all cores); ``dtype`` of ``ortho``, one of
    :data:`NODATA` (integers are rounded and clipped); ``nodata`` its nodata value (default
    from :data:`NODATA`; valid values that round to it move one step towards the type's
    range); ``blocksize`` internal tiles in pixels (a multiple of 16).

    The rules of the command line's outputs hold (:mod:`orthomvp.io.output_checks`): each
    output its own file, named .tif or .tiff, in a writable directory; an existing file is
    replaced only with ``overwrite``, and an input of the run (checked by
    :func:`~orthomvp.engine.run_plan`) only with ``overwrite`` and ``replace_input`` as well.
    The default refuses, as the command line does and unlike ``rasterio.open(path, "w")``:
    a run's outputs are often named after its inputs, and a silent replacement of a DEM or
    an image loses data that no rerun brings back.
    """

    ortho: str | Path | None = None
    visibility: str | Path | None = None
    source: str | Path | None = None
    format: str = "cog"
    compress: str = "zstd"
    dtype: str = "float32"
    nodata: float | None = None
    blocksize: int = 512
    overwrite: bool = False
    replace_input: bool = False

    def __post_init__(self) -> None:
        for name in ("ortho", "visibility", "source"):
            of_type(getattr(self, name), (str, os.PathLike, type(None)), f"output {name}")
        if not self.paths():
            raise InputError("no output asked for: give ortho, visibility or source")
        check_settings(self)
        check_names(self.outputs())
        for out in self.outputs():
            if out.path is not None:
                check_parent(out.path, f"{out.path}: {out.option}")
        for name, value, allowed in (
            ("format", self.format, FORMATS),
            ("compression", self.compress, COMPRESSIONS),
            ("data type", self.dtype, tuple(NODATA)),
        ):
            if value not in allowed:
                raise InputError(
                    f"output {name} must be one of {', '.join(allowed)}, not {value!r}"
                )
        if self.nodata is not None:
            if self.dtype == "float32":
                number_or_nan(self.nodata, "nodata")
            else:
                number(self.nodata, f"nodata of a {self.dtype} output", integer=True)
        if self.nodata is not None and self.dtype != "float32":
            info = np.iinfo(self.dtype)
            if not (info.min <= self.nodata <= info.max) or self.nodata != int(self.nodata):
                raise InputError(f"nodata {self.nodata} is not a {self.dtype} value")

    def outputs(self) -> list[Output]:
        """The outputs, for :mod:`orthomvp.io.output_checks`."""
        return [Output(kind, None if path is None else Path(path)) for kind, path in self.named()]

    def named(self) -> list[tuple[str, str | Path | None]]:
        """(kind, path or None) of every output."""
        return [("ortho", self.ortho), ("visibility", self.visibility), ("source", self.source)]

    def check(self, inputs: Sequence[tuple[str, Path | str]]) -> None:
        """Refuse, before any work, outputs that would replace one of ``inputs`` ((label,
        path) pairs) or an existing file without ``overwrite`` (and ``replace_input``), or
        whose directory cannot be written; InputError (OutputError for a full disk)."""
        check_outputs(self.outputs(), inputs, self.overwrite, self.replace_input, API_FLAGS)

    def paths(self) -> dict[str, Path]:
        """The outputs asked for, by kind ("ortho", "visibility", "source")."""
        paths = {"ortho": self.ortho, "visibility": self.visibility, "source": self.source}
        return {kind: Path(path) for kind, path in paths.items() if path is not None}

    @property
    def fill(self) -> float:
        """The nodata value of ``ortho``."""
        return NODATA[self.dtype] if self.nodata is None else self.nodata


def check_settings(outputs: Any) -> None:
    """InputError for ``outputs``' (an :class:`Outputs` or a ``FitOutputs``) ``blocksize``
    that is not a multiple of 16 pixels, or ``overwrite`` and ``replace_input`` that are not
    booleans."""
    number(outputs.blocksize, "block size", minimum=16, integer=True)
    if outputs.blocksize % 16:
        raise InputError(f"block size must be a multiple of 16 pixels, got {outputs.blocksize}")
    of_type(outputs.overwrite, bool, "overwrite")
    of_type(outputs.replace_input, bool, "replace_input")


def number_or_nan(value: Any, what: str) -> float:
    """``value`` as a float when it is a real number, NaN included; InputError otherwise."""
    if isinstance(value, float) and math.isnan(value):
        return value
    return float(number(value, what))


def plan_inputs(plan: Any) -> list[tuple[str, Path]]:
    """The input files of a plan (its ``dem`` and ``views``), labelled as the command line
    labels them, for :meth:`Outputs.check`."""
    inputs = [("DEM", Path(plan.dem.path))]
    n = len(plan.views)
    for k, view in enumerate(plan.views, start=1):
        inputs.append((f"IMAGE {k}" if n > 1 else "IMAGE", Path(view.path)))
    return inputs


def _creation(outputs: Outputs, dtype: str) -> dict[str, object]:
    """GDAL creation options shared by the tiled GeoTIFF and the COG."""
    opts: dict[str, object] = {"compress": outputs.compress, "bigtiff": "IF_SAFER"}
    if outputs.compress != "none":
        opts["predictor"] = 3 if dtype == "float32" else 2
        opts["num_threads"] = "ALL_CPUS"
    if outputs.compress in LEVELS:
        opts[f"{outputs.compress}_level"] = LEVELS[outputs.compress]
    return opts


def _overview_factors(shape: tuple[int, int], blocksize: int) -> list[int]:
    """Powers of two down to the first level that fits in one block."""
    factors, f = [], 2
    while max(shape) / (f // 2) > blocksize:
        factors.append(f)
        f *= 2
    return factors


@dataclass(frozen=True)
class Layer:
    """One output file of a run: ``path``, ``count`` bands of ``dtype`` with ``nodata`` (None:
    none), band ``names``, the overview ``resampling``, and ``data(result)``: a finished
    tile's arrays for it ((bands, rows, cols) or (rows, cols), already of ``dtype``); ``cast``:
    what counts the values an integer ``dtype`` loses, said once the output is written."""

    path: Path
    count: int
    dtype: str
    nodata: float | None
    resampling: Resampling
    data: Callable[[Any], np.ndarray]
    names: tuple[str, ...] = ()
    cast: IntegerCast | None = None
    photometric: str | None = None  # "RGB" for an orthophoto of RGB images


def source_names(views: int) -> tuple[str, ...]:
    """Band names of a mosaic's source raster: the 1-based view (0 = none), the
    :class:`~orthomvp.ortho.holes.Flag` (how the post was filled, or why it is empty), and each
    view's blend weight in 1/255."""
    return ("view", "flag", *(f"weight {k}" for k in range(1, views + 1)))


def ortho_layers(plan: Plan, outputs: Outputs) -> list[Layer]:
    """The layers of :class:`Outputs` (orthophoto or mosaic, visibility codes, source)."""
    n = len(plan.views)
    source = np.dtype(source_dtype(plan)).name
    names = ("view",) if plan.mosaic is None else source_names(n)
    fill = outputs.fill

    integers = all(v.dtype is not None and np.dtype(v.dtype).kind in "iu" for v in plan.views)

    def image(path: Path) -> Layer:
        cast = None
        if outputs.dtype != "float32":
            cast = IntegerCast(path, outputs.dtype, fill, from_integers=integers)

        def data(result: Any) -> np.ndarray:
            if cast is None:
                return to_dtype(result.data, outputs.dtype, fill)
            return cast(result.data)

        rgb = "RGB" if plan.bands == 3 and all(v.rgb for v in plan.views) else None
        average = Resampling.average
        return Layer(
            path, plan.bands, outputs.dtype, fill, average, data, cast=cast, photometric=rgb
        )

    make = {
        "ortho": image,
        "visibility": lambda path: Layer(
            path, n, "uint8", 0, Resampling.nearest, lambda result: result.codes
        ),
        "source": lambda path: Layer(
            path, len(names), source, 0, Resampling.nearest, lambda r: r.source, names
        ),
    }
    return [make[kind](path) for kind, path in outputs.paths().items()]


def _size(layer: Layer, grid: OutputGrid, outputs: Any) -> int:
    """Bytes an output takes on disk at most while it is written: uncompressed, with its
    overviews, and for a COG twice (the tiled work file and the copy)."""
    rows, cols = grid.shape
    size = rows * cols * layer.count * np.dtype(layer.dtype).itemsize * 4 // 3
    return 2 * size if outputs.format == "cog" else size


def output_bytes(plan: Plan, outputs: Outputs) -> int:
    """Bytes the outputs of ``plan`` take on disk at most while they are written (``_size``)."""
    return sum(_size(layer, plan.grid, outputs) for layer in ortho_layers(plan, outputs))


LEVEL_WINDOW = 1024
"""Side (posts of the level before) of the windows in which the overview levels that no
tile could make are made at the end."""


class _Output:
    """One output being written: its dataset open for windowed writes, and for a COG one per
    overview level (``levels``: the file of each level's factor). Every step that writes
    reports a failure as one OutputError naming the output (see
    :func:`orthomvp.io.write_errors.writing`)."""

    def __init__(
        self,
        layer: Layer,
        grid: OutputGrid,
        outputs: Any,
        final: Path,
        work: Path,
        size: int,
        levels: dict[int, Path],
    ):
        self.layer, self.final, self.work, self.outputs = layer, final, work, outputs
        self.size, self.shape = size, grid.shape
        self.dtype, self.resampling = layer.dtype, layer.resampling
        self.factors = list(levels)
        self.made = [0] * len(levels)
        self.level_paths = list(levels.values())
        rows, cols = grid.shape
        self.profile = {
            "driver": "GTiff",
            "height": rows,
            "width": cols,
            "count": layer.count,
            "dtype": self.dtype,
            "crs": grid.crs.to_wkt(),
            "transform": grid.transform,
            "nodata": layer.nodata,
            "tiled": True,
            "blockxsize": outputs.blocksize,
            "blockysize": outputs.blocksize,
            **_creation(outputs, self.dtype),
        }
        if layer.photometric is not None:  # (GDAL's default for 3 bands other than bytes: grey)
            self.profile["photometric"] = layer.photometric
        self.levels: list[Any] = []
        with writing(layer.path, size):
            self.dataset = rasterio.open(work, "w", **self.profile)
            try:
                for band, name in enumerate(layer.names, start=1):
                    self.dataset.set_band_description(band, name)
                for factor, path in levels.items():
                    self.levels.append(rasterio.open(path, "w", **self._level_profile(factor)))
            except BaseException:
                self.close()
                raise

    def _level_profile(self, factor: int) -> dict[str, Any]:
        """The profile of overview level ``factor``: the output's, on 1 / ``factor`` the posts."""
        rows, cols = self.shape
        return self.profile | {
            "height": -(-rows // factor),
            "width": -(-cols // factor),
            "transform": self.profile["transform"] @ Affine.scale(factor),
        }

    def write(self, result: Any) -> None:
        """A tile's arrays into the output, and into every overview level it holds whole."""
        r0, r1, c0, c1 = result.window
        data = self.layer.data(result)
        data = data[None] if data.ndim == 2 else data
        with writing(self.layer.path, self.size):
            self.dataset.write(data, window=Window(c0, r0, c1 - c0, r1 - r0))
            values = data
            for i, factor in enumerate(self.factors):
                window = window_level(result.window, self.shape, factor)
                if window is None:
                    break
                halved = halve(values, self.resampling.name, self.layer.nodata)
                values = self._write_level(i, halved, window)

    def _write_level(self, i: int, values: np.ndarray, window: tuple[int, ...]) -> np.ndarray:
        """``values`` (as :func:`halve` gives them) into ``window`` of level ``i``; returns
        what was written (of the output's type), from which the next level is made, as it is
        from the file when no tile holds that level's blocks whole."""
        r0, r1, c0, c1 = window
        if self.resampling.name == AVERAGE:
            nodata = np.nan if self.layer.nodata is None else self.layer.nodata
            values = to_dtype(values, self.dtype, nodata)
        self.levels[i].write(values, window=Window(c0, r0, c1 - c0, r1 - r0))
        self.made[i] += (r1 - r0) * (c1 - c0)
        return values

    def close(self) -> None:
        """Close the datasets after a failure, quietly (their temporary files go anyway)."""
        for dataset in (self.dataset, *self.levels):
            with contextlib.suppress(OSError), writing(self.layer.path):
                dataset.close()

    def finish(self) -> None:
        """Overviews, then (COG) the layout of the final temporary file; then the final file is
        checked to open (see :func:`orthomvp.io.raster.check_written`)."""
        with writing(self.layer.path, self.size):
            self._finish()
            check_written(self.final)

    def _finish(self) -> None:
        for dataset in (self.dataset, *self.levels):
            dataset.close()
        if self.outputs.format == "gtiff":
            # overviews on all cores (GDAL_NUM_THREADS: 1.57 s to 0.99 s for a 3-band
            # 2,604 x 4,656 float32 orthophoto on 2 cores)
            factors = _overview_factors(self.shape, self.outputs.blocksize)
            with rasterio.Env(GDAL_NUM_THREADS="ALL_CPUS"), rasterio.open(self.work, "r+") as dst:
                dst.build_overviews(factors, self.resampling)
            return
        for i, factor in enumerate(self.factors):
            rows, cols = -(-self.shape[0] // factor), -(-self.shape[1] // factor)
            if self.made[i] != rows * cols:  # then also every level after it
                for j in range(i, len(self.factors)):
                    self._level_from_previous(j)
                break
        assemble(self.work, self.level_paths, self.final)

    def _level_from_previous(self, i: int) -> None:
        """Make overview level ``i`` from the level before (the full resolution for the first),
        in windows of :data:`LEVEL_WINDOW` posts of it."""
        source = self.work if i == 0 else self.level_paths[i - 1]
        self.made[i] = 0
        with rasterio.open(source) as src, rasterio.open(self.level_paths[i], "r+") as dst:
            self.levels[i] = dst
            for r in range(0, src.height, LEVEL_WINDOW):
                for c in range(0, src.width, LEVEL_WINDOW):
                    h, w = min(LEVEL_WINDOW, src.height - r), min(LEVEL_WINDOW, src.width - c)
                    values = halve(
                        src.read(window=Window(c, r, w, h)), self.resampling.name, src.nodata
                    )
                    self._write_level(
                        i, values, (r // 2, -(-(r + h) // 2), c // 2, -(-(c + w) // 2))
                    )


class Writer:
    """Writes tiles into every output of a run (see :func:`output_files`)."""

    def __init__(self, items: list[_Output]):
        self.items = items

    def write(self, result: Any) -> None:
        """Write one tile's arrays into their windows of every output."""
        for item in self.items:
            item.write(result)


@contextlib.contextmanager
def output_set(plan: Plan, outputs: Outputs) -> Iterator[Writer]:
    """:func:`output_files` of :class:`Outputs` on the plan's grid."""
    with output_files(plan.grid, ortho_layers(plan, outputs), outputs) as writer:
        yield writer


@contextlib.contextmanager
def output_files(grid: OutputGrid, layers: list[Layer], outputs: Any) -> Iterator[Writer]:
    """A :class:`Writer` of ``layers`` on ``grid``, in the ``format``, with the ``compress``
    and ``blocksize`` of ``outputs``; when the block succeeds, overviews (and the COG copies)
    are made and every output is renamed onto its target; when anything fails, no target is
    touched and every temporary file is removed."""
    with contextlib.ExitStack() as stack:
        sizes = [_size(layer, grid, outputs) for layer in layers]
        # what surely is needed: only uncompressed sizes are known before writing
        need = sizes if outputs.compress == "none" else []
        finals = stack.enter_context(atomic_paths([layer.path for layer in layers], need))
        items = []
        factors = _overview_factors(grid.shape, outputs.blocksize)
        for layer, final, size in zip(layers, finals, sizes, strict=True):
            work, levels = final, {}
            if outputs.format == "cog":
                work = stack.enter_context(scratch_path(layer.path, ".tiled"))
                levels = {
                    factor: stack.enter_context(scratch_path(layer.path, f".ovr{factor}"))
                    for factor in factors
                }
            item = _Output(layer, grid, outputs, final, work, size, levels)
            stack.callback(item.close)
            items.append(item)
        yield Writer(items)
        for item in items:
            item.finish()
    for layer in layers:
        if layer.cast is not None and (loss := layer.cast.loss()) is not None:
            warnings.warn(loss, OrthoMVPWarning, stacklevel=3)
