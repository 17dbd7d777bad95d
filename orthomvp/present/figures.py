"""Matplotlib figures for the demo, the README gallery and reports."""

from __future__ import annotations

import csv
import io
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.codes import Code
from orthomvp.io.outputs import atomic_path, write_set
from orthomvp.present.colours import ERROR_CMAP, HEIGHT_CMAP, error_colour_limit

if TYPE_CHECKING:
    from orthomvp.geometry.terrain import Terrain

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
    *,
    overwrite: bool = False,
) -> None:
    """Write ``rows`` (dicts with keys ``fields``; floats to 6 significant digits) as CSV to
    ``table`` and the figure ``fig`` to ``figure`` (the format by its suffix, PNG without one),
    atomically as one set (:func:`orthomvp.io.outputs.write_set`); the figure is closed. A
    file that exists is refused (InputError) unless ``overwrite``, as every output."""
    from orthomvp.io.output_checks import API_FLAGS, Output, check_outputs

    try:
        outputs = [Output("table", Path(table), ()), Output("figure", Path(figure), ())]
        check_outputs(outputs, overwrite=overwrite, flags=API_FLAGS)
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(fields))
        writer.writeheader()
        for r in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
        fmt = Path(figure).suffix.lstrip(".") or "png"
        write_set(
            {
                Path(table): lambda tmp: tmp.write_text(buf.getvalue()),
                Path(figure): lambda tmp: fig.savefig(tmp, dpi=90, format=fmt),
            }
        )
    finally:
        _pyplot().close(fig)


def round_length(target: float) -> float:
    """The largest of 1, 2 or 5 times a power of ten not above ``target`` (> 0): the length of
    a scale bar."""
    power = 10 ** np.floor(np.log10(target))
    return float(max((m * power for m in (1, 2, 5) if m * power <= target), default=power))


def scale_bar(ax, metres_per_pixel: float, note: str = "") -> None:  # noqa: ANN001
    """A scale bar in the lower left of an image axes: a round length (1, 2 or 5 times a power
    of ten, metres or km) about a fifth of the image's width, labelled, on a light box."""
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    width = abs(np.diff(ax.get_xlim())[0]) * metres_per_pixel
    length = round_length(width / 5)
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


LonLat = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""A map's georeference for its furniture: pixel-centre (column, row) arrays to (longitude,
latitude) arrays in degrees (for a DEM, ``np.degrees(terrain.pixel_to_lonlat(c, r))``)."""


def lonlat_degrees(terrain: Terrain) -> LonLat:
    """The :data:`LonLat` georeference of ``terrain``'s grid (its body's lon/lat, degrees)."""

    def lonlat(c: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lon, lat = terrain.pixel_to_lonlat(c, r)
        return np.degrees(lon), np.degrees(lat)

    return lonlat


def _rgb(code: Code) -> tuple[float, float, float]:
    """Matplotlib RGB (0-1) of a visibility code."""
    return CODE_COLOURS[code]


def _degrees(values: np.ndarray, hemispheres: str) -> list[str]:
    """Tick labels of longitudes ("EW") or latitudes ("NS") in degrees, with as few decimals as
    tell the ticks apart."""
    decimals = next((d for d in range(7) if np.allclose(np.round(values, d), values)), 6)
    pos, neg = hemispheres
    return [f"{abs(v):.{decimals}f}\u00b0{pos if v >= 0 else neg}" for v in values]


def _edge_ticks(values: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Round values (1, 2, 2.5 or 5 times a power of ten, 3 to 5 of them) within ``values``
    sampled along an edge at ``positions``, and where on the edge they lie; none when the
    values are not monotonic along it."""
    from matplotlib.ticker import MaxNLocator

    step = np.diff(values)
    if not ((step > 0).all() or (step < 0).all()):
        return np.empty(0), np.empty(0)
    lo, hi = float(values.min()), float(values.max())
    ticks = MaxNLocator(nbins=4, steps=[1, 2, 2.5, 5, 10]).tick_values(lo, hi)
    ticks = ticks[(ticks >= lo) & (ticks <= hi)]
    order = np.argsort(values)
    return ticks, np.interp(ticks, values[order], positions[order])


