"""Tiles in the DEM's own frame, the lon/lat graticule, and PNG encoding.

The pyramid is square: zoom 0 is one TILE x TILE pixel tile whose side ``span`` (map units) is
the DEM's longer side, anchored at its top-left corner; zoom z has 2^z x 2^z tiles, x to the
east and y to the south. The page's Leaflet map uses the matching ``L.CRS.Simple``-like
transformation (see :meth:`Pyramid.leaflet`), so nothing is reprojected. A tile reads only its
own rectangle at its own scale (the files' overviews), so memory is bounded by the tile size.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np
from PIL import Image

from orthomvp.view.layers import Bounds, Layer, LayerSet, map_bounds

TILE = 256
"""Tile side, pixels."""
OVERZOOM = 3
"""Zoom levels past the finest layer's pixels that the map allows (pixels drawn larger)."""
GRATICULE_LINES = 6
"""About how many graticule lines per direction cover the DEM."""


@dataclass(frozen=True)
class Pyramid:
    """The tile pyramid over a DEM: top-left corner (``left``, ``top``) and ``span``."""

    left: float
    top: float
    span: float
    max_native: int

    @classmethod
    def of(cls, layers: LayerSet) -> Pyramid:
        left, bottom, right, top = layers.bounds
        span = max(right - left, top - bottom)
        native = max(0, math.ceil(math.log2(span / (TILE * layers.resolution))))
        return cls(left, top, span, native)

    def bounds(self, z: int, x: int, y: int) -> Bounds:
        """The map rectangle of tile (z, x, y)."""
        side = self.span / 2**z
        left = self.left + x * side
        top = self.top - y * side
        return (left, top - side, left + side, top)

    def valid(self, z: int, x: int, y: int) -> bool:
        return 0 <= z <= self.max_native and 0 <= x < 2**z and 0 <= y < 2**z

    def leaflet(self) -> dict:
        """The page's map settings: L.Transformation(a, b, c, d) from (lng = x, lat = y) to
        pixels at zoom 0, and the zoom range."""
        a = TILE / self.span
        return {
            "transformation": [a, -a * self.left, -a, a * self.top],
            "maxNativeZoom": self.max_native,
            "maxZoom": self.max_native + OVERZOOM,
        }


def render(layer: Layer, bounds: Bounds, size: tuple[int, int], mpp: float) -> np.ndarray:
    """RGBA (rows, cols, 4) uint8 of ``layer`` over ``bounds`` at ``size`` (cols, rows);
    transparent where no file covers; ``mpp`` ground metres per output pixel (for shading)."""
    cols, rows = size
    values = layer.read(bounds, size)
    if values is None:
        return np.zeros((rows, cols, 4), np.uint8)
    rgba = layer.kind.colour(values, layer.stats, mpp)
    covered = _covered(layer, bounds, size)
    rgba[~covered] = 0
    return rgba


def _covered(layer: Layer, bounds: Bounds, size: tuple[int, int]) -> np.ndarray:
    """(rows, cols) bool: output pixels inside every file of the layer."""
    cols, rows = size
    left, bottom, right, top = bounds
    x = left + (np.arange(cols) + 0.5) * (right - left) / cols
    y = top - (np.arange(rows) + 0.5) * (top - bottom) / rows
    inside = np.ones((rows, cols), bool)
    for d in layer.datasets:
        b_left, b_bottom, b_right, b_top = map_bounds(d)
        inside &= ((y >= b_bottom) & (y <= b_top))[:, None] & ((x >= b_left) & (x <= b_right))
    return inside


def tile_png(layers: LayerSet, pyramid: Pyramid, layer: Layer, z: int, x: int, y: int) -> bytes:
    """The PNG of one tile of ``layer``."""
    bounds = pyramid.bounds(z, x, y)
    mpp = layers.metres_per_unit() * (bounds[2] - bounds[0]) / TILE
    return png(render(layer, bounds, (TILE, TILE), mpp))


def png(rgba: np.ndarray) -> bytes:
    """PNG bytes of an RGBA (rows, cols, 4) uint8 array."""
    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def _step(extent: float) -> float:
    """A round step in degrees giving about GRATICULE_LINES lines over ``extent``."""
    raw = max(extent, 1e-9) / GRATICULE_LINES
    base = 10 ** math.floor(math.log10(raw))
    return next(m * base for m in (1, 2, 2.5, 5, 10) if m * base >= raw)


def graticule(layers: LayerSet, samples: int = 64) -> list[dict]:
    """Lines of constant longitude and latitude over the DEM as map-coordinate polylines:
    [{"label": "25.05° E", "kind": "lon"|"lat", "points": [[x, y], ...]}, ...]."""
    left, bottom, right, top = layers.bounds
    gx, gy = np.meshgrid(np.linspace(left, right, samples), np.linspace(bottom, top, samples))
    lon, lat = layers.lonlat(gx.ravel(), gy.ravel())
    lon, lat = np.asarray(lon), np.asarray(lat)
    out = []
    for kind, values, other in (("lon", lon, lat), ("lat", lat, lon)):
        lo, hi = float(np.nanmin(values)), float(np.nanmax(values))
        step = _step(hi - lo)
        o = np.linspace(np.nanmin(other), np.nanmax(other), samples)
        for v in np.arange(math.ceil(lo / step) * step, hi + step * 1e-9, step):
            args = (np.full(samples, v), o) if kind == "lon" else (o, np.full(samples, v))
            x, y = layers.map_xy(*args)
            pts = [[float(a), float(b)] for a, b in zip(x, y, strict=True) if np.isfinite(a)]
            hemi = ("E" if v >= 0 else "W") if kind == "lon" else ("N" if v >= 0 else "S")
            label = f"{round(abs(v), 9):g}° {hemi}"
            out.append({"label": label, "kind": kind, "points": pts})
    return out
