"""``orthomvp demo``: the pipeline end to end on the built-in synthetic crater scene.

Visibility, naive and occlusion-aware orthophotos and a mosaic of the oblique and near-nadir
views; a refined DEM from a perturbed start (MVP fit, all four views); objective plots at one
post (the explorer); offscreen 3D snapshots; exported meshes; every figure scored against the
scene's analytic truth, and an ``index.html`` that shows them all: ``orthomvp view``'s static
export of the outputs' map, followed by the pictures.
"""

from __future__ import annotations

import io
import json
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from scipy import ndimage

from orthomvp import __version__
from orthomvp.codes import Code
from orthomvp.explore import Explorer, ExplorerShell, run_commands
from orthomvp.io.outputs import atomic_dir, atomic_path
from orthomvp.io.raster import write_geotiff
from orthomvp.mvp import FitOptions, fit_dem
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.visibility import occluder_caster
from orthomvp.ortho.orthophoto import mosaic, orthorectify
from orthomvp.present.export import export_mesh
from orthomvp.present.figures import (
    height_error_maps,
    lonlat_degrees,
    ortho_comparison,
    scene_overview,
)
from orthomvp.present.snapshot import SnapshotOptions, snapshot
from orthomvp.present.webpage import report_html
from orthomvp.synthetic import (
    SceneData,
    away_from_boundaries,
    classification_scores,
    load_scene,
    make_scene,
)
from orthomvp.synthetic.scoring import HIDDEN

DEMO_SIZE = 120
DEMO_SPACING = 50.0
START_OFFSET = 30.0  # metres added to the smoothed truth to make the fit's start DEM
START_NOISE = 15.0  # RMS metres of smooth random error added as well
FIT = FitOptions(hwin=5, levels=1)  # small windows resolve the crater walls best here
EXPLORE_POST = (24, 30)  # (c, r) outside the crater, for the objective plots
RIM_RADIUS_POSTS = 45  # posts within this distance of the centre count as "in the crater"
SNAP_SIZE = (900, 640)
IMAGE_MARGIN = 14.0
"""Pixels of each image beyond the DEM (``orthomvp synth`` leaves 6): the fit's window reaches
hwin = 5 posts, 6.25 pixels at the GSD of 0.8 posts, past a post, and a post is fitted only from
views whose window lies inside the image, so with 6 the outermost posts were unresolved."""
EXAGGERATION = 1.5
"""Vertical exaggeration of the relief snapshots (the height-error ones have none)."""
TIMING = (
    "measured on 2 cores: a first run, which compiles numba's kernels into the user's cache "
    "folder, about 21-27 s (29 s of CPU), later runs 10-12 s (13 s of CPU)"
)
"""What the demo takes, as measured on 2 cores: with a fresh numba cache (``NUMBA_CACHE_DIR``
a new folder; CI's first run in a fresh venv took 21 s) and with the cache it filled."""


def run_demo(outdir: str | Path, quiet: bool = False) -> dict:
    """Run everything into ``outdir`` (written atomically) and print a summary, each line
    starting ``orthomvp:`` (nothing when ``quiet``). Returns the measured figures."""
    outdir = Path(outdir)
    t0 = time.perf_counter()
    with atomic_dir(outdir) as tmp:
        made = make_scene("crater", size=DEMO_SIZE, spacing=DEMO_SPACING, image_margin=IMAGE_MARGIN)
        made.write(tmp / "scene", progress=not quiet)
        scene = load_scene(tmp / "scene")
        figures, arrays = _orthophotos(tmp, scene)
        figures.update(_refine(tmp, scene, arrays))
        _objective(tmp, scene, arrays["start"])
        _snapshots(tmp, scene, arrays)
        _meshes(tmp, scene, arrays)
        figures["seconds"] = time.perf_counter() - t0
        lines = _summary(figures, outdir)
        about = _about(scene)
        with atomic_path(tmp / "summary.json") as f:
            f.write_text(json.dumps({**figures, "about": dict(about)}, indent=2))
        _page(tmp, lines, about)
    if not quiet:
        for line in lines:
            print(f"orthomvp: {line.removeprefix('orthomvp ')}")
    return figures


