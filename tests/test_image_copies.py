"""Images in formats that decode only from the top (JPEG, PNG) are read in a run from a copy
made once (:mod:`orthomvp.engine.copies`): the copy reads exactly as the image does, runs give
the same outputs with and without copies on threads and processes, each copy is made once and
removed as soon as no tile still needs it, and an image is read directly when its copy cannot
be made."""

from __future__ import annotations

import os
import shutil
import tempfile
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import rasterio
import rasterio.shutil
from rasterio.errors import NotGeoreferencedWarning

import orthomvp.engine.copies as copies
from orthomvp.engine import (
    FitOutputs,
    Outputs,
    plan_check,
    plan_fit,
    plan_ortho,
    run_check,
    run_plan,
)
from orthomvp.engine.copies import Copies, Copy, copied, decodes_from_top, image_copies, reread
from orthomvp.engine.fit import run_fit
from orthomvp.engine.images import ImageSource
from orthomvp.engine.schedule import all_local
from orthomvp.errors import InputError, OrthoMVPWarning
from orthomvp.geometry.terrain import Terrain
from orthomvp.mvp import FitOptions

pytestmark = pytest.mark.filterwarnings("ignore", category=NotGeoreferencedWarning)


def as_format(source: Path, target: Path, driver: str, **options: object) -> Path:
    """``source`` (a GeoTIFF) written by GDAL's ``driver`` (its own CreateCopy)."""
    rasterio.shutil.copy(source, target, driver=driver, **options)
    return target


def windows(rng: np.random.Generator, rows: int, cols: int, n: int) -> list[tuple]:
    """``n`` random windows of a rows x cols image, from the bottom up half of the time, with
    its edges among them."""
    out = [(0, rows, 0, cols), (rows - 1, rows, cols - 1, cols)]
    for _ in range(n):
        r0, c0 = int(rng.integers(0, rows - 1)), int(rng.integers(0, cols - 1))
        out.append(
            (r0, int(rng.integers(r0 + 1, rows + 1)), c0, int(rng.integers(c0 + 1, cols + 1)))
        )
    return out


def sources(tmp_path: Path) -> dict[str, Path]:
    """A JPEG with GDAL's internal mask, an RGBA PNG, and a 16-bit PNG with a nodata value and a
    scale and offset (in its .aux.xml), made from GeoTIFFs."""
    rng = np.random.default_rng(1)
    rows, cols = 233, 171
    rgb = rng.integers(0, 256, (3, rows, cols), dtype=np.uint8)
    mask = np.full((rows, cols), 255, np.uint8)
    mask[40:90, 30:100] = 0
    profile = {"driver": "GTiff", "height": rows, "width": cols, "dtype": "uint8"}
    with rasterio.open(tmp_path / "masked.tif", "w", count=3, **profile) as dst:
        dst.write(rgb)
        dst.write_mask(mask)
    rgba = np.concatenate([rgb, mask[None]])
    with rasterio.open(tmp_path / "rgba.tif", "w", count=4, **profile) as dst:
        dst.write(rgba)
        dst.colorinterp = [*dst.colorinterp[:3], rasterio.enums.ColorInterp.alpha]
    gray = rng.integers(0, 4000, (1, rows, cols), dtype=np.uint16)
    gray[0, 100:120] = 7
    profile.update(dtype="uint16", nodata=7)
    with rasterio.open(tmp_path / "gray.tif", "w", count=1, **profile) as dst:
        dst.write(gray)
        dst.scales, dst.offsets = (0.25,), (-3.0,)
    strip = rng.integers(0, 256, (2, 2100, 150), dtype=np.uint8)  # (GDAL reads one strip
    strip[:, 1500:1600] = 9  # of 2,001 lines or more a line at a time)
    with rasterio.open(
        tmp_path / "strip.tif", "w", driver="GTiff", height=2100, width=150, count=2,
        dtype="uint8", nodata=9, compress="deflate", blockysize=2100,
    ) as dst:  # fmt: skip
        dst.write(strip)
        dst.scales, dst.offsets = (2.0, 0.5), (1.0, -1.0)
    return {
        "geotiff of one strip": tmp_path / "strip.tif",
        "jpeg with mask": as_format(tmp_path / "masked.tif", tmp_path / "masked.jpg", "JPEG"),
        "png with alpha": as_format(tmp_path / "rgba.tif", tmp_path / "rgba.png", "PNG"),
        "png 16-bit, nodata, scale": as_format(tmp_path / "gray.tif", tmp_path / "gray.png", "PNG"),
    }


