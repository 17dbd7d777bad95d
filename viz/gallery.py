"""Regenerate every picture used in the README into viz/.

Run from the repository root: ``python viz/gallery.py``. Pictures from the real data in
``../shared/data`` are made when it is present.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from orthomvp.demo import DEMO_SIZE, overview_figure
from orthomvp.synth import make_scene

HERE = Path(__file__).resolve().parent


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        scene_dir = Path(tmp) / "scene"
        make_scene("crater", size=DEMO_SIZE, spacing=50.0).write(scene_dir)
        overview_figure(scene_dir, HERE / "overview.png")
    print(f"wrote {HERE / 'overview.png'}")


if __name__ == "__main__":
    main()
