"""The viewer's flags layer: band 2 of a mosaic's source raster (how each post was filled, or
why it is empty) shown in its own colours, read out by name on hover, and only for a source
raster that has that band."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from orthomvp.ortho.holes import Flag

pytest.importorskip("starlette")


def _raster(path: Path, bands: np.ndarray) -> Path:
    profile = {
        "driver": "GTiff",
        "width": bands.shape[2],
        "height": bands.shape[1],
        "count": bands.shape[0],
        "dtype": "uint8",
        "crs": "EPSG:32633",
        "transform": Affine(2.0, 0.0, 500000.0, 0.0, -2.0, 4000000.0),
    }
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(bands.astype(np.uint8))
    return path


@pytest.fixture()
def files(tmp_path: Path) -> dict:
    flags = np.array(sorted({int(f) for f in Flag}), np.uint8)
    band2 = np.resize(flags, (8, 16))  # every flag, in rows of 16 posts
    band1 = np.where(np.isin(band2, [f for f in Flag if f.empty]), 0, 1 + band2 % 3)
    dem = _raster(tmp_path / "dem.tif", np.full((1, 8, 16), 100))
    two = _raster(tmp_path / "source.tif", np.stack([band1, band2]))
    one = _raster(tmp_path / "old-source.tif", band1[None])
    return {"dem": dem, "two": two, "one": one, "band1": band1, "band2": band2}


def test_flags_layer_reads_band_two_in_its_colours(files: dict) -> None:
    from orthomvp.view import LayerSet
    from orthomvp.view.kinds import FLAG_RGB

    layers = LayerSet(files["dem"])
    layers.add_source(files["two"])
    kinds = [layer.kind.name for layer in layers.layers.values()]
    assert kinds == ["relief", "source", "flags"]
    flags = next(v for v in layers.layers.values() if v.kind.name == "flags")
    values = flags.read(layers.bounds, (16, 8))
    assert np.array_equal(values[0], files["band2"])
    rgba = flags.kind.colour(values, flags.stats, 2.0)
    for f, rgb in FLAG_RGB.items():
        assert (rgba[files["band2"] == f, :3] == rgb).all(), Flag(f).label
    # distinct meanings, distinct colours
    assert len(set(FLAG_RGB.values())) == len(FLAG_RGB)
    layers.close()


def test_hover_names_the_reason(files: dict) -> None:
    from orthomvp.view import LayerSet

    layers = LayerSet(files["dem"])
    layers.add_source(files["two"])
    source, flags = (v for v in layers.layers.values() if v.kind.name in ("source", "flags"))
    for row, col in ((0, 0), (0, 6), (3, 9), (7, 15)):
        x, y = 500000 + 2.0 * col + 1.0, 4000000 - 2.0 * row - 1.0
        want = Flag(int(files["band2"][row, col])).label
        assert flags.kind.describe(flags.value_at(x, y)) == want
        text = source.kind.describe(source.value_at(x, y))
        assert text.endswith(f"({want})")
        assert text.startswith("none" if files["band1"][row, col] == 0 else "view ")
    layers.close()


def test_a_one_band_source_has_no_flags_layer(files: dict) -> None:
    from orthomvp.view import LayerSet

    layers = LayerSet(files["dem"])
    layers.add_source(files["one"])
    assert [v.kind.name for v in layers.layers.values()] == ["relief", "source"]
    source = layers.layers["L1"]
    assert source.kind.describe(source.value_at(500001.0, 3999999.0)) in ("none", "view 1")
    layers.close()


def test_layers_take_paths_as_text_and_refuse_a_kind_they_do_not_know(files: dict) -> None:
    """Found by a new user's audit: a path as text without a title was an AttributeError, an
    unknown kind a bare KeyError; a missing file is listed as a problem (None returned)."""
    from orthomvp.errors import InputError
    from orthomvp.view import LayerSet

    layers = LayerSet(str(files["dem"]))
    source = layers.add("source", str(files["one"]))  # one path, as text, no title
    assert source is not None and source.title == "source: old-source.tif"
    again = layers.add("source", [str(files["one"])])
    assert np.array_equal(again.read(layers.bounds, (16, 8)), source.read(layers.bounds, (16, 8)))
    with pytest.raises(InputError, match="layer kind must be one of .*bogus"):
        layers.add("bogus", [files["one"]])
    with pytest.raises(InputError, match="at least one file"):
        layers.add("source", [])
    assert layers.add("source", [files["one"].with_name("absent.tif")]) is None
    assert [p.path.endswith("absent.tif") for p in layers.problems] == [True]
    layers.close()
