"""The README's Python example runs as written, on a synthetic scene."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_example(tmp_path: Path) -> None:
    from orthomvp.synth import make_scene

    make_scene("crater", size=48, spacing=100.0).write(tmp_path / "scene", supersample=1)
    block = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        namespace: dict = {}
        exec(compile(block, "README.md", "exec"), namespace)
    finally:
        os.chdir(cwd)
    np.testing.assert_allclose(namespace["c2"], namespace["c"], atol=1e-7)
    assert (namespace["mos"].source > 0).all()
    assert (tmp_path / "crater.ply").is_file()