def map_frame(ax, lonlat: LonLat, shape: tuple[int, int]) -> None:  # noqa: ANN001
    """Lon/lat furniture on an image axes showing a (rows, cols) grid (``imshow``, pixel
    centres at integers; the maps draw one square per post, nearest interpolation): longitude
    ticks along the bottom edge and latitude ticks along the left edge where round values cross
    them, a faint graticule through the same values, and a north arrow (along the meridian
    through the map's centre) in the upper right."""
    from matplotlib import patheffects

    rows, cols = shape
    c = np.linspace(-0.5, cols - 0.5, 257)
    r = np.linspace(-0.5, rows - 0.5, 257)
    lon_bottom, _ = lonlat(c, np.full_like(c, rows - 0.5))
    _, lat_left = lonlat(np.full_like(r, -0.5), r)
    lon_ticks, at_c = _edge_ticks(np.asarray(lon_bottom), c)
    lat_ticks, at_r = _edge_ticks(np.asarray(lat_left), r)
    ax.set_xticks(at_c, _degrees(lon_ticks, "EW"), fontsize=9)
    ax.set_yticks(at_r, _degrees(lat_ticks, "NS"), fontsize=9)
    cc, rr = np.meshgrid(np.arange(cols, dtype=np.float64), np.arange(rows, dtype=np.float64))
    lon, lat = (np.asarray(v) for v in lonlat(cc, rr))
    for values, ticks in ((lon, lon_ticks), (lat, lat_ticks)):
        if len(ticks):
            ax.contour(
                cc,
                rr,
                values,
                levels=np.sort(ticks),
                colors="0.15",
                linewidths=0.5,
                linestyles=":",
                alpha=0.6,
            )
    # north: the pixel direction along which longitude holds and latitude grows
    c0, r0 = (cols - 1) / 2, (rows - 1) / 2
    around = lonlat(np.array([c0 - 0.5, c0 + 0.5, c0, c0]), np.array([r0, r0, r0 - 0.5, r0 + 0.5]))
    lo, la = (np.asarray(v) for v in around)
    jac = np.array([[lo[1] - lo[0], lo[3] - lo[2]], [la[1] - la[0], la[3] - la[2]]])
    north = np.linalg.solve(jac, [0.0, 1.0])
    north /= np.linalg.norm(north)
    size = 0.1 * min(rows, cols)
    mid = np.array([cols - 1.2 * size, 1.5 * size])  # (c, r) of the arrow's middle
    tail, tip = mid - 0.5 * size * north, mid + 0.5 * size * north
    halo = [patheffects.withStroke(linewidth=3, foreground="white")]
    arrow = {"arrowstyle": "-|>,head_width=0.3", "color": "black", "lw": 1.5, "path_effects": halo}
    ax.annotate("", xy=tip, xytext=tail, arrowprops=arrow)
    label = mid + 0.85 * size * north
    ax.text(*label, "N", ha="center", va="center", fontsize=9, weight="bold", path_effects=halo)
    ax.set_xlim(-0.5, cols - 0.5)
    ax.set_ylim(rows - 0.5, -0.5)


def _map(ax, shape: tuple[int, int], lonlat: LonLat | None, spacing: float | None) -> None:  # noqa: ANN001
    """A map's furniture: lon/lat ticks, graticule and north arrow (:func:`map_frame`) when
    ``lonlat`` is given, else no ticks; a scale bar when the post ``spacing`` (metres) is."""
    if lonlat is not None:
        map_frame(ax, lonlat, shape)
    else:
        ax.set_xticks([])
        ax.set_yticks([])
    if spacing:
        scale_bar(ax, spacing)


