"""Cameras: the frame (pinhole) model, its lens distortions, RPC cameras, and reading and
writing their files.

The model and its conventions (world metres, R camera-to-world, intrinsics in units of the
pitch, pixels (u, v) = (column, row) with integer values at pixel centres) are in
:mod:`orthomvp.camera.model`, the lens distortion models in :mod:`orthomvp.camera.distortion`,
RPC cameras in :mod:`orthomvp.camera.rpc`.

:func:`read_camera` reads any file of the registry :data:`FORMATS`: ASP/VW ``.tsai`` text and
binary ``.pinhole`` (:mod:`.formats.tsai`), OpenSfM's ``reconstruction.json`` and ODM's
``shots.geojson`` (:mod:`.formats.opensfm`), Orthority's parameter files
(:mod:`.formats.orthority`), USGS CSM ISDs and model states (:mod:`.formats.csm`, the line-scan,
frame and push-frame models of :mod:`orthomvp.camera.csm`), spiceinit'd ISIS3 cubes
(:mod:`.formats.isis`, the cube's own camera by :mod:`orthomvp.camera.isis`), RPCs (GeoTIFF
metadata, ``_RPC.TXT``, ``.RPB``, Orthority's RPC YAML: :mod:`.formats.rpc`) and our JSON
(:mod:`.formats.json`). Each format module lists the formats it reads (name, file name
extensions, reader, content test); a file goes to the first format that names its extension and
recognises its content, else to the last one naming its extension (whose reader reports what is
wrong); a file whose extension no format names goes to the first format that recognises its
content. A new reader is a module
in ``formats`` with its ``FORMATS``, added to the tuple below (ahead of ours, with a content
test, where it shares the ``.json`` extension; the RPC formats come first, their YAML sharing
``.yaml`` with Orthority's interior files). Writers replace the destination atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from orthomvp.camera.distortion import (
    BrownConradyDistortion,
    Distortion,
    FisheyeDistortion,
    FovDistortion,
    NullDistortion,
    OpenCVDistortion,
    PhotometrixDistortion,
    TsaiDistortion,
    distortion_class,
)
from orthomvp.camera.formats import csm as csm_format
from orthomvp.camera.formats import isis as isis_format
from orthomvp.camera.formats import json as json_format
from orthomvp.camera.formats import opensfm, orthority, tsai
from orthomvp.camera.formats import rpc as rpc_format
from orthomvp.camera.formats._common import CameraFile, CameraFormat
from orthomvp.camera.formats.json import camera_to_dict, write_json
from orthomvp.camera.formats.opensfm import read_odm_shots, read_opensfm_cameras
from orthomvp.camera.formats.orthority import orthority_rotation, read_orthority_cameras
from orthomvp.camera.formats.tsai import tsai_text, write_tsai
from orthomvp.camera.model import (
    ORTHONORMAL_TOLERANCE,
    Camera,
    PinholeCamera,
    as_image,
    camera_centres,
    check_image,
    in_world,
    require_pinhole,
    sensor_positions,
)
from orthomvp.camera.rpc import Rpc, RpcCamera, world_crs
from orthomvp.errors import FormatError
from orthomvp.io.raster import read_image
from orthomvp.validate import of_type

__all__ = [
    "FORMATS",
    "ORTHONORMAL_TOLERANCE",
    "BrownConradyDistortion",
    "Camera",
    "Distortion",
    "FisheyeDistortion",
    "FovDistortion",
    "NullDistortion",
    "OpenCVDistortion",
    "PhotometrixDistortion",
    "PinholeCamera",
    "Rpc",
    "RpcCamera",
    "TsaiDistortion",
    "as_image",
    "camera_to_dict",
    "check_image",
    "distortion_class",
    "in_world",
    "load_view",
    "orthority_rotation",
    "read_camera",
    "read_odm_shots",
    "read_opensfm_cameras",
    "read_orthority_cameras",
    "require_pinhole",
    "camera_centres",
    "sensor_positions",
    "tsai_text",
    "world_crs",
    "write_json",
    "write_tsai",
]

FORMATS: tuple[CameraFormat, ...] = (
    *rpc_format.FORMATS,
    *opensfm.FORMATS,
    *orthority.FORMATS,
    *csm_format.FORMATS,
    *isis_format.FORMATS,
    *json_format.FORMATS,
    *tsai.FORMATS,
)
"""Every camera file format :func:`read_camera` knows, in the order they are tried."""


def read_camera(
    path: str | Path, image: str | Path | None = None, *, interior: str | Path | None = None
) -> Camera:
    """Read a camera: ``.tsai`` text, binary ``.pinhole``, our ``.json``, Orthority or
    OpenSfM/ODM files, a USGS CSM ISD or model state (a line-scan, frame or push-frame model of
    :mod:`orthomvp.camera.csm`), a spiceinit'd ISIS3 cube (its own camera, a CSM model; see
    :mod:`orthomvp.camera.isis`), or an RPC camera (:class:`RpcCamera`).

    Single-camera files (``.tsai``, ``.pinhole``, ``.json``; other extensions are recognised by
    their content) ignore ``image`` and ``interior``.

    Orthority's exterior parameter files (``.csv``, ``.geojson``, or a ``.json`` holding a
    GeoJSON FeatureCollection) hold many images: ``image`` (a path or a name) picks the row
    whose ``filename`` has the same stem (file name without directory and extension); without
    ``image`` the file must hold one camera. The interior parameters come from ``interior``, or
    else from the one ``.yaml``/``.yml`` file in the exterior file's directory. CSV angles are
    in degrees (see :func:`read_orthority_cameras`). An interior ``.yaml`` alone holds no camera
    pose and raises InputError.

    RPC cameras come from a raster's RPC metadata (the camera file can be the image itself;
    ``.tif``, ``.tiff``, or any raster whose content is TIFF), ``_RPC.TXT`` (``.txt``), ``.RPB``,
    or Orthority's RPC parameter YAML (``image`` picks the entry by stem, as for the exterior
    files); see :mod:`orthomvp.camera.formats.rpc`. They live in WGS84 geocentric metres;
    :meth:`RpcCamera.bind` moves them to a terrain's world frame.

    OpenSfM's ``reconstruction.json`` and ODM's ``shots.geojson`` (whose interior parameters
    come from ``interior`` or the ``cameras.json`` beside it or one directory up) pick the shot
    by the image's stem in the same way, in the map frame of the reconstruction's UTM zone (see
    :mod:`orthomvp.camera.formats.opensfm`); ``cameras.json`` alone raises InputError.

    A missing or unreadable file, one that is not a regular file (a FIFO, ``/dev/zero``) or one
    larger than :data:`~orthomvp.io.files.MAX_SMALL_FILE` raises InputError; a file that breaks
    its format (nested too deeply to parse included) raises FormatError naming it (and the
    line, for text formats).
    """
    of_type(path, (str, os.PathLike), "a camera file name")
    file = CameraFile(Path(path), image, interior)
    try:
        return _format_of(file).read(file)
    except RecursionError:  # JSON or YAML nested deeper than Python's parsers go
        raise FormatError(file.path, "nested too deeply to be a camera file") from None


def _format_of(file: CameraFile) -> CameraFormat:
    """The format of ``file`` (see the module docstring); FormatError if none recognises it."""
    suffix = file.path.suffix.lower()
    named = [fmt for fmt in FORMATS if suffix in fmt.suffixes]
    for fmt in named or FORMATS:
        if fmt.sniff is not None and fmt.sniff(file):
            return fmt
    if named:
        return named[-1]
    tried = ", not ".join(fmt.name for fmt in FORMATS if fmt.sniff is not None)
    raise FormatError(file.path, f"not a camera file: not {tried}")


def load_view(image_path: str | Path, camera_path: str | Path) -> tuple[np.ndarray, Camera]:
    """Read an image (float32 (bands, rows, cols), see :func:`orthomvp.io.raster.read_image`) and
    its camera (:func:`read_camera`, the image's name picking its row in multi-camera files),
    checked against each other; the camera carries the image's size."""
    image = read_image(image_path)
    return image, check_image(image, read_camera(camera_path, image_path), str(image_path))