LAYERS = [
    ("image", ["oblique-ortho.tif"], "oblique orthophoto (occlusion-aware)"),
    ("image", ["oblique-naive.tif"], "oblique orthophoto (naive, with ghosts)"),
    ("image", ["mosaic.tif"], "mosaic of the oblique and nadir views"),
    ("source", ["mosaic-source.tif"], "mosaic source (view 1 oblique, 2 nadir)"),
    ("visibility", ["oblique-visibility.tif"], "visibility of the oblique view"),
    ("height", ["fitted-dem.tif"], "fitted DEM"),
    ("change", ["fitted-dem.tif", "start-dem.tif"], "fitted - start DEM"),
    ("change", ["fitted-dem.tif", "scene/dem.tif"], "fitted - truth (height error)"),
]
"""The layers of the page's map (``orthomvp view``'s kinds), over the true DEM shaded."""


def _page(tmp: Path, lines: list[str], about: list[tuple[str, str]]) -> None:
    """``index.html``: ``orthomvp view --export``'s page of the outputs (the map, its layers
    and legends), followed by the summary, the pictures and the files."""
    from orthomvp.view.export import export_into
    from orthomvp.view.layers import LayerSet

    layers = LayerSet(tmp / "scene" / "dem.tif")
    for kind, files, title in LAYERS:
        if kind == "source":
            layers.add_source(tmp / files[0], title)
        else:
            layers.add(kind, [tmp / f for f in files], title)
    try:
        report = report_html(lines, PAGE, FILES, about)
        export_into(layers, tmp, title="orthomvp demo: the crater scene", report=report)
    finally:
        layers.close()


def _orthophotos(tmp: Path, scene: SceneData) -> tuple[dict, dict]:
    """Visibility, orthophotos and the mosaic of the oblique and nadir views, scored."""
    terrain = scene.terrain
    caster = occluder_caster(terrain)
    oblique, nadir = scene.views["oblique"], scene.views["nadir"]
    aware = orthorectify(terrain, oblique.image, oblique.camera, caster=caster)
    naive = orthorectify(terrain, oblique.image, oblique.camera, occlusion=False, caster=caster)
    mos = mosaic(
        terrain, [(oblique.image, oblique.camera), (nadir.image, nadir.camera)], caster=caster
    )
    t, crs = terrain.transform, terrain.crs
    for name, data in (
        ("oblique-ortho.tif", aware.data),
        ("oblique-naive.tif", naive.data),
        ("mosaic.tif", mos.data),
    ):
        write_geotiff(tmp / name, data, t, crs, nodata=np.nan)
    write_geotiff(tmp / "oblique-visibility.tif", aware.visibility.codes, t, crs, nodata=0)
    write_geotiff(tmp / "mosaic-source.tif", mos.source, t, crs, nodata=0)
    keep = away_from_boundaries(oblique.truth)
    hidden = np.isin(oblique.truth, HIDDEN) & keep
    visible = (oblique.truth == Code.VISIBLE) & keep & np.isfinite(aware.data[0])
    figures = {
        **classification_scores(aware.visibility.codes, oblique.truth, keep),
        "hidden_posts": int(hidden.sum()),
        "ghosts_naive": int(np.isfinite(naive.data[0])[hidden].sum()),
        "ghosts_orthomvp": int(np.isfinite(aware.data[0])[hidden].sum()),
        "radiance_correlation": float(
            np.corrcoef(aware.data[0][visible], scene.radiance[visible])[0, 1]
        ),
        "mosaic_fills_hidden": float(np.isfinite(mos.data[0])[hidden].mean()),
    }
    gsd = float(scene.summary["views"]["oblique"]["gsd_m"])
    radius_km = scene.summary["body_radius_m"] / 1000
    scene_overview(
        terrain.values, DEMO_SPACING, oblique.image[0], oblique.truth, tmp / "overview.png",
        gsd=gsd, lonlat=lonlat_degrees(terrain),
        height_label=f"height above the {radius_km:,.1f} km sphere (m)",
    )  # fmt: skip
    ortho_comparison(
        naive.data[0], aware.data[0], mos.data[0], tmp / "orthophotos.png", DEMO_SPACING,
        codes=aware.visibility.codes, lonlat=lonlat_degrees(terrain),
    )  # fmt: skip
    arrays = {"visibility": aware.visibility.codes, "mosaic": mos.data}
    return figures, arrays