def _visibility_axes(ax, codes: np.ndarray, title: str) -> list:  # noqa: ANN001
    """Draw visibility codes; returns the legend handles of the codes present."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    ax.imshow(
        codes, cmap=ListedColormap(CODE_COLOURS), vmin=-0.5, vmax=3.5, interpolation="nearest"
    )
    ax.set_title(title)
    present = [code for code in Code if (codes == code).any()]
    return [Patch(color=_rgb(code), label=code.label) for code in present]


def scene_overview(
    dem: np.ndarray,
    spacing: float,
    image: np.ndarray,
    truth: np.ndarray,
    path: str | Path,
    view: str = "oblique",
    gsd: float | None = None,
    *,
    lonlat: LonLat | None = None,
    height_label: str = "height (m)",
) -> None:
    """The DEM (heights in colour on :data:`~orthomvp.present.colours.HEIGHT_CMAP`, shaded,
    with a colour bar labelled ``height_label``, metres), a rendered image and its truth
    visibility side by side, with scale bars (``spacing``: DEM post spacing, ``gsd``: the
    image's ground sample distance at the scene centre, both metres), lon/lat ticks and a
    north arrow on the two maps when ``lonlat`` is given (see :func:`map_frame`), and a
    legend of the visibility codes below the figure."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import LightSource, Normalize

    plt = _pyplot()
    norm = Normalize(*np.nanpercentile(dem, [0, 100]))
    cmap = colormaps[HEIGHT_CMAP]
    shaded = LightSource(azdeg=315, altdeg=35).shade(
        dem, cmap=cmap, norm=norm, blend_mode="soft", dx=spacing, dy=spacing
    )
    fig, axes = plt.subplots(1, 3, figsize=(14, 5.4), layout="constrained")
    axes[0].imshow(shaded, interpolation="nearest")
    axes[0].set_title("DEM (heights, shaded relief)")
    fig.colorbar(ScalarMappable(norm, cmap), ax=axes[0], shrink=0.8, label=height_label)
    axes[1].imshow(image, cmap="gray")
    axes[1].set_title(f"rendered '{view}' image (raw frame, not a map)")
    axes[1].set_xticks([])
    axes[1].set_yticks([])
    if gsd:
        scale_bar(axes[1], gsd, " (at the centre)")
    handles = _visibility_axes(axes[2], truth, "truth visibility of that view")
    for ax, grid in ((axes[0], dem), (axes[2], truth)):
        _map(ax, grid.shape, lonlat, spacing)
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=9)
    _save(fig, path)


def orthophoto_axes(
    ax,  # noqa: ANN001
    image: np.ndarray,
    title: str,
    *,
    stretch: tuple[float, float],
    codes: np.ndarray | None = None,
    lonlat: LonLat | None = None,
    spacing: float | None = None,
) -> set[Code]:
    """Draw a one-band orthophoto (rows, cols) in grey, stretched from ``stretch`` (low, high)
    to black and white, its empty (NaN) posts in the colour of why they are empty: their
    visibility code in ``codes`` (as read: NaN is no data; occluded green, facing away orange),
    else no data; with the map furniture of :func:`_map` (lon/lat ticks and a north arrow with
    ``lonlat``, a scale bar with the post ``spacing`` in metres). Returns the codes drawn on
    empty posts, for a legend (:func:`empty_legend`)."""
    why = np.full(image.shape, Code.NODATA) if codes is None else np.asarray(codes)
    why = np.where(np.isfinite(why), why, Code.NODATA).astype(np.uint8)  # NaN: no data
    empty = ~np.isfinite(image)
    reason = np.where(empty & (why != Code.VISIBLE), why, Code.NODATA)
    overlay = np.zeros((*image.shape, 4))
    overlay[..., :3] = np.asarray(CODE_COLOURS)[reason]
    overlay[..., 3] = empty
    grey = np.ma.masked_invalid(image)
    ax.imshow(grey, cmap="gray", vmin=stretch[0], vmax=stretch[1], interpolation="nearest")
    ax.imshow(overlay, interpolation="nearest")
    ax.set_title(title, fontsize=10)
    _map(ax, image.shape, lonlat, spacing)
    return {Code(v) for v in np.unique(reason[empty])}


