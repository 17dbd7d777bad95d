"""What a layer of the viewer means: how its values are coloured, read out and explained.

One :class:`Kind` per meaning, in :data:`KINDS`; adding a kind of layer is one entry there. The
colours are the snapshots' (:mod:`orthomvp.present.colours`, :mod:`orthomvp.codes`): shaded
heights on :data:`~orthomvp.present.colours.HEIGHT_CMAP`, images grey or RGB with no value
violet, visibility codes in their fixed colours, height changes red up and blue down, views in
the camera colours, a mosaic's flags (how each post was filled, or why it is empty) in
:data:`FLAG_RGB`. Values come in as float64 (bands, rows, cols) with NaN where a file has no
value; colours go out as RGBA uint8 (rows, cols, 4).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import LightSource, Normalize, to_hex

from orthomvp.codes import CODE_RGB, Code
from orthomvp.ortho.holes import Flag
from orthomvp.present.colours import (
    CAMERA_COLOURS,
    ERROR_CMAP,
    HEIGHT_CMAP,
    NAN_RGB,
    image_colours,
)

UNCERTAINTY_CMAP = "magma"
"""Colour map of 1-sigma height uncertainties (metres): dark small, bright large."""

Stats = dict[str, float]
"""A layer's colour range, from its coarsest overview: ``lo``, ``hi`` (and ``bands``)."""


@dataclass(frozen=True)
class Kind:
    """A kind of layer. ``colour(values, stats, metres_per_pixel)`` -> RGBA; ``stats(sample)``
    the colour range from a coarse sample of the values; ``legend(stats)`` a JSON legend
    (``ramp``: colours, lo, hi, unit; or ``classes``: [label, css colour] pairs); ``describe``
    one value (bands,) as text for the hover readout; ``files`` how many rasters the layer
    reads (``combine`` makes one value array of them); ``categorical`` reads nearest posts."""

    name: str
    colour: Callable[[np.ndarray, Stats, float], np.ndarray]
    stats: Callable[[np.ndarray], Stats]
    legend: Callable[[Stats], dict]
    describe: Callable[[np.ndarray], str]
    categorical: bool = False
    files: int = 1
    combine: Callable[[list[np.ndarray]], np.ndarray] = field(default=lambda arrays: arrays[0])


