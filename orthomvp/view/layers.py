"""The files a viewer shows: a registry of layer ids to the rasters the user named.

The map's frame is the DEM's CRS: map coordinates (x, y) are its easting and northing (or
longitude and latitude in degrees for a geographic DEM). A layer is on the DEM's grid when it
shares its CRS and overlaps it; any resolution is fine (each tile is read at its own scale). A
file that is missing, not a raster, or off the grid is refused with a one-line reason and the
rest still work. Requests name layers by id only: no path from a request ever opens a file.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rasterio
from pyproj import CRS, Geod, Transformer
from rasterio.enums import Resampling
from rasterio.windows import Window

from orthomvp.errors import InputError
from orthomvp.io.raster import open_raster
from orthomvp.view.kinds import KINDS, Kind, Stats

SAMPLE = 512
"""Longest side, in pixels, of the coarse read that sets a layer's colour range."""

Bounds = tuple[float, float, float, float]
"""(left, bottom, right, top) in map coordinates."""


@dataclass
class Layer:
    """One layer: ``id`` (what requests say), ``title``, ``kind`` (a :data:`KINDS` name),
    ``paths`` (the kind's files, opened once and read under a lock), and its colour range."""

    id: str
    title: str
    kind: Kind
    paths: tuple[Path, ...]
    datasets: list[rasterio.DatasetReader] = field(default_factory=list)
    stats: Stats = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def resolution(self) -> float:
        """The finest pixel size of its files, map units."""
        return min(min(abs(d.res[0]), abs(d.res[1])) for d in self.datasets)

    def read(self, bounds: Bounds, size: tuple[int, int]) -> np.ndarray | None:
        """Values (bands, rows, cols) float64 of the map rectangle ``bounds`` resampled to
        ``size`` (cols, rows) pixels, NaN where a file has no value and outside it; None when
        the rectangle misses the files. Decimated reads come from the files' overviews."""
        with self.lock:
            arrays = [_read(d, bounds, size, self.kind.categorical) for d in self.datasets]
        if any(a is None for a in arrays):
            return None
        return self.kind.combine(arrays)  # type: ignore[arg-type]

    def value_at(self, x: float, y: float) -> np.ndarray | None:
        """The values (bands,) at map point (x, y) (the pixel it falls in), None outside."""
        out = []
        with self.lock:
            for d in self.datasets:
                r, c = d.index(x, y, op=np.floor)
                if not (0 <= r < d.height and 0 <= c < d.width):
                    return None
                a = d.read(window=Window(c, r, 1, 1), masked=True).astype(np.float64)
                out.append(a.filled(np.nan)[:, 0, 0][:, None, None])
        return self.kind.combine(out)[:, 0, 0]

    def close(self) -> None:
        for d in self.datasets:
            d.close()


def _read(
    d: rasterio.DatasetReader, bounds: Bounds, size: tuple[int, int], nearest: bool
) -> np.ndarray | None:
    """Read ``bounds`` of ``d`` onto ``size`` (cols, rows) pixels (see :meth:`Layer.read`),
    north up whichever way the file's rows and columns run (a south-up file's rows flipped)."""
    cols, rows = size
    left, bottom, right, top = bounds
    (ca, ra), (cb, rb) = ~d.transform @ (left, top), ~d.transform @ (right, bottom)
    (col_lo, col_hi), (row_lo, row_hi) = sorted((ca, cb)), sorted((ra, rb))
    c0, r0 = max(col_lo, 0.0), max(row_lo, 0.0)
    c1, r1 = min(col_hi, d.width), min(row_hi, d.height)
    if c1 <= c0 or r1 <= r0:
        return None
    # the part of the output the file covers, in output pixels (file order)
    x0 = int(round((c0 - col_lo) / (col_hi - col_lo) * cols))
    x1 = int(round((c1 - col_lo) / (col_hi - col_lo) * cols))
    y0 = int(round((r0 - row_lo) / (row_hi - row_lo) * rows))
    y1 = int(round((r1 - row_lo) / (row_hi - row_lo) * rows))
    out = np.full((d.count, rows, cols), np.nan)
    if x1 <= x0 or y1 <= y0:
        return out
    part = d.read(
        window=Window(c0, r0, c1 - c0, r1 - r0),
        out_shape=(d.count, y1 - y0, x1 - x0),
        resampling=Resampling.nearest if nearest else Resampling.bilinear,
        masked=True,
    )
    part = part.astype(np.float64).filled(np.nan)
    if d.transform.e > 0:  # rows run south to north
        part, (y0, y1) = part[:, ::-1], (rows - y1, rows - y0)
    if d.transform.a < 0:  # columns run east to west
        part, (x0, x1) = part[:, :, ::-1], (cols - x1, cols - x0)
    out[:, y0:y1, x0:x1] = part
    return out


def map_bounds(d: rasterio.DatasetReader) -> Bounds:
    """(left, bottom, right, top) of a raster with left < right and bottom < top, whichever
    way its rows and columns run (rasterio gives a south-up file's ``bounds`` bottom > top)."""
    left, bottom, right, top = d.bounds
    return (min(left, right), min(bottom, top), max(left, right), max(bottom, top))


