"""Images read window by window: their size from the header, pixels only where a tile needs
them. Windows are ``(row0, row1, col0, col1)``, half-open, in image pixels; pixels come back
float32 ``(bands, rows, cols)`` with NaN at nodata (ISIS special pixels), as
:func:`orthomvp.io.raster.read_image` gives them for the whole image."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rasterio.enums import Interleaving
from rasterio.errors import RasterioError
from rasterio.io import DatasetReader
from rasterio.windows import Window

from orthomvp.camera import Camera, check_image, read_camera
from orthomvp.engine.copies import Copy, copied, decodes_from_top
from orthomvp.errors import InputError
from orthomvp.io.raster import corrupt_data, held_raster, image_bands, open_raster, read_values

if TYPE_CHECKING:
    from orthomvp.io.isis import CubeLayout  # (pvl, imported only for cubes)


@dataclass(frozen=True)
class ImageSource:
    """One view: the image file, its size and band count, and its camera (carrying the size);
    whether GDAL decodes it from its top (:func:`~orthomvp.engine.copies.decodes_from_top`), the
    widest band's data type (None for a cube), and in a run the
    :class:`~orthomvp.engine.copies.Copy` it is read from (see :mod:`orthomvp.engine.copies`)."""

    path: Path
    width: int
    height: int
    bands: int
    camera: Camera
    layout: CubeLayout | None = None  # an ISIS3 cube's, read while planning
    from_top: bool = False
    dtype: str | None = None
    copy: Copy | None = None
    camera_file: Path | None = None  # the file the camera was read from, if any
    rgb: bool = False  # its first three bands are red, green and blue (GDAL's colours)

    def read(self, window: tuple[int, int, int, int], band: int | None = None) -> np.ndarray:
        """Pixels of ``window`` (clipped to the image by the caller), every band or only
        ``band`` (1-based; still (1, rows, cols))."""
        if self.path.suffix.lower() == ".cub":
            return _read_cube_window(self.path, window, band, self.layout)
        r0, r1, c0, c1 = window
        indexes = list(range(1, self.bands + 1)) if band is None else [band]  # (no alpha band)
        path = self.path if self.copy is None else copied(self.path, self.copy)
        # (a copy is read once per tile: opening it is cheaper than holding a file removed)
        with held_raster(path) if path == self.path else open_raster(path) as src:
            try:
                return read_values(src, indexes, Window(c0, r0, c1 - c0, r1 - r0), np.float32)
            except RasterioError as exc:
                raise corrupt_data(self.path, exc) from exc


def image_source(image: str | Path, camera: str | Path | Camera) -> ImageSource:
    """An image and its camera (a path, read with :func:`read_camera`, the image's name picking
    its row in multi-camera files; or a camera), checked against each other from the image's
    header alone: no pixel is read."""
    path = Path(image)
    from_top, dtype, rgb = False, None, False
    if path.suffix.lower() == ".cub":
        from orthomvp.io.isis import read_layout  # pvl, only for cubes

        layout = read_layout(path)
        bands, rows, cols = layout.bands, layout.lines, layout.samples
    else:
        layout = None
        with open_raster(path) as src:
            bands, rows, cols = len(image_bands(src)), src.height, src.width
            rgb = [c.name for c in src.colorinterp[:3]] == ["red", "green", "blue"]
            from_top = decodes_from_top(src)
            dtype = max(src.dtypes, key=lambda d: np.dtype(d).itemsize)
            check_blocks(src, path)
    camera_file = None
    if not isinstance(camera, Camera):
        camera_file = Path(camera)
        camera = read_camera(camera, path)
    shape_only = np.broadcast_to(np.float32(0), (bands, rows, cols))
    camera = check_image(shape_only, camera, str(path))
    return ImageSource(
        path, cols, rows, bands, camera, layout, from_top, dtype, camera_file=camera_file, rgb=rgb
    )


def check_blocks(src: DatasetReader, path: Path) -> None:
    """InputError when a block of the GeoTIFF ``src`` (of file ``path``) lies past the end
    of the file (a truncated file, or a corrupt offset), from the header alone (GDAL's
    ``BLOCK_OFFSET``/``BLOCK_SIZE`` of each block; about 4 us a block). Without it the run
    would fail only when a tile reads that block: on one backend and not another, or never,
    depending on the windows read."""
    if src.driver != "GTiff" or not src.block_shapes:
        return
    size = path.stat().st_size
    height, width = src.block_shapes[0]
    bands = range(1, src.count + 1) if src.interleaving == Interleaving.band else (1,)
    for band in bands:
        for row in range(-(-src.height // height)):
            for col in range(-(-src.width // width)):
                offset = src.get_tag_item(f"BLOCK_OFFSET_{col}_{row}", "TIFF", bidx=band)
                if not offset:  # a sparse block (no data written: read as nodata)
                    continue
                length = src.get_tag_item(f"BLOCK_SIZE_{col}_{row}", "TIFF", bidx=band) or 0
                if int(offset) + int(length) > size:
                    raise InputError(
                        f"{path}: corrupt or truncated: block {row}, {col} (band {band}) of "
                        f"{width} x {height} pixels lies at bytes {int(offset):,} to "
                        f"{int(offset) + int(length):,}, past the end of the file "
                        f"({size:,} bytes)"
                    )


def _read_cube_window(
    path: Path,
    window: tuple[int, int, int, int],
    band: int | None = None,
    known: CubeLayout | None = None,
) -> np.ndarray:
    """A window of an ISIS3 cube (every band, or only ``band``, 1-based), through a memory
    map of its pixels (see :func:`orthomvp.io.isis.read_cube` for the layout and the special
    pixels); ``known``: its layout as read before, while its label is unchanged."""
    from orthomvp.io.isis import cube_values, read_layout

    layout = read_layout(path, known=known)
    r0, r1, c0, c1 = window
    ts, tl = layout.tile_samples, layout.tile_lines
    across, down = -(-layout.samples // ts), -(-layout.lines // tl)
    try:
        raw = np.memmap(
            path, layout.dtype, "r", layout.start, (layout.nbytes // layout.dtype.itemsize,)
        )
    except ValueError:
        raise InputError(
            f"{path}: truncated cube: {layout.nbytes} bytes of pixels expected"
        ) from None
    tiles = raw.reshape(layout.bands, down, across, tl, ts)
    tr0, tr1, tc0, tc1 = r0 // tl, -(-r1 // tl), c0 // ts, -(-c1 // ts)
    bands = slice(None) if band is None else slice(band - 1, band)
    part = tiles[bands, tr0:tr1, tc0:tc1].transpose(0, 1, 3, 2, 4)
    part = part.reshape(part.shape[0], (tr1 - tr0) * tl, (tc1 - tc0) * ts)
    return cube_values(
        layout, part[:, r0 - tr0 * tl : r1 - tr0 * tl, c0 - tc0 * ts : c1 - tc0 * ts]
    )
