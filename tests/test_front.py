"""The package's front (``orthomvp.Terrain``, ``orthomvp.orthorectify``, ...) and the module
paths of release 0.1, which still import with a warning."""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import pytest

import orthomvp
from orthomvp._moved import MOVED, SPLIT


def test_import_orthomvp_stays_light() -> None:
    code = (
        "import sys, orthomvp\n"
        "heavy = ('numpy', 'rasterio', 'pyproj', 'scipy', 'cv2', 'numba', 'click')\n"
        "print([m for m in heavy if m in sys.modules])\n"
        "print(sorted(m for m in sys.modules if m.startswith('orthomvp')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    heavy, ours = out.stdout.splitlines()
    assert heavy == "[]"
    assert ours == "['orthomvp', 'orthomvp._lazy', 'orthomvp._moved']"


@pytest.mark.parametrize("name", [n for n in orthomvp.__all__ if n != "__version__"])
def test_every_front_name_is_the_object_of_its_home(name: str) -> None:
    home = importlib.import_module(orthomvp._HOMES[name])
    assert getattr(orthomvp, name) is getattr(home, name)
    assert name in dir(orthomvp)


def test_an_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'orthorectified'"):
        orthomvp.orthorectified  # noqa: B018


@pytest.mark.parametrize("old", sorted(MOVED))
def test_old_module_paths_warn_and_give_the_new_module(old: str) -> None:
    code = (
        "import importlib, sys, warnings\n"
        "warnings.simplefilter('error')\n"
        f"new = importlib.import_module({MOVED[old]!r})\n"
        "warnings.simplefilter('always')\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        f"    old = importlib.import_module({old!r})\n"
        "assert old is new, (old, new)\n"
        "assert old.__spec__.name == new.__name__ and old.__name__ == new.__name__\n"
        "assert [w.category.__name__ for w in caught] == ['DeprecationWarning'], caught\n"
        f"assert {MOVED[old]!r} in str(caught[0].message)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_the_front_function_mosaic_survives_the_old_module_path_of_the_same_name() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from orthomvp.mosaic import compose  # noqa: F401 (the old module path)
    from orthomvp.ortho.composite import compose as new_compose

    assert compose is new_compose
    assert callable(orthomvp.mosaic) and orthomvp.mosaic.__name__ == "mosaic"


def test_patching_the_old_path_patches_the_new(monkeypatch: pytest.MonkeyPatch) -> None:
    from orthomvp.occlusion import visibility

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        monkeypatch.setattr("orthomvp.visibility.default_eps", lambda gsd: "patched")
    assert visibility.default_eps(None) == "patched"


def test_the_split_raster_module_still_gives_every_name_of_0_1() -> None:
    names = ("atomic_path", "atomic_paths", "HeldSignals", "writing", "check_space", "read_image")
    code = (
        "import warnings\n"
        "warnings.simplefilter('always')\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    import orthomvp.raster as old\n"
        "import importlib\n"
        f"homes = [importlib.import_module(h) for h in {SPLIT['orthomvp.raster']!r}]\n"
        f"for name in {names!r}:\n"
        "    value = getattr(old, name)\n"
        "    home = importlib.import_module(value.__module__)\n"
        "    assert home in homes and value is vars(home)[name], name\n"
        "assert [w.category.__name__ for w in caught] == ['DeprecationWarning'], caught\n"
        "try:\n"
        "    old.no_such_name\n"
        "except AttributeError:\n"
        "    pass\n"
        "else:\n"
        "    raise AssertionError('no AttributeError')\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