def start_dem(truth: np.ndarray, seed: int = 1) -> np.ndarray:
    """The fit's start: the truth smoothed over 2 posts, raised START_OFFSET metres, plus
    smooth random error of START_NOISE metres RMS (correlation length about 6 posts)."""
    noise = ndimage.gaussian_filter(np.random.default_rng(seed).normal(size=truth.shape), 6)
    return ndimage.gaussian_filter(truth, 2) + START_OFFSET + noise * (START_NOISE / noise.std())


def _refine(tmp: Path, scene: SceneData, arrays: dict) -> dict:
    """Fit the DEM from the perturbed start with all four views; score against the truth."""
    terrain, truth = scene.terrain, scene.terrain.values
    start = terrain.with_values(start_dem(truth))
    views = list(scene.views.values())
    res = fit_dem(start, [v.image for v in views], [v.camera for v in views], FIT)
    start.write(tmp / "start-dem.tif")
    write_geotiff(
        tmp / "fitted-dem.tif", res.heights.astype(np.float32), terrain.transform, terrain.crs,
        nodata=np.nan,
    )  # fmt: skip
    arrays.update(start=start, fitted=res.heights)
    ok = res.resolved
    rows, cols = truth.shape
    r, c = np.mgrid[:rows, :cols]
    outside = np.hypot(c - (cols - 1) / 2, r - (rows - 1) / 2) > RIM_RADIUS_POSTS

    def rmse(err: np.ndarray, mask: np.ndarray) -> float:
        return float(np.sqrt(np.mean(err[mask & ok] ** 2)))

    before, after = start.values - truth, res.heights - truth
    height_error_maps(
        before, after, DEMO_SPACING, tmp / "height-error.png", lonlat=lonlat_degrees(terrain)
    )
    return {
        "fit_resolved": float(ok.mean()),
        "fit_rmse_start": rmse(before, True),
        "fit_rmse": rmse(after, True),
        "fit_rmse_start_outside_crater": rmse(before, outside),
        "fit_rmse_outside_crater": rmse(after, outside),
        "fit_rmse_start_crater": rmse(before, ~outside),
        "fit_rmse_crater": rmse(after, ~outside),
        "fit_median_abs_error": float(np.median(np.abs(after[ok]))),
        "gsd_m": float(scene.summary["views"]["nadir"]["gsd_m"]),
    }


def _objective(tmp: Path, scene: SceneData, start) -> None:  # noqa: ANN001
    """rplot and llplot at one post of the start DEM, after a traced fit from there."""
    views = list(scene.views.values())
    explorer = Explorer(
        start, [v.image for v in views], [v.camera for v in views], list(scene.views)
    )
    commands = [
        f"poi {EXPLORE_POST[0]} {EXPLORE_POST[1]}",
        f"hwin {FIT.hwin}",
        "fit",
        "rplot 150",
        f"save {tmp / 'objective-rplot.png'}",
        "llplot 20",
        f"save {tmp / 'objective-llplot.png'}",
    ]
    run_commands(ExplorerShell(explorer, stdout=io.StringIO()), commands)


def _snapshots(tmp: Path, scene: SceneData, arrays: dict) -> None:
    """3D snapshots: visibility of the oblique view with the cameras and rays, the mosaic
    draped, and the height error before and after the fit."""
    terrain = scene.terrain
    oblique, nadir = scene.views["oblique"].camera, scene.views["nadir"].camera
    truth = terrain.values
    limit = float(np.nanpercentile(np.abs(arrays["start"].values - truth), 99))
    raised = SnapshotOptions(exaggerate=EXAGGERATION, size=SNAP_SIZE, crop=True)
    errors = SnapshotOptions(size=SNAP_SIZE, error_limit=limit, crop=True)
    shots = {
        "snap-visibility.png": (
            dict(visibility=arrays["visibility"], cameras=[oblique, nadir]),
            replace(raised, rays=6),
        ),
        "snap-mosaic.png": (dict(ortho=arrays["mosaic"]), raised),
        "snap-error-start.png": (dict(heights=arrays["start"].values, truth=truth), errors),
        "snap-error-fitted.png": (dict(heights=arrays["fitted"], truth=truth), errors),
    }
    for name, (rasters, options) in shots.items():
        snap = snapshot(terrain, **rasters, options=options)
        try:
            snap.save(tmp / name)
        finally:
            snap.close()