def test_a_copy_reads_as_its_image_reads(tmp_path: Path) -> None:
    """Every window of every band, and of one band, of a copy equals the image's own read, NaN
    (mask, alpha, nodata) and scaled values included; the copy is an uncompressed tiled
    GeoTIFF."""
    for name, path in sources(tmp_path).items():
        with rasterio.open(path) as src:
            assert decodes_from_top(src), name
            rows, cols, bands = src.height, src.width, src.count
        direct = ImageSource(path, cols, rows, bands, None)  # type: ignore[arg-type]
        copy = Copy(tmp_path / f"{path.stem}.copy.tif", 0, 0)
        via = ImageSource(path, cols, rows, bands, None, copy=copy)  # type: ignore[arg-type]
        rng = np.random.default_rng(2)
        for window in windows(rng, rows, cols, 30):
            a, b = direct.read(window), via.read(window)
            np.testing.assert_array_equal(b, a, err_msg=name)
            np.testing.assert_array_equal(via.read(window, band=bands), a[-1:], err_msg=name)
        whole = direct.read((0, rows, 0, cols))
        assert np.isnan(whole).any() and np.isfinite(whole).any(), name
        with rasterio.open(copy.path) as src:
            assert src.driver == "GTiff" and src.block_shapes[0] == (256, 256), name
            assert src.compression is None, name


def test_what_decodes_from_the_top(tmp_path: Path) -> None:
    """JPEG, PNG, a GeoTIFF of one compressed 8-bit strip of 2,100 lines and one of a 16 MiB
    block decode from the top; tiled GeoTIFFs, GeoTIFFs of many strips (also of one line
    each), of one uncompressed strip (GDAL reads its lines directly) and of a block under
    16 MiB do not."""
    data = np.random.default_rng(3).integers(0, 256, (1, 2100, 200), dtype=np.uint8)
    base = tmp_path / "base.tif"
    with rasterio.open(
        base, "w", driver="GTiff", height=2100, width=200, count=1, dtype="uint8"
    ) as dst:
        dst.write(data)
    forms = {
        "jpg": ("JPEG", {}, True),
        "png": ("PNG", {}, True),
        "strip.tif": ("GTiff", {"compress": "lzw", "blockysize": 2100}, True),
        "tiled.tif": (
            "GTiff",
            {"compress": "deflate", "tiled": True, "blockxsize": 64, "blockysize": 64},
            False,
        ),
        "strips.tif": ("GTiff", {"compress": "deflate", "blockysize": 16}, False),
        "raw.tif": ("GTiff", {"blockysize": 2100}, False),
        "lines.tif": ("GTiff", {"compress": "deflate", "blockysize": 1}, False),
    }
    for suffix, (driver, options, expected) in forms.items():
        path = as_format(base, tmp_path / f"a.{suffix}", driver, **options)
        with rasterio.open(path) as src:
            assert decodes_from_top(src) == expected, suffix
    # 16-bit single strips are one block for GDAL: copied from BLOCK_BYTES
    for side, expected in ((2900, True), (2800, False)):  # (16.0 and 15.0 MiB)
        path = tmp_path / f"u16-{side}.tif"
        with rasterio.open(
            path, "w", driver="GTiff", height=side, width=side, count=1, dtype="uint16",
            compress="deflate", blockysize=side,
        ) as dst:  # fmt: skip
            dst.write(np.zeros((1, side, side), np.uint16))
        with rasterio.open(path) as src:
            assert src.block_shapes[0] == (side, side)
            assert decodes_from_top(src) == expected, side


