"""``orthomvp eps-study``: sweep the visibility tolerance on a scene with truth.

For each epsilon (in DEM posts) and each view, the visibility test is scored against the marched
truth on posts farther than one post from a truth class boundary: precision, recall and F1 of
'visible' and of 'hidden'. The default rule of :func:`orthomvp.occlusion.visibility.default_eps` is
scored too. Optional Gaussian noise on the DEM heights imitates a real DEM that is an imperfect
model of the true surface (the truth stays that of the true surface).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.codes import classify
from orthomvp.errors import InputError
from orthomvp.occlusion.visibility import Visibility, compute_visibility, occluder_caster
from orthomvp.present.figures import save_with_table
from orthomvp.synthetic import away_from_boundaries, classification_scores, load_scene
from orthomvp.validate import number

if TYPE_CHECKING:
    from matplotlib.figure import Figure

DEFAULT_EPS_VALUES = tuple(np.round(np.geomspace(0.02, 20, 19), 3))
CSV_FIELDS = (
    "noise_m",
    "view",
    "eps",
    "scored",
    "precision_visible",
    "recall_visible",
    "f1_visible",
    "precision_hidden",
    "recall_hidden",
    "f1_hidden",
)


def reclassify(vis: Visibility, eps: np.ndarray | float) -> np.ndarray:
    """Visibility codes for another epsilon, from a :class:`Visibility` computed once."""
    codes = vis.codes.copy()
    cast = ~np.isnan(vis.miss)
    codes[cast] = classify(vis.miss[cast], eps if np.isscalar(eps) else np.asarray(eps)[cast])
    return codes


def eps_study(
    scene_dir: str | Path,
    eps_values: tuple[float, ...] = DEFAULT_EPS_VALUES,
    noise: tuple[float, ...] = (0.0,),
    seed: int = 0,
) -> list[dict]:
    """Score the visibility test for every epsilon (DEM posts, each > 0), view and DEM noise
    level (standard deviations in metres, each >= 0); InputError for other values."""
    eps_values = tuple(
        number(e, "an epsilon (DEM posts)", minimum=0, min_open=True) for e in _values(eps_values)
    )
    noise = tuple(number(n, "a DEM noise level (metres)", minimum=0) for n in _values(noise))
    scene = load_scene(scene_dir)
    rows = []
    for sigma in noise:
        rng = np.random.default_rng(seed)
        terrain = scene.terrain
        if sigma > 0:
            terrain = terrain.with_values(terrain.values + rng.normal(0, sigma, terrain.shape))
        caster = occluder_caster(terrain)
        for name, view in scene.views.items():
            vis = compute_visibility(terrain, view.camera, caster=caster)
            keep = away_from_boundaries(view.truth)
            # vis.eps holds the default rule (no eps was given) at every post that was cast
            for eps, label in [(e, float(e)) for e in eps_values] + [(vis.eps, "default")]:
                scores = classification_scores(reclassify(vis, eps), view.truth, keep)
                rows.append({"noise_m": sigma, "view": name, "eps": label, **scores})
    return rows


def _values(values: object) -> tuple:
    """``values`` as a non-empty tuple; InputError for anything else."""
    if isinstance(values, (str, bytes)) or not hasattr(values, "__iter__"):
        raise InputError(f"expected a sequence of numbers, got {values!r:.40}")
    values = tuple(values)
    if not values:
        raise InputError("expected at least one value, got none")
    return values


def save(
    rows: list[dict],
    table: str | Path,
    figure: str | Path,
    title: str = "",
    *,
    overwrite: bool = False,
) -> None:
    """Write the study as CSV (``table``) and its :func:`plot` (``figure``, PNG or another
    format matplotlib writes, by the suffix), atomically as a set; files that exist are
    refused unless ``overwrite``."""
    save_with_table(plot(rows, title), figure, rows, CSV_FIELDS, table, overwrite=overwrite)


def plot(rows: list[dict], title: str = "") -> Figure:
    """F1 of 'visible' and of 'hidden' against epsilon, one line per view and noise level;
    the default rule's score marked at the median epsilon it used."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True, sharex=True)
    keys = sorted({(r["noise_m"], r["view"]) for r in rows})
    for noise_m, view in keys:
        sweep = [
            r
            for r in rows
            if r["view"] == view and r["noise_m"] == noise_m and r["eps"] != "default"
        ]
        if not any(r["f1_hidden"] < 1 or r["recall_hidden"] < 1 for r in sweep) and len(keys) > 4:
            continue
        label = f"{view}" + (f", DEM noise {noise_m:g} m" if noise_m else "")
        eps = [r["eps"] for r in sweep]
        for ax, metric in zip(axes, ("f1_visible", "f1_hidden"), strict=True):
            (line,) = ax.semilogx(eps, [r[metric] for r in sweep], marker=".", label=label)
            dflt = next(
                r
                for r in rows
                if r["view"] == view and r["noise_m"] == noise_m and r["eps"] == "default"
            )
            ax.axhline(dflt[metric], color=line.get_color(), lw=0.8, ls=":")
    for ax, name in zip(axes, ("visible", "hidden (occluded or facing away)"), strict=True):
        ax.set_xlabel("epsilon (DEM posts)")
        ax.set_ylabel(f"F1 of '{name}'")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title or "visibility test against marched truth (dotted: default rule)")
    return fig