def _meshes(tmp: Path, scene: SceneData, arrays: dict) -> None:
    """The true surface coloured by radiance (PLY), the DEM draped with the mosaic (GLB) and
    the fitted DEM coloured by its error (PLY)."""
    terrain = scene.terrain
    tmesh = terrain_mesh(terrain)
    export_mesh(tmesh, tmp / "crater.ply", scene.radiance[None])
    export_mesh(tmesh, tmp / "crater.glb", arrays["mosaic"])
    fitted = terrain.with_values(arrays["fitted"])
    error = arrays["fitted"] - terrain.values
    export_mesh(terrain_mesh(fitted), tmp / "fitted.ply", error, colour_kind="error")


PAGE = [
    ("overview.png", "The crater scene: the DEM's heights in colour over shaded relief (colour bar "
     "in metres above the 1,737.4 km sphere), the rendered 55-degree oblique image (its raw "
     "frame) and that view's truth visibility (green occluded, orange facing away). Maps have "
     "longitude and latitude ticks, a north arrow and a scale bar."),
    ("orthophotos.png", "Naive orthophoto with ghosts, orthomvp's occlusion-aware orthophoto "
     "(hidden posts left empty, drawn in the colour of why: green occluded, orange facing away) "
     "and the mosaic that fills them from the near-nadir view."),
    ("snap-visibility.png", f"3D, vertical exaggeration {EXAGGERATION:g}x: visibility of the "
     "oblique view (green occluded, orange facing away), its camera (1) and the near-nadir one "
     "(2) with rays to their first hits; the white bar in front of the DEM's near edge gives "
     "the scale."),
    ("snap-mosaic.png", f"3D, vertical exaggeration {EXAGGERATION:g}x: the mosaic draped on the "
     "DEM, with a scale bar."),
    ("height-error.png", "Height error against the truth of the start DEM and of the fitted DEM "
     "(colour bar in metres: red too high, blue too low)."),
    ("snap-error-start.png", "3D, no vertical exaggeration: height error of the start DEM "
     "(colour bar in metres, red too high, blue too low)."),
    ("snap-error-fitted.png", "3D, no vertical exaggeration: height error of the fitted DEM, "
     "on the start DEM's colour scale."),
    ("objective-rplot.png", "The objective against height at one post of the start DEM, with "
     "the optimiser's path (orthomvp explore: rplot)."),
    ("objective-llplot.png", "The objective over orientations at the fitted height, with the "
     "path (llplot)."),
]  # fmt: skip
FILES = [
    ("scene/", "the synthetic scene: DEM (the truth), images, .tsai cameras, truth rasters"),
    ("oblique-visibility.tif", "visibility codes of the oblique view (1 visible, 2 occluded, "
     "3 facing away, 0 outside)"),
    ("oblique-ortho.tif", "occlusion-aware orthophoto of the oblique view"),
    ("oblique-naive.tif", "naive orthophoto of the oblique view (with ghosts)"),
    ("mosaic.tif", "mosaic of the oblique and nadir views"),
    ("mosaic-source.tif", "which view each mosaic post came from (1 oblique, 2 nadir)"),
    ("start-dem.tif", "the perturbed start DEM of the fit"),
    ("fitted-dem.tif", "the refined DEM (NaN where fewer than 2 views see a post)"),
    ("crater.ply", "mesh of the true surface with radiance colours (body-fixed metres)"),
    ("crater.glb", "mesh draped with the mosaic (glTF)"),
    ("fitted.ply", "mesh of the fitted DEM coloured by its height error"),
    ("objective-rplot.csv", "data of the rplot"),
    ("objective-llplot.csv", "data of the llplot"),
    ("summary.json", "every figure in the summary"),
    ("static/", "the page's scripts and style sheets (Leaflet 1.9.4)"),
    ("tiles/", "the map's layers as pre-rendered tiles"),
]  # fmt: skip


