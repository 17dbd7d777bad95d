"""The arguments that the engine's planners (:func:`~orthomvp.engine.plan_ortho`,
:func:`~orthomvp.engine.plan_fit`, :func:`~orthomvp.engine.plan_check`) share, checked once
here: the DEM's path, the (image, camera) views, the visibility tolerance and how to read the
DEM. Each refusal is an :class:`~orthomvp.errors.InputError` naming the argument."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from orthomvp.camera import Camera
from orthomvp.errors import InputError
from orthomvp.io.output_checks import same_file
from orthomvp.validate import number, of_type

PATHLIKE = (str, os.PathLike)
"""What a file argument may be."""


def dem_path(dem: Any) -> Path:
    """The DEM argument as a Path; InputError unless a str or a path."""
    return Path(of_type(dem, PATHLIKE, "dem", " (the DEM's path)"))


def view_pairs(views: Any, minimum: int = 1) -> list[tuple[Path, Path | Camera]]:
    """``views`` as a list of (image path, camera path or camera) pairs, at least ``minimum``
    and no pair twice; InputError otherwise (a dict, a string, a pair of the wrong length)."""
    if isinstance(views, str | bytes | os.PathLike | Mapping) or not isinstance(views, Sequence):
        raise InputError(
            "views must be a list of (image, camera) pairs, got "
            f"{type(views).__name__} {str(views)[:40]!r}"
        )
    pairs: list[tuple[Path, Path | Camera]] = []
    for k, view in enumerate(views, start=1):
        if isinstance(view, str | bytes | os.PathLike) or not isinstance(view, Sequence):
            raise InputError(f"view {k} must be an (image, camera) pair, got {view!r:.60}")
        if len(view) != 2:
            raise InputError(
                f"view {k} must be an (image, camera) pair, got {len(view)} item(s): {view!r:.60}"
            )
        image, camera = view
        of_type(image, PATHLIKE, f"the image of view {k}", " (its path)")
        of_type(camera, (*PATHLIKE, Camera), f"the camera of view {k}", " (a path or a Camera)")
        pair = (Path(image), camera if isinstance(camera, Camera) else Path(camera))
        for j, (other_image, other_camera) in enumerate(pairs, start=1):
            if same_file(image, other_image) and _same_camera(pair[1], other_camera):
                raise InputError(
                    f"{image}: views {j} and {k} are the same image and camera; give each view once"
                )
        pairs.append(pair)
    if len(pairs) < minimum:
        raise InputError(
            "give at least one image and its camera"
            if minimum == 1
            else f"got {len(pairs)} view(s): this needs at least {minimum} images, each with "
            "its camera"
        )
    return pairs


def _same_camera(a: Path | Camera, b: Path | Camera) -> bool:
    if isinstance(a, Camera) or isinstance(b, Camera):
        return a is b
    return same_file(a, b)


def eps_posts(eps: Any) -> float | None:
    """The visibility tolerance ``eps`` (DEM posts): None (the default rule) or a finite
    number > 0; InputError otherwise."""
    if eps is None:
        return None
    return number(eps, "eps (DEM posts)", minimum=0, min_open=True)


def dem_reading(
    *,
    radius_values: Any,
    world: Any,
    progress: Any,
    vertical_datum: Any,
    height_offset: Any,
    dem_crs: Any = None,
) -> None:
    """InputError for options of how the DEM is read that are not of their kind:
    ``radius_values`` and ``progress`` booleans, ``world`` "auto", "body" or "map",
    ``vertical_datum`` "auto" or "ignore", ``height_offset`` None or a finite number of
    metres, ``dem_crs`` None, a string or a CRS object (checked by pyproj where read)."""
    from orthomvp.engine.grid_choice import world_frame

    of_type(radius_values, bool, "radius_values")
    of_type(progress, bool, "progress")
    world_frame(world)
    if vertical_datum not in ("auto", "ignore"):
        raise InputError(f"vertical_datum must be auto or ignore, not {vertical_datum!r}")
    if height_offset is not None:
        number(height_offset, "height_offset (metres)")
    if isinstance(dem_crs, bool | int | float):
        raise InputError(f"dem_crs must be a CRS or a string naming one, got {dem_crs!r}")


def check_bounds(bounds: Any) -> tuple[float, float, float, float] | None:
    """``bounds`` (left, bottom, right, top) as four finite floats with left < right and
    bottom < top, or None; InputError otherwise."""
    if bounds is None:
        return None
    if isinstance(bounds, str) or not isinstance(bounds, Sequence) or len(bounds) != 4:
        raise InputError(f"bounds must be four numbers (left, bottom, right, top), got {bounds!r}")
    left, bottom, right, top = (number(b, "bounds") for b in bounds)
    if not (left < right and bottom < top):
        raise InputError(f"bounds must have left < right and bottom < top, got {bounds}")
    return left, bottom, right, top
