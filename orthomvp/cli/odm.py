"""``--odm DIR``: the DEM, images and cameras of an OpenDroneMap dataset directory.

ODM writes its surface model to ``odm_dem/dsm.tif`` (``--dsm``) and its terrain model to
``odm_dem/dtm.tif`` (``--dtm``), both in the projected CRS of its outputs (a WGS 84 UTM zone,
or the CRS of the ground control points); the images lie in ``images/`` and the cameras in
``opensfm/reconstruction.json``, which ODM rewrites in the DEM's CRS (see
:mod:`orthomvp.camera.formats.opensfm`). The cameras are read in the DEM's CRS, as Orthority's
``oty odm`` does.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import click

from orthomvp.cli.options import PATH, DemInput, usage_error, view_inputs
from orthomvp.errors import InputError

if TYPE_CHECKING:
    from orthomvp.camera import PinholeCamera

DEMS = ("odm_dem/dsm.tif", "odm_dem/dtm.tif")
"""Where ODM writes its DEMs, in order of preference: the surface model (buildings and trees
occlude), then the terrain model."""
RECONSTRUCTION = "opensfm/reconstruction.json"
"""Where ODM keeps the cameras."""
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".png")
"""File name extensions (lower case) of the images read from ``images/``."""


odm_option = click.option(
    "--odm",
    type=PATH,
    metavar="DIR",
    help="an OpenDroneMap dataset: its DEM (odm_dem/dsm.tif, else dtm.tif), images/ and "
    "opensfm/reconstruction.json, instead of DEM IMAGE CAMERA ...",
)
"""``--odm DIR``, for a command with :data:`~orthomvp.cli.options.optional_dem_argument` and
an optional :func:`~orthomvp.cli.options.pairs_argument` (see :func:`command_views`)."""


@dataclass(frozen=True)
class OdmDataset:
    """An ODM dataset: its ``dem`` file, ``reconstruction`` file and ``views`` ((image path,
    camera) pairs, images sorted by name)."""

    dem: Path
    reconstruction: Path
    views: list[tuple[Path, PinholeCamera]]


def read_odm_dataset(directory: Path, *, dem_crs: str | None = None) -> OdmDataset:
    """The DEM, images and cameras of the ODM dataset ``directory`` (see the module docstring);
    the cameras in the DEM's CRS, or ``dem_crs`` when given. InputError, in one line, when the
    directory, its DEM, its reconstruction or any image with a camera is missing. Warns on
    stderr when only the terrain model is there, and when images have no camera (left out)."""
    from orthomvp.camera import read_opensfm_cameras
    from orthomvp.io.raster import open_raster

    if not directory.is_dir():
        raise InputError(f"{directory}: --odm needs an ODM dataset directory; this is not one")
    dem = next((directory / name for name in DEMS if (directory / name).is_file()), None)
    if dem is None:
        raise InputError(
            f"{directory}: the ODM dataset has no DEM ({' or '.join(DEMS)}); run ODM with --dsm"
        )
    if dem.name == "dtm.tif":
        _warn(
            f"{dem}: only the terrain model is there, so buildings and trees hide nothing; "
            "run ODM with --dsm for a surface model"
        )
    reconstruction = directory / RECONSTRUCTION
    if not reconstruction.is_file():
        raise InputError(f"{directory}: the ODM dataset has no cameras ({RECONSTRUCTION})")
    if dem_crs is None:
        with open_raster(dem) as src:
            crs = src.crs
        if crs is None:
            raise InputError(f"{dem}: the DEM has no CRS; give it with --dem-crs")
    cameras = read_opensfm_cameras(reconstruction, crs=dem_crs or crs.to_wkt())
    folder = directory / "images"
    images = sorted(
        p for p in folder.glob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
    )
    views = [(image, cameras[image.stem]) for image in images if image.stem in cameras]
    if not views:
        raise InputError(
            f"{folder}: none of the {len(images)} images has a camera in {reconstruction}"
        )
    left = [image.name for image in images if image.stem not in cameras]
    if left:
        shown = ", ".join(left[:3]) + (", ..." if len(left) > 3 else "")
        _warn(f"{len(left)} images in {folder} have no camera (not reconstructed): {shown}")
    return OdmDataset(dem, reconstruction, views)


def command_views(
    dem: DemInput, pairs: list[tuple[Path, Path]], odm: Path | None
) -> tuple[DemInput, list[tuple[Path, Path | PinholeCamera]], list[tuple[str, Path]]]:
    """The DEM, the (image, camera) views and the input files (labelled for
    :func:`~orthomvp.cli.options.check_outputs`) of a command given DEM IMAGE CAMERA ... or
    ``--odm DIR``: as given, or read from the ODM dataset (:func:`read_odm_dataset`). A usage
    error for neither, or for a DEM with ``--odm``."""
    if odm is None:
        if dem.path is None or not pairs:
            raise usage_error("needs DEM IMAGE CAMERA [IMAGE CAMERA ...], or --odm DIR")
        return dem, list(pairs), view_inputs(dem, pairs)
    if dem.path is not None:
        raise usage_error("--odm DIR takes the DEM, images and cameras from DIR; give no DEM")
    dataset = read_odm_dataset(odm, dem_crs=dem.crs)
    inputs = [("DEM", dataset.dem), ("CAMERA", dataset.reconstruction)]
    inputs += [(f"IMAGE {k}", image) for k, (image, _) in enumerate(dataset.views, start=1)]
    return replace(dem, path=dataset.dem), list(dataset.views), inputs


def _warn(message: str) -> None:
    """One warning line on stderr."""
    click.echo(f"orthomvp: warning: {message}", file=sys.stderr)
