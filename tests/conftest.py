"""Shared test fixtures: the real-data directory and small synthetic scenes made once.

The real data lives in the directory named by the ORTHOMVP_DATA environment variable, by
default ``../shared/data`` beside the repository; tests that need it are marked ``realdata``
and skip when it is absent.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

SHARED_DATA = Path(
    os.environ.get("ORTHOMVP_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data"
).absolute()


def shared(*parts: str) -> Path:
    """A path under the real-data directory; skips the test when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(
            f"real data not available: {path} is absent "
            "(set ORTHOMVP_DATA to the data directory; default ../shared/data)"
        )
    return path


@pytest.fixture(scope="session")
def crater_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small crater scene written once per test session."""
    from orthomvp.synthetic import make_scene

    out = tmp_path_factory.mktemp("crater")
    make_scene("crater", size=64, spacing=80.0).write(out, supersample=2)
    return out
