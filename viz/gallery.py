"""Regenerate every picture used in the README into viz/.

Run from the repository root: ``python viz/gallery.py``. Pictures from the real data in
``../shared/data`` are made when it is present.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from orthomvp.demo import run_demo
from orthomvp.epsstudy import eps_study, plot, write_csv
from orthomvp.synth import make_scene

HERE = Path(__file__).resolve().parent


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        demo = Path(tmp) / "demo"
        run_demo(demo, quiet=True)
        for name in ("overview.png", "orthophotos.png"):
            shutil.copy(demo / name, HERE / name)
        # the epsilon study behind the default rule: the default crater scene (40 m posts,
        # image GSD 0.8 posts) and DEMs with 0, 5 and 10 m of noise
        scene = Path(tmp) / "crater"
        make_scene("crater").write(scene)
        rows = eps_study(scene, noise=(0.0, 5.0, 10.0))
        write_csv(rows, HERE / "eps-study.csv")
        plot(
            rows,
            HERE / "eps-study.png",
            "crater scene, oblique view: visibility test vs marched truth (dotted: default)",
        )
    print(f"wrote the README pictures into {HERE}")


if __name__ == "__main__":
    main()