def _horizontal(crs: object) -> CRS:
    """The horizontal part of a CRS (a compound CRS's first; the DEM's may carry a vertical
    datum that its outputs do not)."""
    crs = CRS.from_user_input(crs.to_wkt() if hasattr(crs, "to_wkt") else crs)
    return crs.sub_crs_list[0] if crs.is_compound else crs


@dataclass
class Problem:
    """A file the viewer could not show, and why (one line)."""

    path: str
    reason: str


class LayerSet:
    """The DEM and the layers over it, by id (``L0`` the shaded DEM, then in the order given),
    the map frame (``bounds``, ``crs``) and the files refused (``problems``)."""

    def __init__(self, dem: Path) -> None:
        """Open the DEM (an InputError when it is missing, no georeferenced raster, or cannot be
        shown: there is nothing to show the other layers over). North-up and south-up files
        alike (rows running either way): the map's frame is north up."""
        with open_raster(dem) as src:
            if src.crs is None:
                raise InputError(f"{dem}: the DEM has no CRS")
            self.crs = CRS.from_user_input(src.crs.to_wkt())
            self.bounds: Bounds = map_bounds(src)
            self.shape = (src.height, src.width)
            self.transform = src.transform
        self.dem = Path(dem)
        self.layers: dict[str, Layer] = {}
        self.problems: list[Problem] = []
        if self.add("relief", [dem], f"DEM shaded: {Path(dem).name}") is None:
            raise InputError(self.problems[0].reason)  # nothing to show the others over
        geographic = self.crs.geodetic_crs or self.crs
        self._lonlat = Transformer.from_crs(self.crs, geographic, always_xy=True)
        self._geod = Geod(ellps="WGS84") if self.crs.ellipsoid is None else self.crs.get_geod()

    def add(
        self, kind: str, paths: str | Path | Sequence[str | Path], title: str | None = None
    ) -> Layer | None:
        """Add a layer of ``kind`` (one of :data:`KINDS`; InputError otherwise) from
        ``paths`` (one file or several); a file that cannot be shown (missing, not on the
        DEM's grid) goes to ``problems`` and None is returned, as the page lists it."""
        if kind not in KINDS:
            raise InputError(f"layer kind must be one of {', '.join(KINDS)}, not {kind!r}")
        paths = [Path(paths)] if isinstance(paths, str | Path) else [Path(p) for p in paths]
        if not paths:
            raise InputError("a layer needs at least one file")
        the_kind = KINDS[kind]
        title = title or f"{kind}: {paths[0].name}"
        datasets = []
        try:
            for p in paths:
                datasets.append(self._open(p))
        except InputError as exc:
            for d in datasets:
                d.close()
            self.problems.append(Problem(str(paths[len(datasets)]), str(exc)))
            return None
        layer = Layer(f"L{len(self.layers)}", title, the_kind, tuple(paths), datasets)
        layer.stats = the_kind.stats(self._sample(layer))
        self.layers[layer.id] = layer
        return layer

    def add_source(self, path: Path, title: str | None = None) -> None:
        """Add a mosaic's source raster: the source layer, and its flags layer (band 2: how
        each post was filled, or why it is empty) when the file has that band."""
        layer = self.add("source", [path], title)
        if layer is not None and layer.datasets[0].count >= 2:
            self.add("flags", [path], f"hole reasons: {Path(path).name}")

    def _open(self, path: Path) -> rasterio.DatasetReader:
        src = open_raster(path)
        try:
            if src.crs is None or not _horizontal(src.crs).equals(
                _horizontal(self.crs), ignore_axis_order=True
            ):
                raise InputError(f"{path}: not on the DEM's grid (its CRS is not the DEM's)")
            left, bottom, right, top = map_bounds(src)
            l0, b0, r0, t0 = self.bounds
            if right <= l0 or left >= r0 or top <= b0 or bottom >= t0:
                raise InputError(f"{path}: not on the DEM's grid (it does not overlap the DEM)")
        except BaseException:
            src.close()
            raise
        return src

    def _sample(self, layer: Layer) -> np.ndarray:
        """A coarse read of the whole layer (from its smallest useful overview)."""
        left, bottom, right, top = self.bounds
        w, h = right - left, top - bottom
        scale = SAMPLE / max(w, h)
        size = (max(int(w * scale), 1), max(int(h * scale), 1))
        values = layer.read(self.bounds, size)
        return np.full((1, 1, 1), np.nan) if values is None else values

    # ------------------------------------------------------------------ map frame
    @property
    def resolution(self) -> float:
        """The finest pixel size of any layer, map units."""
        return min(layer.resolution for layer in self.layers.values())

    def lonlat(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map coordinates to longitude and latitude in degrees on the DEM's body."""
        return self._lonlat.transform(x, y)

    def map_xy(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Longitude and latitude (degrees) to map coordinates."""
        return self._lonlat.transform(lon, lat, direction="INVERSE")

    def metres_per_unit(self) -> float:
        """Ground metres per map unit along x at the DEM's centre (the scale bar's)."""
        left, bottom, right, top = self.bounds
        cx, cy, d = (left + right) / 2, (bottom + top) / 2, (right - left) / 100
        lon, lat = self.lonlat(np.array([cx - d, cx + d]), np.array([cy, cy]))
        return float(self._geod.inv(lon[0], lat[0], lon[1], lat[1])[2] / (2 * d))

    def close(self) -> None:
        for layer in self.layers.values():
            layer.close()
