"""Regenerate every picture used in the README into viz/.

Run from the repository root: ``python viz/gallery.py [PART ...]`` with parts ``demo``,
``eps``, ``explore``, ``linescan`` and ``view`` (default: all). Pictures from the real data are
made when it is present: the directory named by ORTHOMVP_DATA, by default ``../shared/data``
beside the repository.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from orthomvp.camera import read_camera
from orthomvp.demo import run_demo
from orthomvp.explore import Explorer, ExplorerShell, run_commands
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import read_image
from orthomvp.present.figures import empty_legend, lonlat_degrees, orthophoto_axes
from orthomvp.quality.eps_study import eps_study, save
from orthomvp.synthetic import make_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from view_pictures import view_pictures  # noqa: E402

HERE = Path(__file__).resolve().parent
DATA = Path(os.environ.get("ORTHOMVP_DATA") or HERE.parents[1] / "shared" / "data")


def demo_pictures(tmp: Path) -> None:
    """From the demo: the crater scene overview, the naive / occlusion-aware / mosaic
    orthophotos, the visibility and mosaic snapshots, and the height error before and after
    the fit (maps, and the two snapshots side by side)."""
    demo = tmp / "demo"
    run_demo(demo, quiet=True)
    for name in (
        "overview.png",
        "orthophotos.png",
        "snap-visibility.png",
        "snap-mosaic.png",
        "height-error.png",
    ):
        shutil.copy(demo / name, HERE / name)
    pair = [np.asarray(Image.open(demo / f"snap-error-{k}.png")) for k in ("start", "fitted")]
    height = max(p.shape[0] for p in pair)  # cropped snapshots: pad with their bottom rows
    pair = [np.pad(p, ((0, height - p.shape[0]), (0, 0), (0, 0)), mode="edge") for p in pair]
    Image.fromarray(np.hstack(pair)).save(HERE / "snap-error.png")


def eps_pictures(tmp: Path) -> None:
    """The epsilon study behind the default rule: the default crater scene (40 m posts, image
    GSD 0.8 posts) and DEMs with 0, 5 and 10 m of noise."""
    scene = tmp / "crater"
    make_scene("crater").write(scene)
    rows = eps_study(scene, noise=(0.0, 5.0, 10.0))
    save(
        rows,
        HERE / "eps-study.csv",
        HERE / "eps-study.png",
        "crater scene, oblique view: visibility test vs marched truth (dotted: default)",
    )


def explore_pictures(tmp: Path) -> None:
    """rplot, llplot and a window sweep at the centre post of the real Apollo 15 tile, with a
    Gaussian window of sigma 8 posts as in the mvpgui paper's figures 10 and 11; the fit runs
    from the ground DEM's tangent plane and its path is drawn."""
    data = DATA / "apollo15-mvp"
    if not data.exists():
        print(f"skipping the explorer pictures: {data} is absent")
        return
    explorer = Explorer(
        Terrain.read(data / "ground-dem.tif"),
        [read_image(data / f"image{k}.tif") for k in range(4)],
        [read_camera(data / f"camera{k}.pinhole") for k in range(4)],
        [f"image{k}" for k in range(4)],
    )
    commands = [
        "hwin 16",
        "fit",
        "rplot 400",
        f"save {HERE / 'apollo-rplot.png'}",
        "llplot 15",
        f"save {HERE / 'apollo-llplot.png'}",
        "sweep hwin 2 16 2",
        f"save {HERE / 'apollo-sweep.png'}",
    ]
    run_commands(ExplorerShell(explorer), commands)


def linescan_pictures(tmp: Path) -> None:
    """The line-scan crater through the command line, as the README shows it: its visibility
    in 3D (occluded posts green, facing away orange) and, side by side, the line-scan image,
    the naive orthophoto and the occlusion-aware one (its empty posts in their code's
    colour), maps with lon/lat ticks, a north arrow and a scale bar."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from orthomvp.cli import main as cli

    scene = tmp / "linescan"
    views = [scene / "dem.tif", scene / "linescan.tif", scene / "linescan.json"]
    for args in (
        ["synth", "crater", scene, "--sensor", "linescan"],
        ["visibility", *views, "-o", tmp / "vis.tif"],
        ["ortho", *views, "-o", tmp / "ortho.tif"],
        ["ortho", *views, "-o", tmp / "naive.tif", "--no-occlusion"],
        ["render", scene / "dem.tif", "--visibility", tmp / "vis.tif", "--exaggerate", "1.5"]
        + ["--azimuth", "20", "--elevation", "50"]
        + ["--crop", "-o", HERE / "linescan-visibility.png"],
    ):
        if cli([str(a) for a in args]) != 0:
            sys.exit(f"gallery: orthomvp {args[0]} failed")
    terrain = Terrain.read(scene / "dem.tif")
    codes = read_image(tmp / "vis.tif")[0]
    naive, aware = (read_image(tmp / f"{name}.tif")[0] for name in ("naive", "ortho"))
    image = read_image(scene / "linescan.tif")[0]
    fig, axes = plt.subplots(1, 3, figsize=(14, 5.0), layout="constrained")
    high = float(np.nanpercentile(image, 99.5))
    axes[0].imshow(image, cmap="gray", vmin=0, vmax=high)
    axes[0].set_title("line-scan image (rows = lines = time)", fontsize=10)
    axes[0].set_axis_off()
    spacing = float(np.mean(terrain.post_spacing()))
    lonlat = lonlat_degrees(terrain)
    shown = set()
    for ax, ortho, title in zip(
        axes[1:], (naive, aware), ("naive orthophoto", "occlusion-aware orthophoto"), strict=True
    ):
        shown |= orthophoto_axes(
            ax, ortho, title, stretch=(0, high), codes=codes, spacing=spacing, lonlat=lonlat
        )
    empty_legend(fig, shown)
    fig.savefig(HERE / "linescan-orthophotos.png", dpi=90)
    plt.close(fig)


PARTS = {
    "demo": demo_pictures,
    "eps": eps_pictures,
    "explore": explore_pictures,
    "linescan": linescan_pictures,
    "view": lambda tmp: view_pictures(tmp, DATA),
}


def main(parts: list[str]) -> None:
    unknown = set(parts) - set(PARTS)
    if unknown:
        sys.exit(f"gallery: unknown part(s) {sorted(unknown)}; choose from {sorted(PARTS)}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in parts or PARTS:
            PARTS[name](Path(tmp))
    print(f"wrote the README pictures into {HERE}")


if __name__ == "__main__":
    main(sys.argv[1:])
