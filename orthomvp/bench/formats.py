"""Image formats that decode only from the top (``orthomvp bench --formats``): one frame's
orthophoto, whole ``orthomvp ortho`` processes, with its image stored as a tiled GeoTIFF (the
baseline), a JPEG, a PNG and a GeoTIFF of one deflate strip, at the default tiles and at small
ones (many windows per image). The PNG and the strip hold the GeoTIFF's pixels, so their
orthophotos must equal the baseline's bit for bit; the JPEG's differ by its compression.

The frame is the ngi-aerial frame of :data:`~orthomvp.bench.peer.PEER_IMAGE` (or, without the
data, the synthetic stand-in of :func:`~orthomvp.bench.peer.synthetic_case`) enlarged 4 times
to 2,560 x 4,608 pixels, a size drone and aerial frames have (the camera's interior file says
so: same sensor, smaller pixels)."""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

import numpy as np
import rasterio
from rasterio.errors import NotGeoreferencedWarning

from orthomvp.bench.gdal import best_runs
from orthomvp.bench.peer import PeerCase, ngi_case, synthetic_case
from orthomvp.io.raster import read_image

ENLARGE = 4
"""Times the frame is enlarged on each axis."""

FORMATS = {
    "GTiff": ("GTiff", ".tif", {"tiled": True, "blockxsize": 256, "blockysize": 256,
                                "compress": "deflate"}),
    "JPEG": ("JPEG", ".jpg", {"quality": 90}),
    "PNG": ("PNG", ".png", {}),
    "strip": ("GTiff", ".tif", {"compress": "deflate"}),
}  # fmt: skip
"""The stored forms of the frame, baseline first: GDAL's driver, the file's suffix and its
creation options ("strip": a GeoTIFF of one deflate strip for the whole image, as some photo
software writes them); each in a folder of its name."""


def formats_case(data: Path | None, workdir: Path) -> tuple[PeerCase, dict[str, Path], Path]:
    """The case (ngi-aerial in ``data`` when it holds ``dem.tif``, else synthetic), the frame
    enlarged :data:`ENLARGE` times in each of :data:`FORMATS`, and its camera (an exterior CSV
    beside an interior YAML of the enlarged size)."""
    import cv2

    if data is not None and (data / "dem.tif").is_file():
        case = ngi_case(data, workdir)
    else:
        case = synthetic_case(workdir)
    with warnings.catch_warnings():  # (a frame has no georeferencing)
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        pixels = read_image(case.image).astype(np.uint8)
    big = np.stack(
        [
            cv2.resize(band, None, fx=ENLARGE, fy=ENLARGE, interpolation=cv2.INTER_CUBIC)
            for band in pixels
        ]
    )
    images = {}
    for name, (driver, suffix, options) in FORMATS.items():
        path = workdir / name / f"{case.image.stem}{suffix}"
        path.parent.mkdir()
        profile = {"driver": driver, "height": big.shape[1], "width": big.shape[2]}
        if name == "strip":
            profile["blockysize"] = big.shape[1]
        with warnings.catch_warnings():  # (a frame has no georeferencing)
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path, "w", count=3, dtype="uint8", **profile, **options) as dst:
                dst.write(big)
        images[name] = path
    interior = case.interior.read_text()
    rows, cols = pixels.shape[1:]
    size = f"im_size: [{cols}, {rows}]"
    if size not in interior:
        raise RuntimeError(f"{case.interior}: no '{size}' to enlarge")
    folder = workdir / "camera"
    folder.mkdir()
    (folder / "int_param.yaml").write_text(
        interior.replace(size, f"im_size: [{cols * ENLARGE}, {rows * ENLARGE}]")
    )
    exterior = folder / "xyz_opk.csv"
    exterior.write_text(case.exterior.read_text())
    return case, images, exterior


def bench_formats(
    data: Path | None, workdir: Path, res: float = 2.0, small: int = 128, repeat: int = 3
) -> list[dict]:
    """``orthomvp ortho`` of the frame of :func:`formats_case` in each form at ``res`` m, at
    the default tiles and with ``--tile small``: whole processes, alternating ``repeat`` times
    after an untimed warm-up, best wall time and peak RSS; ratio = the form's time over the
    GeoTIFF's at the same tiles; whether the orthophoto equals the GeoTIFF's (NaN where it
    does). One row per tile size and form."""
    case, images, camera = formats_case(data, workdir)
    base = [sys.executable, "-m", "orthomvp", "-q", "ortho", str(case.dem)]
    runs = {}
    for tile in (None, small):
        for driver, image in images.items():
            out = workdir / f"{driver}-{tile}.tif"
            args = [*base, str(image), str(camera), "--res", f"{res}m", "-o", str(out)]
            args += ["--overwrite", *(["--tile", str(tile)] if tile else [])]
            runs[tile, driver] = (args, out)
    best, rss = best_runs({key: args for key, (args, _) in runs.items()}, repeat)
    rows = []
    with warnings.catch_warnings():  # (a frame has no georeferencing)
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(images["GTiff"]) as src:
            shape = [src.height, src.width]
    for tile, driver in runs:
        ours, baseline = read_image(runs[tile, driver][1]), read_image(runs[tile, "GTiff"][1])
        rows.append(
            {
                "case": case.name,
                "image": shape,
                "format": driver,
                "tile": tile or "default",
                "res_m": res,
                "repeat": repeat,
                "threads": os.cpu_count() or 1,
                "seconds": best[tile, driver],
                "rss_mb": rss[tile, driver],
                "ratio": best[tile, driver] / best[tile, "GTiff"],
                "equal": bool(np.array_equal(ours, baseline, equal_nan=True)),
            }
        )
    return rows


def format_formats(rows: list[dict]) -> str:
    """A text table of :func:`bench_formats`'s rows."""
    rows_, cols = rows[0]["image"]
    lines = [
        f"image formats: {rows[0]['case']} frame enlarged to {cols} x {rows_} px, "
        f"orthomvp ortho at {rows[0]['res_m']:g} m, whole processes, best of "
        f"{rows[0]['repeat']}, {rows[0]['threads']} threads",
        "  tiles    format   time      ratio   peak RSS MB  equals the GeoTIFF's",
    ]
    for row in rows:
        lines.append(
            f"  {str(row['tile']):8s} {row['format']:6s} {row['seconds']:7.2f} s  "
            f"{row['ratio']:5.2f}x  {row['rss_mb']:8.0f}     {'yes' if row['equal'] else 'no'}"
        )
    lines.append("ratio = the form's wall time / the tiled GeoTIFF's at the same tiles")
    return "\n".join(lines)
