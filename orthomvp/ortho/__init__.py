"""Making the picture. Orthophotos that leave occluded posts empty and mosaics that fill them
from the views that see them (:mod:`.orthophoto`); the mosaic's composition: trust, seamlines,
feathering and the hole policy (:mod:`.composite`, with the fused numba kernel
:mod:`.composite_kernel` that its numpy code tests), after the views' radiometric balance
(:mod:`.balance`). Its names are imported on first use."""

from typing import TYPE_CHECKING

from orthomvp._lazy import lazy_exports

_HOMES = {
    name: "orthomvp.ortho.orthophoto"
    for name in (
        "BYTES_PER_BAND_POST",
        "INTERPOLATION",
        "OUTSIDE",
        "Mosaic",
        "Ortho",
        "check_orthophoto_memory",
        "mosaic",
        "orthophoto_bytes",
        "orthorectify",
        "sample_image",
    )
} | {"MosaicOptions": "orthomvp.ortho.composite"}

__all__ = [
    "BYTES_PER_BAND_POST",
    "INTERPOLATION",
    "Mosaic",
    "MosaicOptions",
    "OUTSIDE",
    "Ortho",
    "check_orthophoto_memory",
    "mosaic",
    "orthophoto_bytes",
    "orthorectify",
    "sample_image",
]

if TYPE_CHECKING:
    from orthomvp.ortho.composite import MosaicOptions
    from orthomvp.ortho.orthophoto import (
        BYTES_PER_BAND_POST,
        INTERPOLATION,
        OUTSIDE,
        Mosaic,
        Ortho,
        check_orthophoto_memory,
        mosaic,
        orthophoto_bytes,
        orthorectify,
        sample_image,
    )

__getattr__, __dir__ = lazy_exports(__name__, _HOMES)