def _about(scene: SceneData) -> list[tuple[str, str]]:
    """What made this page: the version, the date and the demo's parameters."""
    views = scene.summary["views"]
    made = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return [
        ("orthomvp", __version__),
        ("made", made),
        ("scene", f"crater (orthomvp synth crater --size {DEMO_SIZE} --spacing {DEMO_SPACING:g}"
         f" --seed {scene.summary['seed']}, its images {IMAGE_MARGIN:g} px beyond the DEM instead "
         f"of 6 so that the fit's window fits at the edge posts): {DEMO_SIZE} x {DEMO_SIZE} posts "
         f"of {DEMO_SPACING:g} m on the Moon"),
        ("views", ", ".join(f"{name} ({v['emission_deg']:g} degrees, GSD {v['gsd_m']:.0f} m)"
                             for name, v in views.items())),
        ("visibility", "epsilon = max(3 posts, GSD in posts) on the occluder surface, the default"),
        ("fit start", f"truth smoothed over 2 posts, +{START_OFFSET:g} m, +{START_NOISE:g} m "
         "RMS of smooth random error (seed 1)"),
        ("fit", f"hwin {FIT.hwin}, sigma {FIT.window_sigma:g} posts, {FIT.levels} pyramid "
         f"level{'s' if FIT.levels > 1 else ''}, reject below {FIT.reject_below}, deconvolve "
         f"{FIT.deconvolve}, all {len(views)} views"),
        ("objective plots", f"post (c, r) = {EXPLORE_POST}"),
        ("snapshots", f"{SNAP_SIZE[0]} x {SNAP_SIZE[1]} px, cropped to the scene"),
    ]  # fmt: skip


def _summary(f: dict, outdir: Path) -> list[str]:
    """The printed summary, also shown on the index page."""
    return [
        f"orthomvp demo: crater scene, {DEMO_SIZE} x {DEMO_SIZE} posts of {DEMO_SPACING:g} m, "
        f"4 views ({f['seconds']:.1f} s), outputs in {outdir}/",
        f"  what the demo takes, {TIMING}",
        f"  visibility of the 55-degree oblique view vs marched truth: F1 visible "
        f"{f['f1_visible']:.4f}, hidden {f['f1_hidden']:.4f}",
        f"  ghosts among {f['hidden_posts']:,} hidden posts: naive orthophoto "
        f"{f['ghosts_naive']:,}, orthomvp {f['ghosts_orthomvp']:,}",
        f"  orthophoto vs true radiance at visible posts: r = {f['radiance_correlation']:.4f}",
        f"  mosaic (oblique + nadir) fills {100 * f['mosaic_fills_hidden']:.1f}% of the hidden "
        "posts",
        f"  MVP fit from a start {f['fit_rmse_start']:.1f} m RMS off (hwin {FIT.hwin}, 4 views, "
        f"{100 * f['fit_resolved']:.1f}% of posts resolved): RMSE {f['fit_rmse']:.1f} m, median "
        f"|error| {f['fit_median_abs_error']:.1f} m",
        f"    outside the crater {f['fit_rmse_start_outside_crater']:.1f} -> "
        f"{f['fit_rmse_outside_crater']:.1f} m ({f['fit_rmse_outside_crater'] / f['gsd_m']:.2f} "
        f"image GSD); inside {f['fit_rmse_start_crater']:.1f} -> {f['fit_rmse_crater']:.1f} m "
        "(planes cannot follow the rim crest and the central peak)",
        "  open index.html for every picture; files: scene/, oblique-*.tif, mosaic*.tif, "
        "start-dem.tif, fitted-dem.tif, crater.ply, crater.glb, fitted.ply, objective-*.png, "
        "snap-*.png, summary.json",
    ]