def crater_as(crater_dir: Path, folder: Path, driver: str) -> list[tuple[Path, Path]]:
    """The crater scene's oblique and nadir views with their images as 8-bit ``driver`` files
    (the radiance times 300, rounded)."""
    folder.mkdir()
    views = []
    for name in ("oblique", "nadir"):
        with rasterio.open(crater_dir / f"{name}.tif") as src:
            values = np.round(src.read() * 300).clip(0, 255).astype(np.uint8)
        byte = folder / f"{name}.tif"
        with rasterio.open(
            byte, "w", driver="GTiff", height=values.shape[1], width=values.shape[2], count=1,
            dtype="uint8",
        ) as dst:  # fmt: skip
            dst.write(values)
        suffix = {"PNG": ".png", "JPEG": ".jpg"}[driver]
        image = as_format(byte, folder / f"{name}{suffix}", driver)
        views.append((image, crater_dir / f"{name}.tsai"))
    return views


def counting(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """The images copied in this process from now on (in order), as a list that grows."""
    made: list[Path] = []
    real_copy = copies._copy

    def counted(image: Path, part: Path) -> None:
        made.append(image)
        real_copy(image, part)

    monkeypatch.setattr(copies, "_copy", counted)
    return made


@pytest.mark.parametrize("driver", ["PNG", "JPEG"])
def test_runs_with_copies_equal_direct_reads(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, driver: str
) -> None:
    """An orthophoto and a mosaic of PNG or JPEG images in 16-post tiles,
    on 2 threads and on 2 processes, equal the same runs reading the images directly; on
    threads each image is copied once; no copy or folder of copies is left. The lossless
    PNG mosaic also equals that of its pixels as GeoTIFFs."""
    views = crater_as(crater_dir, tmp_path / "images", driver)
    made = counting(monkeypatch)

    def run(name: str, run_views: list, every: int, **kw: object) -> dict[str, np.ndarray]:
        monkeypatch.setattr(copies, "COPY_PIXELS", every)
        plan = plan_ortho(tmp_path / "dem.tif", run_views, tile=16, progress=False, grid="dem")
        outputs = Outputs(ortho=tmp_path / f"{name}.tif", source=tmp_path / f"{name}-s.tif")
        run_plan(plan, outputs, progress=False, **kw)
        out = {}
        for kind, path in outputs.paths().items():
            with rasterio.open(path) as src:
                out[kind] = src.read()
        return out

    shutil.copy(crater_dir / "dem.tif", tmp_path / "dem.tif")
    for k, kw in enumerate([{"threads": 2}, {"processes": 2}]):
        for views_run in (views[:1], views):
            direct = run(f"direct{k}{len(views_run)}", views_run, 1 << 40, **kw)
            made.clear()
            via = run(f"copies{k}{len(views_run)}", views_run, 0, **kw)
            for kind in direct:
                np.testing.assert_array_equal(via[kind], direct[kind], err_msg=f"{kind} {kw}")
            if "threads" in kw:
                assert sorted(made) == sorted(image for image, _ in views_run)
    if driver == "PNG":
        tiffs = [
            (image.with_name(f"{image.stem.split('-')[0]}.tif"), camera) for image, camera in views
        ]
        np.testing.assert_array_equal(run("tiff", tiffs, 0, threads=2)["ortho"], via["ortho"])
    leftovers = [p for p in tmp_path.rglob("*") if "orthomvp-copies" in str(p)]
    assert leftovers == []


def test_check_with_copies_equals_direct_reads(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The truth-free check of two PNG views gives the same rows with and without copies."""
    views = crater_as(crater_dir, tmp_path / "images", "PNG")
    made = counting(monkeypatch)
    rows = []
    for every in (1 << 40, 0):
        monkeypatch.setattr(copies, "COPY_PIXELS", every)
        plan = plan_check(crater_dir / "dem.tif", views, names=["o", "n"], tile=16, progress=False)
        rows.append(run_check(plan, threads=2, progress=False))
        assert sorted(made) == ([] if every else sorted(image for image, _ in views))
    assert [str(r) for r in rows[0].rows] == [str(r) for r in rows[1].rows]
    assert any(r["scored"] for r in rows[0].rows)


def test_a_copy_is_made_ahead_and_removed_after_the_last_tile_that_reads_it(
    tmp_path: Path,
) -> None:
    """Copies removes a view's copy when the last of the jobs reading it finishes, in any
    order of finishing, and never a file of a view with no copy; a tile submitted starts the
    copies of its views in the background, once each; a copy that no tile needs any more by
    the time its turn comes is not made."""
    image = tmp_path / "image.png"
    with rasterio.open(
        image, "w", driver="PNG", height=40, width=30, count=1, dtype="uint8"
    ) as dst:  # fmt: skip
        dst.write(np.full((1, 40, 30), 7, np.uint8))
    files = [tmp_path / f"{k}.tif" for k in range(3)]
    views = [SimpleNamespace(path=image, copy=Copy(files[k], 1, 0)) for k in range(2)]
    views.append(SimpleNamespace(path=image, copy=None))
    files[2].write_bytes(b"x")
    reads = [(0,), (0, 1), (1, 2), (2,), (0,)]
    tiles = [SimpleNamespace(index=i, views=v) for i, v in enumerate(reads)]
    plan = SimpleNamespace(views=views, tiles=tiles)
    copies = Copies(plan, [4, 1, 2, 3])  # (tile 0 is not run here)
    copies.started(4)
    copies.started(1)
    copies.started(2)
    copies.pool.submit(lambda: None).result()  # (one thread: the copies before are made)
    assert files[0].exists() and files[1].exists()
    with rasterio.open(files[0]) as src:
        assert (src.read() == 7).all()
    copies.finished(2)
    assert files[0].exists() and files[1].exists()
    copies.finished(4)
    assert files[0].exists() and files[1].exists()
    copies.finished(1)
    assert not files[0].exists() and not files[1].exists()
    copies.finished(3)
    assert files[2].exists()
    late = Copies(plan, [1])
    late.finished(1)  # (done before its copies' turn)
    late._ahead(0)
    late._ahead(1)
    assert not files[0].exists() and not files[1].exists()
    copies.close()


def test_an_image_is_read_directly_when_its_copy_cannot_be_made(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without room on the disk (the copies made ahead warn), without the copies' folder, or
    when the copy fails (then once: later readers are told), the image itself is read and no
    partial copy stays; a truncated PNG fails a run as it does without copies, naming the
    image."""
    views = crater_as(crater_dir, tmp_path / "images", "PNG")
    image = views[0][0]
    copy = Copy(tmp_path / "c.tif", 10**6, 0)
    real_usage = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda p: real_usage(p)._replace(free=10**6 - 1))
    assert copied(image, copy) == image and not copy.path.exists()
    plan = Views((SimpleNamespace(path=image, copy=copy),), tiles_reading((0,)))
    warned: set[Path] = set()
    with pytest.warns(OrthoMVPWarning, match="no room for its copy .* 977 KiB free"):
        Copies(plan, [0], warned)._ahead(0)  # (the copies made ahead say so)
    assert not copy.path.exists() and warned == {image}
    with warnings.catch_warnings():  # (once: a survey's, then the run's, say it once)
        warnings.simplefilter("error")
        Copies(plan, [0], warned)._ahead(0)
    monkeypatch.setattr(shutil, "disk_usage", real_usage)
    assert copied(image, Copy(tmp_path / "gone" / "c.tif", 1, 0)) == image
    calls = []

    def failing(image: Path, part: Path) -> None:
        calls.append(part)
        part.write_bytes(b"half")
        raise OSError("disk full")

    monkeypatch.setattr(copies, "_copy", failing)
    assert copied(image, copy) == image and copied(image, copy) == image
    assert len(calls) == 1 and not calls[0].exists() and not copy.path.exists()
    monkeypatch.undo()

    broken = tmp_path / "broken.png"
    broken.write_bytes(image.read_bytes()[: image.stat().st_size // 2])
    messages = []
    for every in (1 << 40, 0):
        monkeypatch.setattr(copies, "COPY_PIXELS", every)
        plan = plan_ortho(crater_dir / "dem.tif", [(broken, views[0][1])], tile=16, progress=False)
        with pytest.raises(InputError, match="corrupt or truncated") as info:
            run_plan(plan, Outputs(ortho=tmp_path / f"o{every}.tif"), threads=2, progress=False)
        messages.append(str(info.value))
        assert not (tmp_path / f"o{every}.tif").exists()
    assert messages[0] == messages[1] and str(broken) in messages[0]


@dataclass(frozen=True)
class Views:
    """A plan's views and tiles (each with its ``index`` and the ``views`` it reads)."""

    views: tuple[ImageSource, ...]
    tiles: tuple = ()


def tiles_reading(*reads: tuple[int, ...]) -> tuple:
    """Tiles 0, 1, ... reading the views ``reads[i]``."""
    return tuple(SimpleNamespace(index=i, views=v) for i, v in enumerate(reads))


def test_no_copies_for_remote_workers_or_small_images(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A Dask client with a worker on another machine gets no copies (it cannot read this
    machine's folder), one with local workers does; neither does an image under
    COPY_PIXELS, a GeoTIFF, or an image that only one of the run's tiles reads (nor, in a
    survey, one that only one of its tiles reads); the folder is absolute."""
    remote = SimpleNamespace(
        nthreads=lambda: {"tcp://127.0.0.1:4000": 1, "tcp://192.0.2.7:4000": 1}
    )
    local = SimpleNamespace(nthreads=lambda: {"tcp://127.0.0.1:4000": 1, "tcp://127.0.0.1:4001": 2})
    assert not all_local(remote) and all_local(local) and all_local(None)
    big = ImageSource(tmp_path / "a.jpg", 2048, 2048, 3, None, from_top=True, dtype="uint8")  # type: ignore[arg-type]
    small = replace(big, height=2047)
    tiff = ImageSource(tmp_path / "a.tif", 4096, 4096, 3, None, dtype="uint8")  # type: ignore[arg-type]
    once = replace(big, path=tmp_path / "b.jpg")
    plan = Views((big, small, tiff, once), tiles_reading((0, 1, 2), (0, 1, 2, 3), (0,)))
    with image_copies(plan, tmp_path / "out.tif", local=False, jobs=[0, 1, 2]) as same:
        assert same is plan
    with image_copies(plan, tmp_path / "out.tif", local=True, jobs=[2]) as same:
        assert same is plan  # (view 0: one tile)
    monkeypatch.chdir(tmp_path)
    with image_copies(plan, Path("out.tif"), local=True, jobs=[0, 1, 2]) as got:
        assert [v.copy is not None for v in got.views] == [True, False, False, False]
        assert got.views[0].copy.path.parent.parent == tmp_path.resolve()
        assert got.views[0].copy.path.is_absolute()
        assert got.views[0].copy.nbytes == 2048 * 2048 * 3
        folder = got.views[0].copy.path.parent
        assert folder.is_dir()
        survey = replace(got, tiles=tiles_reading((0,), (1,), (0,)))
        assert reread(survey, [0, 1, 2]) is survey
        assert reread(survey, [0, 1]).views[0].copy is None
    assert not folder.exists()


def test_copies_never_go_to_a_folder_in_memory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Beside an output in a tmpfs (/dev/shm, as `stat -f` tells), and with the temporary
    folder there too, nothing is copied; with the temporary folder on disk, copies go there."""
    import subprocess

    shm = Path("/dev/shm")
    kind = subprocess.run(["stat", "-f", "-c", "%T", str(shm)], capture_output=True, text=True)
    if not shm.is_dir() or kind.stdout.strip() != "tmpfs":
        pytest.skip("no tmpfs at /dev/shm here")
    disk = subprocess.run(["stat", "-f", "-c", "%T", str(tmp_path)], capture_output=True, text=True)
    if disk.stdout.strip() in ("tmpfs", "ramfs"):
        pytest.skip(f"{tmp_path} is in memory here")
    view = ImageSource(tmp_path / "a.jpg", 2048, 2048, 3, None, from_top=True, dtype="uint8")  # type: ignore[arg-type]
    plan = Views((view,), tiles_reading((0,), (0,)))
    monkeypatch.setattr(tempfile, "tempdir", str(shm))
    with image_copies(plan, shm / "out.tif", local=True, jobs=[0, 1]) as got:
        assert got is plan
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with image_copies(plan, shm / "out.tif", local=True, jobs=[0, 1]) as got:
        assert got.views[0].copy.path.parent.parent == tmp_path.resolve()


def test_fit_with_copies_equals_direct_reads(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A tiled MVP fit of two PNG views gives the same heights with and without copies."""
    views = crater_as(crater_dir, tmp_path / "images", "PNG")
    terrain = Terrain.read(crater_dir / "dem.tif")
    terrain.write(tmp_path / "start.tif", terrain.values + 10.0)
    made = counting(monkeypatch)
    heights = []
    for every in (1 << 40, 0):
        monkeypatch.setattr(copies, "COPY_PIXELS", every)
        options = FitOptions(hwin=4, reject_below=None)
        plan = plan_fit(tmp_path / "start.tif", views, options, tile=16, progress=False)
        out = tmp_path / f"h{every}.tif"
        report = run_fit(plan, FitOutputs(out), threads=2, progress=False)
        with rasterio.open(out) as src:
            heights.append(src.read())
        assert report.fitted > 1000
        assert sorted(made) == ([] if every else sorted(image for image, _ in views))
    np.testing.assert_array_equal(heights[1], heights[0])


def test_a_run_removes_the_copies_that_a_killed_run_left(tmp_path: Path) -> None:
    """Folders of copies of this machine's processes that no longer run are removed when a run
    makes its own beside them; those of running processes, of other machines (a host name
    that only starts like this one's included), those whose lock a run holds (a run in another
    process-id namespace), those changed in the last minute and other files stay; a run holds
    its own folder's lock."""
    import fcntl
    import socket
    import subprocess
    import sys

    host = socket.gethostname()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    names = {
        f".orthomvp-copies-{host}-{dead}-ab_c1234": False,
        f".orthomvp-copies-{host}-{os.getpid()}-ab_c1234": True,
        f".orthomvp-copies-{host}-2-{dead}-ab_c1234": True,  # (host "HOST-2")
        f".orthomvp-copies-other-{dead}-ab_c1234": True,
        f".orthomvp-copies-{host}-x{dead}-ab_c1234": True,
        f".orthomvp-copies-{host}-{dead}-lockedxy": True,
        f".orthomvp-copies-{host}-{dead}-recentxy": True,
    }
    old = time.time() - 2 * copies.STALE_SECONDS
    for name in names:
        (tmp_path / name).mkdir()
        (tmp_path / name / "0.tif").write_bytes(b"x")
        if "recent" not in name:
            os.utime(tmp_path / name, (old, old))
    held = open(tmp_path / f".orthomvp-copies-{host}-{dead}-lockedxy" / copies.IN_USE, "a")  # noqa: SIM115
    fcntl.flock(held, fcntl.LOCK_EX)
    os.utime(tmp_path / f".orthomvp-copies-{host}-{dead}-lockedxy", (old, old))
    view = ImageSource(tmp_path / "a.jpg", 2048, 2048, 3, None, from_top=True, dtype="uint8")  # type: ignore[arg-type]
    plan = Views((view,), tiles_reading((0,), (0,)))
    with image_copies(plan, tmp_path / "out.tif", local=True, jobs=[0, 1]) as got:
        mine = got.views[0].copy.path.parent.name
        assert mine.startswith(f".orthomvp-copies-{host}-{os.getpid()}-")
        for name, kept in names.items():
            assert (tmp_path / name).exists() == kept, name
        with open(tmp_path / mine / copies.IN_USE, "a") as other:
            with pytest.raises(BlockingIOError):
                fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
    held.close()


def test_a_copy_that_would_read_otherwise_is_not_used(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A JPEG's mask is kept in the copy even where GDAL is told to write GeoTIFF masks beside
    the file (the default before GDAL 3.9: renaming the copy would leave its mask behind); a
    nodata value on one band of three would not survive the copy (a GeoTIFF has one for all
    bands): that image is read directly. Both read as they do without copies."""
    rng = np.random.default_rng(4)
    rows, cols = 120, 90
    rgb = rng.integers(0, 40, (3, rows, cols), dtype=np.uint8)
    mask = np.full((rows, cols), 255, np.uint8)
    mask[10:50, 20:70] = 0
    profile = {"driver": "GTiff", "height": rows, "width": cols, "dtype": "uint8", "count": 3}
    with rasterio.open(tmp_path / "masked.tif", "w", **profile) as dst:
        dst.write(rgb)
        dst.write_mask(mask)
    masked = as_format(tmp_path / "masked.tif", tmp_path / "masked.jpg", "JPEG")
    with rasterio.open(tmp_path / "plain.tif", "w", **profile) as dst:
        dst.write(rgb)
    one = as_format(tmp_path / "plain.tif", tmp_path / "one.png", "PNG")
    (tmp_path / "one.png.aux.xml").write_text(
        '<PAMDataset><PAMRasterBand band="1"><NoDataValue>7</NoDataValue></PAMRasterBand>'
        "</PAMDataset>"
    )
    monkeypatch.setenv("GDAL_TIFF_INTERNAL_MASK", "NO")
    for path in (masked, one):
        direct = ImageSource(path, cols, rows, 3, None)  # type: ignore[arg-type]
        copy = Copy(tmp_path / f"{path.stem}.copy.tif", 0, 0)
        via = ImageSource(path, cols, rows, 3, None, copy=copy)  # type: ignore[arg-type]
        a = direct.read((0, rows, 0, cols))
        assert np.isnan(a).any() and not np.isnan(a).all(), path.name
        np.testing.assert_array_equal(via.read((0, rows, 0, cols)), a, err_msg=path.name)
        assert copy.path.exists() == (path == masked), path.name


def test_a_visibility_run_copies_no_image(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A run that writes only visibility codes reads no pixel it needs: with more threads than
    tiles (each tile then reads its image windows ahead, in a spare thread) no image is copied,
    and no folder of copies is made."""
    views = crater_as(crater_dir, tmp_path / "images", "JPEG")
    made = counting(monkeypatch)
    monkeypatch.setattr(copies, "COPY_PIXELS", 0)
    plan = plan_ortho(crater_dir / "dem.tif", views[:1], tile=48, progress=False, grid="dem")
    assert 2 <= len(plan.tiles) <= 4  # (8 threads: each tile has a spare one)
    folders: list[str] = []
    real_mkdtemp = tempfile.mkdtemp
    monkeypatch.setattr(
        tempfile, "mkdtemp", lambda **kw: folders.append(kw["prefix"]) or real_mkdtemp(**kw)
    )
    run_plan(plan, Outputs(visibility=tmp_path / "vis.tif"), threads=8, progress=False)
    assert made == [] and not [f for f in folders if "orthomvp-copies" in f]


def test_no_warning_for_a_copy_that_a_tile_made_first(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The copies made ahead warn of no room only when they find none: not when a tile made
    the copy before their turn on a disk with room for it once (not twice)."""
    image = crater_as(crater_dir, tmp_path / "images", "PNG")[0][0]
    (tmp_path / "copies").mkdir()
    with rasterio.open(image) as src:
        nbytes = src.width * src.height * src.count
    real_usage = shutil.disk_usage

    def usage(path: Path) -> object:  # (a disk of 3 copies' bytes, less the files in it)
        used = sum(f.stat().st_size for f in Path(path).iterdir() if f.is_file())
        return real_usage(path)._replace(free=3 * nbytes - used)

    monkeypatch.setattr(shutil, "disk_usage", usage)
    copy = Copy(tmp_path / "copies" / "0.tif", nbytes, 3 * nbytes // 2)
    plan = Views((SimpleNamespace(path=image, copy=copy),), tiles_reading((0,), (0,)))
    assert copied(image, copy) == copy.path  # (a tile's worker, first)
    with warnings.catch_warnings():
        warnings.simplefilter("error", OrthoMVPWarning)
        Copies(plan, [0, 1])._ahead(0)
    assert copy.path.exists()
    copy.path.unlink()
    tight = replace(copy, reserve=3 * nbytes)  # (no room for it even once)
    plan = Views((SimpleNamespace(path=image, copy=tight),), tiles_reading((0,), (0,)))
    with pytest.warns(OrthoMVPWarning, match="no room for its copy"):
        Copies(plan, [0, 1])._ahead(0)
    assert not copy.path.exists()


def test_stale_folders_of_odd_names_are_left_and_never_leak_a_run_s_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A folder whose process id is not ASCII digits, or that has no mkdtemp suffix (another
    host's name, such as HOST for a host HOST-7, can make one look so), stays, and the run goes
    on; a failure to look for stale folders leaves the run's own folder where it was made
    (none left behind)."""
    import socket

    host = socket.gethostname()
    odd = [
        f".orthomvp-copies-{host}-\u00b2-ab_c1234",  # ("²".isdigit(), but int("²") fails)
        f".orthomvp-copies-{host}-99999999",  # (HOST-99999999 of host HOST? no suffix)
    ]
    for name in odd:
        (tmp_path / name).mkdir()
    view = ImageSource(tmp_path / "a.jpg", 2048, 2048, 3, None, from_top=True, dtype="uint8")  # type: ignore[arg-type]
    plan = Views((view,), tiles_reading((0,), (0,)))
    with image_copies(plan, tmp_path / "out.tif", local=True, jobs=[0, 1]) as got:
        assert got.views[0].copy.path.parent.parent == tmp_path.resolve()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(odd)

    def failing(parent: Path) -> None:
        raise OSError(116, "Stale file handle")

    monkeypatch.setattr(copies, "_remove_stale", failing)
    with image_copies(plan, tmp_path / "out.tif", local=True, jobs=[0, 1]) as got:
        assert got.views[0].copy.path.parent.parent == tmp_path.resolve()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(odd)


@pytest.mark.parametrize(
    ("mounts", "path", "expected"),
    [
        ("tmpfs /a\\040b tmpfs rw 0 0", "/a b/x", True),
        ("tmpfs /a\\011b tmpfs rw 0 0", "/a\tb/x", True),  # (a tab)
        ("tmpfs /a\\134b tmpfs rw 0 0", "/a\\b/x", True),  # (a backslash)
        ("tmpfs /tmp tmpfs rw 0 0", "/tmpx/y", False),
        ("/dev/sdb1 /s ext4 rw 0 0\ntmpfs /s tmpfs rw 0 0", "/s/x", True),  # (mounted over)
        ("tmpfs /s tmpfs rw 0 0\n/dev/sdb1 /s ext4 rw 0 0", "/s/x", False),
    ],
)
def test_what_lies_in_memory(
    monkeypatch: pytest.MonkeyPatch, mounts: str, path: str, expected: bool
) -> None:
    """/proc/mounts's octal escapes (space, tab, backslash) are read as such; a mount point
    is not a mere prefix of the path's name; of two file systems mounted on one point, the
    later one (the one seen) counts."""
    import io

    text = f"/dev/sda1 / ext4 rw 0 0\n{mounts}\n"
    monkeypatch.setattr(copies, "open", lambda *a, **k: io.StringIO(text), raising=False)
    assert copies._in_memory(Path(path)) == expected