def _rgba(rgb: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    out = np.empty((*shape, 4), np.uint8)
    out[..., :3] = rgb.reshape(*shape, 3)
    out[..., 3] = 255
    return out


def _percentiles(sample: np.ndarray, lo: float = 1, hi: float = 99) -> Stats:
    finite = sample[np.isfinite(sample)]
    if not finite.size:
        return {"lo": 0.0, "hi": 1.0}
    a, b = np.percentile(finite, [lo, hi])
    return {"lo": float(a), "hi": float(max(b, a + 1e-6))}


def _ramp(cmap: str, unit: str, label: str) -> Callable[[Stats], dict]:
    colours = [to_hex(c) for c in colormaps[cmap](np.linspace(0, 1, 11))]
    return lambda s: {
        "type": "ramp",
        "colours": colours,
        "lo": s["lo"],
        "hi": s["hi"],
        "unit": unit,
        "label": label,
    }


def _metres(v: np.ndarray, sign: bool = False, prefix: str = "") -> str:
    x = float(v[0])
    if not np.isfinite(x):
        return "no value"
    return f"{prefix}{x:+.2f} m" if sign else f"{prefix}{x:.2f} m"


# ------------------------------------------------------------------------------ heights
def _shaded(values: np.ndarray, stats: Stats, mpp: float) -> np.ndarray:
    """Heights on HEIGHT_CMAP, shaded from the north-west (as the snapshots' DEM)."""
    z = values[0]
    finite = np.isfinite(z)
    filled = np.where(finite, z, np.nanmean(z) if finite.any() else 0.0)
    norm = Normalize(stats["lo"], stats["hi"], clip=True)
    rgb = LightSource(azdeg=315, altdeg=35).shade(
        filled, cmap=colormaps[HEIGHT_CMAP], norm=norm, blend_mode="soft", dx=mpp, dy=mpp
    )
    out = _rgba((rgb[..., :3] * 255).astype(np.uint8), z.shape)
    out[~finite, :3] = NAN_RGB
    return out


def _sequential(cmap: str) -> Callable[[np.ndarray, Stats, float], np.ndarray]:
    def colour(values: np.ndarray, stats: Stats, mpp: float) -> np.ndarray:
        v = values[0]
        rgba = colormaps[cmap](Normalize(stats["lo"], stats["hi"], clip=True)(v), bytes=True)
        rgba[~np.isfinite(v), :3] = NAN_RGB
        rgba[..., 3] = 255
        return rgba

    return colour


def _change_stats(sample: np.ndarray) -> Stats:
    finite = np.abs(sample[np.isfinite(sample)])
    lim = max(float(np.percentile(finite, 99)), 1e-3) if finite.size else 1.0
    return {"lo": -lim, "hi": lim}


# ------------------------------------------------------------------------------ images
def _image(values: np.ndarray, stats: Stats, mpp: float) -> np.ndarray:
    shape = values.shape[1:]
    bands = values if len(values) != 2 else values[:1]
    rgb = image_colours(bands, stretch=(stats["lo"], stats["hi"]))
    return _rgba(rgb, shape)


def _image_stats(sample: np.ndarray) -> Stats:
    used = sample[:3] if len(sample) >= 3 else sample[:1]
    filled = np.isfinite(used).all(axis=0)
    return _percentiles(used[:, filled]) if filled.any() else {"lo": 0.0, "hi": 255.0}


def _describe_image(v: np.ndarray) -> str:
    if not np.isfinite(v).all():
        return "no value"
    return " ".join(f"{x:.4g}" for x in v[:3])


# ------------------------------------------------------------------------------ codes
def _codes(values: np.ndarray, stats: Stats, mpp: float) -> np.ndarray:
    v = values[0]
    codes = np.where(np.isin(v, list(Code)), v, Code.NODATA).astype(np.uint8)
    return _rgba(CODE_RGB[codes], v.shape)


def _describe_code(v: np.ndarray) -> str:
    x = v[0]
    return Code(int(x)).label if np.isfinite(x) and int(x) in list(Code) else "no value"


def _css(rgb: tuple[int, int, int] | np.ndarray) -> str:
    return "#{:02x}{:02x}{:02x}".format(*(int(c) for c in rgb))


VIEW_RGB = np.array([[int(c[i : i + 2], 16) for i in (1, 3, 5)] for c in CAMERA_COLOURS], np.uint8)
"""Colours of the views in the source layer: the cameras' colours of the snapshots, in turn."""


def _source(values: np.ndarray, stats: Stats, mpp: float) -> np.ndarray:
    v = values[0]
    k = np.where(np.isfinite(v), v, 0).astype(np.int64)
    rgb = VIEW_RGB[(np.maximum(k, 1) - 1) % len(VIEW_RGB)]
    rgb[k <= 0] = NAN_RGB
    return _rgba(rgb, v.shape)


def _source_stats(sample: np.ndarray) -> Stats:
    finite = sample[0][np.isfinite(sample[0])]
    return {"lo": 0.0, "hi": float(finite.max()) if finite.size else 0.0}


def _source_legend(stats: Stats) -> dict:
    n = max(int(stats["hi"]), len(VIEW_RGB))
    items = [[f"view {k}", _css(VIEW_RGB[(k - 1) % len(VIEW_RGB)])] for k in range(1, n + 1)]
    return {"type": "classes", "items": [*items, ["none", _css(NAN_RGB)]]}


FLAG_RGB: dict[int, tuple[int, int, int]] = {
    Flag.OUTSIDE: tuple(int(c) for c in NAN_RGB),
    Flag.VISIBLE: Code.VISIBLE.rgb,
    Flag.BEHIND: (90, 140, 220),
    Flag.NAIVE: (230, 60, 160),
    Flag.DOUBTFUL: (240, 220, 60),
    Flag.INPAINTED: (60, 200, 200),
    Flag.FACING_AWAY: Code.FACING_AWAY.rgb,
    Flag.OCCLUDED: Code.OCCLUDED.rgb,
    Flag.HIDDEN: (20, 110, 40),
    Flag.DOUBTFUL_EMPTY: (130, 130, 20),
    Flag.NO_VALUE: (70, 70, 70),
}
"""Colours of the mosaic's flags (band 2 of its source raster: how a post was filled, or why
it is empty): the visibility codes' colours where the meaning is the same (visible, occluded,
facing away, no value), others for the fills and the remaining reasons."""

_FLAG_LUT = np.zeros((256, 3), np.uint8)
_FLAG_LUT[:] = NAN_RGB
for _flag, _rgb in FLAG_RGB.items():
    _FLAG_LUT[int(_flag)] = _rgb


def _flags(values: np.ndarray, stats: Stats, mpp: float) -> np.ndarray:
    v = values[0]
    k = np.where(np.isfinite(v), v, 0).astype(np.int64).clip(0, 255)
    return _rgba(_FLAG_LUT[k], v.shape)


def _flag_legend(stats: Stats) -> dict:
    return {"type": "classes", "items": [[Flag(f).label, _css(c)] for f, c in FLAG_RGB.items()]}


def _describe_flag(v: np.ndarray) -> str:
    x = v[0]
    return Flag(int(x)).label if np.isfinite(x) and int(x) in FLAG_RGB else "no value"


def _describe_source(v: np.ndarray) -> str:
    """The view a post came from, and (band 2) how it was filled or why it is empty."""
    x = v[0]
    view = f"view {int(x)}" if np.isfinite(x) and x > 0 else "none"
    return f"{view} ({_describe_flag(v[1:2])})" if len(v) > 1 else view


def _code_legend(stats: Stats) -> dict:
    return {"type": "classes", "items": [[c.label, _css(c.rgb)] for c in Code]}


KINDS: dict[str, Kind] = {
    k.name: k
    for k in (
        Kind("relief", _shaded, _percentiles, _ramp(HEIGHT_CMAP, "m", "height"), _metres),
        Kind("height", _shaded, _percentiles, _ramp(HEIGHT_CMAP, "m", "height"), _metres),
        Kind(
            "image",
            _image,
            _image_stats,
            lambda s: {"type": "image", "lo": s["lo"], "hi": s["hi"]},
            _describe_image,
        ),
        Kind("visibility", _codes, lambda s: {}, _code_legend, _describe_code, categorical=True),
        Kind("source", _source, _source_stats, _source_legend, _describe_source, categorical=True),
        Kind(
            "flags",
            _flags,
            lambda s: {},
            _flag_legend,
            _describe_flag,
            categorical=True,
            combine=lambda a: a[0][1:2],
        ),
        Kind(
            "change",
            _sequential(ERROR_CMAP),
            _change_stats,
            _ramp(ERROR_CMAP, "m", "height change, red up, blue down"),
            lambda v: _metres(v, sign=True),
            files=2,
            combine=lambda a: a[0][:1] - a[1][:1],
        ),
        Kind(
            "uncertainty",
            _sequential(UNCERTAINTY_CMAP),
            lambda s: _percentiles(s, 0, 99),
            _ramp(UNCERTAINTY_CMAP, "m", "1-sigma"),
            lambda v: _metres(v, prefix="± "),
        ),
    )
}
"""The kinds of layer by name (see :class:`Kind`)."""
