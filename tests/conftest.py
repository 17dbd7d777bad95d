"""Shared test fixtures: the real-data directory and small synthetic scenes made once.

The real data lives in the directory named by the ORTHOMVP_DATA environment variable, by
default ``../shared/data`` beside the repository; tests that need it are marked ``realdata``
and skip when it is absent.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from types import ModuleType

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


@functools.cache
def open3d_missing() -> str | None:
    """Why Open3D cannot be imported (on Debian, without the system library libusb-1.0, it
    fails with an OSError), or None when it can."""
    try:
        import open3d  # noqa: F401
    except (ImportError, OSError) as exc:
        return (
            f"Open3D cannot be imported ({exc}); on Debian or Ubuntu: apt-get install libusb-1.0-0"
        )
    return None


def require_open3d() -> ModuleType:
    """The open3d module; skips the test, saying why, when it cannot be imported."""
    if reason := open3d_missing():
        pytest.skip(reason)
    import open3d

    return open3d


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tests run on the Open3D ray-casting backend skip when Open3D cannot be imported."""
    on_open3d = [
        item
        for item in items
        if getattr(item, "callspec", None) and item.callspec.params.get("backend") == "open3d"
    ]
    if on_open3d and (reason := open3d_missing()):
        for item in on_open3d:
            item.add_marker(pytest.mark.skip(reason=reason))


@pytest.fixture(scope="session")
def crater_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small crater scene written once per test session."""
    from orthomvp.synthetic import make_scene

    out = tmp_path_factory.mktemp("crater")
    make_scene("crater", size=64, spacing=80.0).write(out, supersample=2)
    return out


@pytest.fixture(scope="session")
def city_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small city scene written once per test session."""
    from orthomvp.synthetic import make_scene

    out = tmp_path_factory.mktemp("city")
    make_scene("city", size=64).write(out, supersample=1)
    return out
