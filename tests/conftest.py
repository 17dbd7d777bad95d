"""Shared test fixtures: paths to ../shared/data and small synthetic scenes made once."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def shared(*parts: str) -> Path:
    """A path under ../shared/data; skips the test when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not available: {path} is absent (needs ../shared/data)")
    return path


@pytest.fixture(scope="session")
def crater_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small crater scene written once per test session."""
    from orthomvp.synthetic import make_scene

    out = tmp_path_factory.mktemp("crater")
    make_scene("crater", size=64, spacing=80.0).write(out, supersample=2)
    return out
