"""Figures and tables of the objective explorer.

Each ``*_plot`` function returns a :class:`Plot`: a matplotlib Figure (made without pyplot, so
it needs no display) and the plotted data as CSV columns. Heights are in the DEM's convention
(metres), tilts and angles in degrees, costs are eq. (20) (0 = perfect agreement).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from orthomvp.explore.session import Curve, ExploreError, PathPoint, Surface
from orthomvp.io.output_checks import check_directory, same_file
from orthomvp.io.outputs import write_set

FORMATS = ("png", "svg", "pdf")


@dataclass
class Plot:
    """A figure and its data: CSV ``header`` and ``rows``."""

    figure: Figure
    header: list[str]
    rows: list[list[object]]

    def save(
        self,
        path: str | Path,
        *,
        inputs: Sequence[tuple[str, Path | str | None]] = (),
        overwrite: bool = False,
        overwrite_hint: str = "overwrite=True",
    ) -> tuple[Path, Path]:
        """Write the figure (format from the suffix: PNG, SVG or PDF) and the data as CSV beside
        it (same name, ``.csv``), atomically as a set. Returns both paths. Neither file may be
        one of the ``inputs`` ((label, path) pairs, e.g. ("DEM", dem_path); also through links),
        nor may it exist unless ``overwrite`` (``overwrite_hint`` names that permission in the
        message); ExploreError otherwise, before anything is written."""
        path = Path(path)
        fmt = path.suffix.lower().lstrip(".")
        if fmt not in FORMATS:
            raise ExploreError(f"save: {path.name}: use a .png, .svg or .pdf name")
        data = path.with_name(path.stem + ".csv")
        for out in (path, data):
            for label, given in inputs:
                if given is not None and same_file(out, given):
                    alias = f" ({given})" if str(out) != str(given) else ""
                    raise ExploreError(
                        f"save: {out} is the input {label}{alias}; give another file name"
                    )
            if out.is_dir():
                raise ExploreError(f"save: {out} is a directory; give a file name")
            if not overwrite and os.path.lexists(out):
                raise ExploreError(f"save: {out} exists; {overwrite_hint} to replace it")
            check_directory(out, f"save: {out}")
        write_set(
            {
                path: lambda tmp: self.figure.savefig(tmp, format=fmt, dpi=110),
                data: self._write_csv,
            }
        )
        return path, data

    def _write_csv(self, path: Path) -> None:
        with open(path, "w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(self.header)
            writer.writerows(self.rows)


def _title(ax, what: str, where: str) -> None:  # noqa: ANN001
    ax.set_title(f"{what}\n{where}", fontsize=10)


def height_plot(curve: Curve, current: float, where: str, path: list[PathPoint] | None) -> Plot:
    """rplot: cost against height, the current plane's height and the minimum marked, and the
    optimiser's path (level-0 cost at each accepted iterate) when given."""
    fig = Figure(figsize=(7, 4.5), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(curve.heights, curve.cost, "-", color="0.2", lw=1.5, label="objective f")
    ax.axvline(current, color="tab:blue", ls="--", lw=1, label=f"current plane {current:.2f} m")
    ax.plot(
        [curve.h_min],
        [curve.cost_min],
        "o",
        color="tab:red",
        ms=8,
        label=f"minimum {curve.h_min:.2f} m",
    )
    if path:
        hs = [p.theta[0] for p in path]
        ax.plot(hs, [p.cost for p in path], ".-", color="tab:orange", ms=7, lw=1,
                label=f"fit path ({len(path) - 1} steps, own orientation)")  # fmt: skip
        ax.plot(hs[:1], [path[0].cost], "s", color="tab:orange", ms=6)
    ax.set_xlabel("height of the plane at the post (m)")
    ax.set_ylabel("objective f (eq. 20; 0 = patches agree)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _title(ax, "rplot: objective against height, orientation held", where)
    rows = [[f"{h:.4f}", f"{c:.8g}"] for h, c in zip(curve.heights, curve.cost, strict=True)]
    return Plot(fig, ["height_m", "cost"], rows)


def tilt_plot(
    surf: Surface, current: tuple[float, float], where: str, path: list[PathPoint] | None
) -> Plot:
    """llplot: cost over normal tilts as a grey image (darker = lower), the current plane and
    the minimum marked, and the optimiser's path when given."""
    fig = Figure(figsize=(6.4, 5.4), layout="constrained")
    ax = fig.add_subplot()
    de = (surf.east[1] - surf.east[0]) / 2
    dn = (surf.north[1] - surf.north[0]) / 2
    extent = (surf.east[0] - de, surf.east[-1] + de, surf.north[0] - dn, surf.north[-1] + dn)
    im = ax.imshow(surf.cost, origin="lower", extent=extent, cmap="gray", aspect="equal")
    fig.colorbar(im, ax=ax, label="objective f (eq. 20)", shrink=0.85)
    ax.plot(*current, "+", color="tab:blue", ms=14, mew=2, label="current plane")
    ax.plot(surf.east_min, surf.north_min, "x", color="tab:red", ms=11, mew=2.5,
            label=f"minimum ({surf.east_min:.2f}, {surf.north_min:.2f})")  # fmt: skip
    if path:
        e = [np.degrees(np.arctan(p.theta[1])) for p in path]
        n = [np.degrees(np.arctan(p.theta[2])) for p in path]
        ax.plot(e, n, ".-", color="tab:orange", ms=7, lw=1, label="fit path (own height)")
    ax.set_xlabel("normal tilt towards east (deg)")
    ax.set_ylabel("normal tilt towards north (deg)")
    ax.legend(fontsize=8, loc="upper right")
    _title(ax, "llplot: objective over orientation, height held", where)
    rows = []
    for i, n in enumerate(surf.north):
        for j, e in enumerate(surf.east):
            rows.append(
                [
                    f"{e:.4f}",
                    f"{n:.4f}",
                    f"{surf.n_theta[i, j]:.5f}",
                    f"{surf.n_phi[i, j]:.5f}",
                    f"{surf.cost[i, j]:.8g}",
                ]
            )
    header = ["tilt_east_deg", "tilt_north_deg", "n_theta_deg", "n_phi_deg", "cost"]
    return Plot(fig, header, rows)


def patches_plot(
    names: list[str], patches: np.ndarray, albedo: np.ndarray, loo: list[float], where: str
) -> Plot:
    """The normalised patches of the used views and their mean (the albedo), side by side, on
    one grey scale (unit-variance values)."""
    n = len(names) + 1
    fig = Figure(figsize=(2.3 * n, 2.9), layout="constrained")
    axes = fig.subplots(1, n, squeeze=False)[0]
    lim = float(np.nanmax(np.abs(np.concatenate([patches.ravel(), albedo.ravel()])))) or 1.0
    for ax, img, label in zip(
        axes, [*patches, albedo], [*(f"{a}\ncorr {c:.2f}" for a, c in zip(names, loo, strict=True)),
                                   "albedo (mean)"], strict=True
    ):  # fmt: skip
        im = ax.imshow(img, cmap="gray", vmin=-lim, vmax=lim, interpolation="nearest")
        ax.set_title(label, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=list(axes), shrink=0.8, label="normalised value (eq. 19)")
    fig.suptitle(f"patches at the current plane: {where}", fontsize=10)
    side = albedo.shape[0]
    h = side // 2
    header = ["i", "j", *names, "albedo"]
    rows = [
        [j - h, i - h, *(f"{p[i, j]:.6g}" for p in patches), f"{albedo[i, j]:.6g}"]
        for i in range(side)
        for j in range(side)
    ]
    return Plot(fig, header, rows)


def sweep_plot(results: list[tuple[int, float, Curve]], where: str) -> Plot:
    """Height curves for several window sizes (each scaled to its own range, so shapes compare)
    and, beside them, the minimum's height and the count of local minima per window."""
    fig = Figure(figsize=(10, 4.3), layout="constrained")
    ax, ax2 = fig.subplots(1, 2, width_ratios=[1.6, 1])
    cmap = _cmap("viridis")
    for k, (hwin, _, c) in enumerate(results):
        finite = np.isfinite(c.cost)
        lo, hi = np.min(c.cost[finite]), np.max(c.cost[finite])
        y = (c.cost - lo) / max(hi - lo, 1e-30)
        colour = cmap(k / max(len(results) - 1, 1))
        ax.plot(c.heights, y, color=colour, lw=1.2, label=f"hwin {hwin}")
        ax.plot([c.h_min], [(c.cost_min - lo) / max(hi - lo, 1e-30)], "o", color=colour, ms=4)
    ax.set_xlabel("height of the plane at the post (m)")
    ax.set_ylabel("objective f, scaled to [0, 1] per window")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    _title(ax, "sweep: height curves by window half-size", where)
    hw = [h for h, _, _ in results]
    ax2.bar(hw, [c.local_minima for _, _, c in results], color="0.85", width=0.6)
    ax2.set_ylabel("local minima in the range (bars)")
    ax2.set_xlabel("window half-size hwin (posts)")
    ax2.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax3 = ax2.twinx()
    ax3.plot(hw, [c.h_min for _, _, c in results], "o-", color="tab:red")
    ax3.set_ylabel("height of the minimum (m, red)", color="tab:red")
    _title(ax2, "minimum and local minima against window size", "")
    header = ["hwin", "sigma", "h_min_m", "cost_min", "curvature_per_m2", "local_minima"]
    rows = [
        [h, f"{s:g}", f"{c.h_min:.4f}", f"{c.cost_min:.8g}", f"{c.curvature:.6g}", c.local_minima]
        for h, s, c in results
    ]
    return Plot(fig, header, rows)


def _cmap(name: str):  # noqa: ANN202
    from matplotlib import colormaps

    return colormaps[name]
