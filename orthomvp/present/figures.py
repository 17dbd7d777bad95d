"""Matplotlib figures for the demo, the README gallery and reports."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from orthomvp.codes import Code
from orthomvp.io.outputs import atomic_path, write_set
from orthomvp.present.colours import ERROR_CMAP, error_colour_limit

CODE_COLOURS = [tuple(v / 255 for v in code.rgb) for code in Code]
"""Matplotlib RGB (0-1) of the visibility codes, indexed by code."""


def _pyplot():  # noqa: ANN202
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path) -> None:  # noqa: ANN001
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format=Path(path).suffix.lstrip(".") or "png")
    _pyplot().close(fig)


def save_with_table(
    fig,
    figure: str | Path,
    rows: Sequence[dict],
    fields: Sequence[str],
    table: str | Path,  # noqa: ANN001
) -> None:
    """Write ``rows`` (dicts with keys ``fields``; floats to 6 significant digits) as CSV to
    ``table`` and the figure ``fig`` to ``figure`` (the format by its suffix, PNG without one),
    atomically as one set (:func:`orthomvp.io.outputs.write_set`); the figure is closed."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(fields))
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    fmt = Path(figure).suffix.lstrip(".") or "png"
    try:
        write_set(
            {
                Path(table): lambda tmp: tmp.write_text(buf.getvalue()),
                Path(figure): lambda tmp: fig.savefig(tmp, dpi=90, format=fmt),
            }
        )
    finally:
        _pyplot().close(fig)


def scale_bar(ax, metres_per_pixel: float, note: str = "") -> None:  # noqa: ANN001
    """A scale bar in the lower left of an image axes: a round length (1, 2 or 5 times a power
    of ten, metres or km) about a fifth of the image's width, labelled, on a light box."""
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    width = abs(np.diff(ax.get_xlim())[0]) * metres_per_pixel
    target = width / 5
    power = 10 ** np.floor(np.log10(target))
    length = max((m * power for m in (1, 2, 5) if m * power <= target), default=power)
    label = f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m"
    bar = AnchoredSizeBar(
        ax.transData,
        length / metres_per_pixel,
        label + note,
        "lower left",
        pad=0.4,
        sep=3,
        color="black",
        frameon=True,
        size_vertical=max(width / metres_per_pixel / 150, 0.5),
        fontproperties={"size": 8},
    )
    bar.patch.set_alpha(0.75)
    ax.add_artist(bar)


def _visibility_axes(ax, codes: np.ndarray, title: str) -> list:  # noqa: ANN001
    """Draw visibility codes; returns the legend handles of the codes present."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    ax.imshow(
        codes, cmap=ListedColormap(CODE_COLOURS), vmin=-0.5, vmax=3.5, interpolation="nearest"
    )
    ax.set_title(title)
    present = [code for code in Code if (codes == code).any()]
    return [Patch(color=CODE_COLOURS[code], label=code.label) for code in present]


def scene_overview(
    dem: np.ndarray,
    spacing: float,
    image: np.ndarray,
    truth: np.ndarray,
    path: str | Path,
    view: str = "oblique",
    gsd: float | None = None,
) -> None:
    """Shaded DEM, a rendered image and its truth visibility side by side, with scale bars
    (``spacing``: DEM post spacing, ``gsd``: the image's ground sample distance at the scene
    centre, both metres) and a legend of the visibility codes below the figure."""
    from matplotlib.colors import LightSource

    plt = _pyplot()
    shade = LightSource(azdeg=315, altdeg=35).hillshade(dem, dx=spacing, dy=spacing)
    fig, axes = plt.subplots(1, 3, figsize=(13, 5.2), layout="constrained")
    axes[0].imshow(shade, cmap="gray")
    axes[0].set_title("DEM (shaded relief)")
    axes[1].imshow(image, cmap="gray")
    axes[1].set_title(f"rendered '{view}' image (raw frame)")
    handles = _visibility_axes(axes[2], truth, "truth visibility of that view")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    scale_bar(axes[0], spacing)
    if gsd:
        scale_bar(axes[1], gsd, " (at the centre)")
    scale_bar(axes[2], spacing)
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=9)
    _save(fig, path)


def ortho_comparison(
    naive: np.ndarray,
    aware: np.ndarray,
    mosaic: np.ndarray,
    path: str | Path,
    spacing: float | None = None,
) -> None:
    """Naive orthophoto, occlusion-aware orthophoto, and the mosaic that fills the gaps, with
    a scale bar when the post ``spacing`` (metres) is given."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.6), constrained_layout=True)
    finite = np.concatenate([a[np.isfinite(a)] for a in (naive, aware, mosaic)])
    lo, hi = np.percentile(finite, [1, 99])
    titles = [
        "naive orthophoto (ghosts in the hidden areas)",
        "orthomvp: occluded posts left empty",
        "mosaic: filled from the near-nadir view",
    ]
    for ax, img, title in zip(axes, (naive, aware, mosaic), titles, strict=True):
        ax.set_facecolor("#c0392b")
        ax.imshow(np.ma.masked_invalid(img), cmap="gray", vmin=lo, vmax=hi)
        ax.set_title(title, fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
        if spacing:
            scale_bar(ax, spacing)
    fig.text(0.5, 0.01, "red: nodata", ha="center", fontsize=9, color="#c0392b")
    _save(fig, path)


def height_error_maps(
    before: np.ndarray, after: np.ndarray, spacing: float, path: str | Path
) -> None:
    """Height error maps (metres, DEM minus truth) before and after fitting, on one diverging
    colour scale symmetric about 0; NaN (unresolved) posts black."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10.5, 4.6), constrained_layout=True)
    finite = np.concatenate([a[np.isfinite(a)] for a in (before, after)])
    lim = error_colour_limit(finite)
    for ax, err, name in zip(axes, (before, after), ("start DEM", "fitted DEM"), strict=True):
        ok = np.isfinite(err)
        rmse = float(np.sqrt(np.mean(err[ok] ** 2)))
        ax.set_facecolor("black")
        im = ax.imshow(np.ma.masked_invalid(err), cmap=ERROR_CMAP, vmin=-lim, vmax=lim)
        ax.set_title(f"{name}: error against truth, RMSE {rmse:.1f} m", fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_xlabel(f"{spacing:g} m posts")
        scale_bar(ax, spacing)
    fig.colorbar(im, ax=list(axes), shrink=0.85, label="height error (m): red too high")
    _save(fig, path)
