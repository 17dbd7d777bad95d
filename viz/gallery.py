"""Regenerate every picture used in the README into viz/.

Run from the repository root: ``python viz/gallery.py [PART ...]`` with parts ``demo``, ``eps``
and ``explore`` (default: all). Pictures from the real data are made when it is present: the
directory named by ORTHOMVP_DATA, by default ``../shared/data`` beside the repository.
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
from orthomvp.epsstudy import eps_study, save
from orthomvp.explore import Explorer, ExplorerShell, run_commands
from orthomvp.raster import read_image
from orthomvp.synthetic import make_scene
from orthomvp.terrain import Terrain

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


PARTS = {"demo": demo_pictures, "eps": eps_pictures, "explore": explore_pictures}


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
