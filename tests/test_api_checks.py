"""The engine's Python API refuses what the command line refuses: outputs that would replace
an input, each other or an existing file, or that are misnamed; arguments of the wrong type or
out of range. Each refusal is one of the orthomvp.errors family, naming the argument, and
nothing is written."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from orthomvp.engine import CheckResult, FitOutputs, Outputs, plan_check, plan_ortho, run_plan
from orthomvp.engine.cluster import dask_client
from orthomvp.errors import InputError, OrthoMVPError


@pytest.fixture(scope="module")
def scene(crater_dir: Path) -> dict:
    return {
        "dem": crater_dir / "dem.tif",
        "view": (crater_dir / "oblique.tif", crater_dir / "oblique.tsai"),
        "other": (crater_dir / "nadir.tif", crater_dir / "nadir.tsai"),
    }


def _copy(src: Path, dst: Path) -> Path:
    shutil.copy(src, dst)
    return dst


def test_a_run_never_replaces_its_dem_or_image(scene: dict, tmp_path: Path) -> None:
    dem = _copy(scene["dem"], tmp_path / "d.tif")
    image = _copy(scene["view"][0], tmp_path / "img.tif")
    before = dem.read_bytes(), image.read_bytes()
    plan = plan_ortho(dem, [(image, scene["view"][1])], progress=False)
    link = tmp_path / "link.tif"
    link.symlink_to(image)
    (tmp_path / "sub").mkdir()
    for outputs, match in (
        (Outputs(ortho=dem), r"d\.tif: ortho would replace the input DEM"),
        (Outputs(visibility=image), r"img\.tif: visibility would replace the input IMAGE"),
        (Outputs(ortho=link), r"link\.tif: ortho would replace the input IMAGE \(.*img\.tif\)"),
        (Outputs(ortho=tmp_path / "sub" / ".." / "d.tif"), "would replace the input DEM"),
        (Outputs(ortho=dem, overwrite=True), "overwrite=True and replace_input=True"),
    ):
        with pytest.raises(InputError, match=match):
            run_plan(plan, outputs, threads=1)
    assert (dem.read_bytes(), image.read_bytes()) == before
    # told twice, it may: the inputs are read before the outputs replace them
    run_plan(plan, Outputs(visibility=image, overwrite=True, replace_input=True), threads=1)
    assert image.read_bytes() != before[1]


def test_an_existing_output_is_kept_unless_overwrite(scene: dict, tmp_path: Path) -> None:
    plan = plan_ortho(scene["dem"], [scene["view"]], progress=False)
    out = tmp_path / "o.tif"
    out.write_bytes(b"keep me")
    with pytest.raises(
        InputError,
        match=r"o\.tif: the output file of ortho exists; give "
        r"overwrite=True to replace it",
    ):
        run_plan(plan, Outputs(ortho=out), threads=1)
    assert out.read_bytes() == b"keep me"
    report = run_plan(plan, Outputs(ortho=out, overwrite=True), threads=1)
    assert report.filled > 0 and out.read_bytes()[:2] in (b"II", b"MM")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"ortho": "x.tif", "visibility": "x.tif"}, "given to both ortho and visibility"),
        ({"ortho": "x.tif", "source": "sub/../x.tif"}, r"given to both ortho and source \(as"),
        ({"ortho": "x.png"}, r"ortho writes a GeoTIFF; name it \.tif or \.tiff, not \.png"),
        ({"visibility": "x"}, r"name it \.tif or \.tiff$"),
        ({"ortho": 5}, "output ortho must be a str or PathLike"),
        ({"ortho": "a.tif", "blocksize": "512"}, "block size must be an integer, got str"),
        ({"ortho": "a.tif", "blocksize": 520}, "multiple of 16"),
        ({"ortho": "a.tif", "nodata": "0"}, "nodata must be a number, got str"),
        ({"ortho": "a.tif", "dtype": "uint8", "nodata": 0.5}, "nodata of a uint8 output must"),
        ({"ortho": "a.tif", "dtype": "uint8", "nodata": float("nan")}, "nodata of a uint8"),
        ({"ortho": "a.tif", "overwrite": "yes"}, "overwrite must be a bool"),
        (
            {"ortho": "no/such/dir/a.tif"},
            r"a\.tif: ortho: the directory no/such/dir does not exist",
        ),
    ],
)
def test_outputs_refuse(
    kwargs: dict, match: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError, match=match):
        Outputs(**kwargs)


def test_fit_outputs_follow_the_same_rules(scene: dict, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="given to both heights and cost"):
        FitOutputs(heights=tmp_path / "h.tif", cost=tmp_path / "h.tif")
    with pytest.raises(InputError, match=r"uncertainty writes a GeoTIFF; name it"):
        FitOutputs(heights=tmp_path / "h.tif", uncertainty=tmp_path / "u.png")


def test_run_options_are_checked(scene: dict, tmp_path: Path) -> None:
    plan = plan_ortho(scene["dem"], [scene["view"]], progress=False)
    for kwargs, match in (
        ({"threads": 2.5}, "threads must be an integer, got float 2.5"),
        ({"threads": "2"}, "threads must be an integer, got str"),
        ({"threads": True}, "threads must be an integer, got bool"),
        ({"processes": True}, "processes must be an integer, got bool"),
        ({"processes": 0}, "processes must be >= 1"),
        ({"client": object()}, "client must be a dask.distributed Client"),
        ({"inflight": 1.5}, "inflight must be an integer"),
        ({"progress": "x"}, "progress must be a bool"),
    ):
        with pytest.raises(InputError, match=match):
            run_plan(plan, Outputs(ortho=tmp_path / "o.tif"), **kwargs)
    with pytest.raises(InputError, match=r"plan must be a Plan \(from plan_ortho\)"):
        run_plan(5, Outputs(ortho=tmp_path / "o.tif"))  # type: ignore[arg-type]
    with pytest.raises(InputError, match=r"outputs must be an Outputs"):
        run_plan(plan, tmp_path / "o.tif")  # type: ignore[arg-type]
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"dem": 123}, "dem must be a str or PathLike"),
        ({"views": "oblique.tif"}, "views must be a list of"),
        ({"views": {"a": "b"}}, "views must be a list of"),
        ({"views": [("a.tif", "b.tsai", "c")]}, r"view 1 must be an \(image, camera\) pair, got 3"),
        ({"views": [("a.tif",)]}, r"view 1 must be an \(image, camera\) pair, got 1"),
        ({"views": [(5, "b.tsai")]}, "the image of view 1 must be a str or PathLike"),
        ({"views": "twice"}, "views 1 and 2 are the same image and camera"),
        ({"eps": float("inf")}, r"eps \(DEM posts\) must be > 0, got inf"),
        ({"eps": "3"}, r"eps \(DEM posts\) must be a number, got str"),
        ({"eps": True}, r"eps \(DEM posts\) must be a number, got bool"),
        ({"res": "abc"}, "resolution must be a number or a length such as '5m'"),
        ({"res": (1e-9, 1e-9)}, "finer than a millimetre"),
        ({"bounds": (1, 2)}, "bounds must be four numbers"),
        ({"bounds": (0, 0, float("nan"), 1)}, "bounds must be finite"),
        ({"bounds": (10, 10, 0, 0)}, "left < right"),
        ({"occlusion": "no"}, "occlusion must be a bool"),
        ({"radius_values": "yes"}, "radius_values must be a bool"),
        ({"height_offset": float("nan")}, r"height_offset \(metres\) must be finite"),
        ({"vertical_datum": "x"}, "vertical_datum must be auto or ignore"),
        ({"output_dir": "/nonexistent/dir"}, "output_dir /nonexistent/dir is not a directory"),
    ],
)
def test_plan_arguments_are_checked(scene: dict, change: dict, match: str) -> None:
    args = {"dem": scene["dem"], "views": [scene["view"]], "progress": False} | change
    if args["views"] == "twice":
        args["views"] = [scene["view"], scene["view"]]
    with pytest.raises(OrthoMVPError, match=match):
        plan_ortho(**args)


def test_check_and_dask_options(scene: dict) -> None:
    views = [scene["view"], scene["other"]]
    with pytest.raises(InputError, match="views must be a list of"):
        plan_check(scene["dem"], dict(views), progress=False)
    with pytest.raises(InputError, match="names must be a list of strings"):
        plan_check(scene["dem"], views, names="ab", progress=False)
    with pytest.raises(InputError, match="eps_values must be a list of numbers"):
        plan_check(scene["dem"], views, eps_values="a", progress=False)
    for kwargs, match in (
        ({"workers": 0}, "Dask workers must be >= 1, got 0"),
        ({"workers": -2}, "Dask workers must be >= 1"),
        ({"workers": 1.5}, "Dask workers must be an integer"),
        ({"address": 5}, "Dask scheduler address must be a str"),
        ({"address": "tcp://127.0.0.1:1", "timeout": -1}, r"Dask timeout \(seconds\) must be > 0"),
    ):
        with pytest.raises(InputError, match=match), dask_client(**kwargs):
            pass
    result = CheckResult(
        [{"view": "all", "eps": 2.0, "class": "visible", "miss_from": 0, "miss_to": np.inf}], []
    )
    assert result.pooled(2.0, "visible")["eps"] == 2.0
    with pytest.raises(InputError, match="no pooled row for eps 99: the check has eps 2"):
        result.pooled(99, "visible")
    with pytest.raises(InputError, match="class must be one of visible, occluded"):
        result.pooled(2.0, "both")
