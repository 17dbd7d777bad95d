"""``orthomvp view --export DIR``: the page as static files, with its tiles pre-rendered.

The export opens from ``file://`` with no server and no network: the page, its scripts and
style sheets, and every tile of every layer from zoom 0 to the deepest zoom whose tiles number
at most :data:`MAX_TILES` per layer, as PNG files under ``tiles/ID/Z/X/Y.png``, and for the
hover readout each layer's values on a grid of at most :data:`HOVER` cells a side (in the page's
configuration). Clicks and the 3D view need the live viewer.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from orthomvp.io.output_checks import check_folder, holds
from orthomvp.io.outputs import atomic_dir
from orthomvp.view.layers import LayerSet
from orthomvp.view.page import index_html, page_config, static_files
from orthomvp.view.tiles import Pyramid, tile_png

MAX_TILES = 400
"""Most tiles of one layer at the deepest exported zoom."""
HOVER = 64
"""Cells on the longer side of the value grid an export holds per layer for its hover readout
(each layer's distinct values as text, and an index into them a cell: 170 kB in the page for
a DEM, a height layer and four visibility layers)."""
STATIC = ("view.js", "view.css", "vendor/README.txt")
"""The page's own files an export copies (and Leaflet's folder)."""
MARKS = ("index.html", "static/view.js")
"""The files by which a folder is known as an earlier export's (which an export refreshes)."""


def export_zooms(layers: LayerSet, pyramid: Pyramid) -> int:
    """The deepest zoom exported: the finest native zoom, or shallower so that the tiles over
    the DEM number at most MAX_TILES."""
    left, bottom, right, top = layers.bounds
    z = 0
    while z < pyramid.max_native:
        side = pyramid.span / 2 ** (z + 1)
        count = -(-(right - left) // side) * -(-(top - bottom) // side)
        if count > MAX_TILES:
            break
        z += 1
    return z


def hover_grid(layers: LayerSet, cells: int = HOVER) -> dict:
    """Each layer's values over the DEM's bounds on a grid of at most ``cells`` a side, worded
    as the live readout words them, read as the layer's tiles are (from the files' overviews,
    nearest posts for codes): ``cols``, ``rows``, ``bounds`` (left, bottom, right, top) and by
    layer id its distinct ``words`` and each cell's index into them (row by row from the top;
    -1 where the layer's files all miss the DEM)."""
    left, bottom, right, top = layers.bounds
    scale = cells / max(right - left, top - bottom)
    cols, rows = max(1, round((right - left) * scale)), max(1, round((top - bottom) * scale))
    values: dict[str, dict] = {}
    for layer in layers.layers.values():
        data = layer.read(layers.bounds, (cols, rows))
        if data is None:
            values[layer.id] = {"words": [], "cells": [-1] * (cols * rows)}
            continue
        flat = data.reshape(len(data), -1)
        said = [layer.kind.describe(flat[:, k]) for k in range(flat.shape[1])]
        words = sorted(set(said))
        index = {w: k for k, w in enumerate(words)}
        values[layer.id] = {"words": words, "cells": [index[w] for w in said]}
    return {"cols": cols, "rows": rows, "bounds": [left, bottom, right, top], "values": values}


def write_export(
    layers: LayerSet,
    outdir: str | Path,
    *,
    overwrite: bool = False,
    title: str = "",
    report: str = "",
) -> int:
    """Write the static page of ``layers`` into the folder ``outdir`` (atomically); returns the
    number of tiles written. A folder an earlier export wrote (one holding :data:`MARKS`) is
    refreshed whole: its ``tiles/`` and ``static/`` are replaced, so no tile of an earlier
    layer stays. Any other folder that holds files is refused (InputError) unless
    ``overwrite``, and then keeps what else it holds. ``title``, ``report``: see
    :func:`export_into`."""
    outdir = Path(outdir)
    check_folder(outdir, "the export folder", overwrite=overwrite, refresh=MARKS)
    with atomic_dir(outdir, replace=("tiles", "static") if holds(outdir, MARKS) else ()) as tmp:
        return export_into(layers, tmp, title=title, report=report)


def export_into(layers: LayerSet, folder: Path, *, title: str = "", report: str = "") -> int:
    """Write ``index.html``, ``static/`` and ``tiles/`` into the existing ``folder``; ``title``
    heads the page, ``report`` (HTML) follows the map (a run's pictures and summary). Returns
    the number of tiles written."""
    pyramid = Pyramid.of(layers)
    deepest = export_zooms(layers, pyramid)
    static = Pyramid(pyramid.left, pyramid.top, pyramid.span, deepest)
    config = page_config(layers, static, False, []) | {"hover": hover_grid(layers)}
    count = 0
    left, bottom, right, top = layers.bounds
    text = index_html(config, live=False, title=title, report=report)
    (folder / "index.html").write_text(text, encoding="utf-8")
    for name, path in static_files().items():
        if name in STATIC or name.startswith("vendor/leaflet-"):
            target = folder / "static" / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, target)
    for layer in layers.layers.values():
        for z in range(deepest + 1):
            side = pyramid.span / 2**z
            for x in range(int((right - left) // side) + 1):
                for y in range(int((top - bottom) // side) + 1):
                    if not pyramid.valid(z, x, y):
                        continue
                    target = folder / "tiles" / layer.id / str(z) / str(x) / f"{y}.png"
                    target.parent.mkdir(parents=True, exist_ok=True)
                    target.write_bytes(tile_png(layers, pyramid, layer, z, x, y))
                    count += 1
    return count