def empty_legend(fig, shown: set[Code]) -> None:  # noqa: ANN001
    """A legend below ``fig`` of the colours of empty orthophoto posts (see
    :func:`orthophoto_axes`), when there are any."""
    from matplotlib.patches import Patch

    if shown:
        handles = [Patch(color=_rgb(c), label=f"empty: {c.label}") for c in sorted(shown)]
        fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=9)


def ortho_comparison(
    naive: np.ndarray,
    aware: np.ndarray,
    mosaic: np.ndarray,
    path: str | Path,
    spacing: float | None = None,
    *,
    codes: np.ndarray | None = None,
    lonlat: LonLat | None = None,
) -> None:
    """Naive orthophoto, occlusion-aware orthophoto, and the mosaic that fills the gaps (see
    :func:`orthophoto_axes`: empty posts in the colour of their code in ``codes``, the
    occlusion-aware orthophoto's view), with a scale bar when the post ``spacing`` (metres) is
    given and lon/lat ticks and a north arrow when ``lonlat`` is, and a legend of the empty
    posts' colours below."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 5.2), layout="constrained")
    finite = np.concatenate([a[np.isfinite(a)] for a in (naive, aware, mosaic)])
    lo, hi = np.percentile(finite, [1, 99])
    titles = [
        "naive orthophoto (ghosts in the hidden areas)",
        "orthomvp: hidden posts left empty",
        "mosaic: filled from the near-nadir view",
    ]
    shown: set[Code] = set()
    for ax, img, title in zip(axes, (naive, aware, mosaic), titles, strict=True):
        shown |= orthophoto_axes(
            ax, img, title, stretch=(lo, hi), codes=codes, lonlat=lonlat, spacing=spacing
        )
    empty_legend(fig, shown)
    _save(fig, path)


def height_error_maps(
    before: np.ndarray,
    after: np.ndarray,
    spacing: float,
    path: str | Path,
    *,
    lonlat: LonLat | None = None,
) -> None:
    """Height error maps (metres, DEM minus truth) before and after fitting, on one diverging
    colour scale symmetric about 0 (:data:`~orthomvp.present.colours.ERROR_CMAP`: red too
    high, blue too low) with a colour bar in metres; NaN (unresolved) posts in the no-data
    colour, named in a legend when there are any. Scale bars, and lon/lat ticks and a north
    arrow when ``lonlat`` is given (see :func:`map_frame`)."""
    from matplotlib import colormaps
    from matplotlib.patches import Patch

    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.0), layout="constrained")
    finite = np.concatenate([a[np.isfinite(a)] for a in (before, after)])
    lim = error_colour_limit(finite)
    cmap = colormaps[ERROR_CMAP].with_extremes(bad=_rgb(Code.NODATA))
    for ax, err, name in zip(axes, (before, after), ("start DEM", "fitted DEM"), strict=True):
        ok = np.isfinite(err)
        rmse = float(np.sqrt(np.mean(err[ok] ** 2)))
        im = ax.imshow(
            np.ma.masked_invalid(err), cmap=cmap, vmin=-lim, vmax=lim, interpolation="nearest"
        )
        ax.set_title(f"{name}: error against truth, RMSE {rmse:.1f} m", fontsize=10)
        _map(ax, err.shape, lonlat, spacing)
    fig.colorbar(
        im, ax=list(axes), shrink=0.85, label="height error (m): red too high, blue too low"
    )
    if not all(np.isfinite(a).all() for a in (before, after)):
        patch = Patch(color=_rgb(Code.NODATA), label="unresolved (fewer than 2 views)")
        fig.legend(handles=[patch], loc="outside lower center", fontsize=9)
    _save(fig, path)
