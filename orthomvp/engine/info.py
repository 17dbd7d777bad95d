"""What a DEM is, and what an image sees of it: :func:`describe` gives it as a GeoJSON Feature
(the ``orthomvp info`` command prints it for a human, or as is with ``--json``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from orthomvp.camera import Camera
from orthomvp.codes import WorldFrame
from orthomvp.engine.footprint import image_footprint, to_lonlat
from orthomvp.engine.grid import DemSource, grid_to_dem, scan_dem
from orthomvp.engine.grid_choice import choose_grid, read_source
from orthomvp.engine.images import image_source
from orthomvp.engine.units import unit_scale
from orthomvp.geometry.crs import as_pyproj
from orthomvp.geometry.datum import HeightOptions
from orthomvp.geometry.vectors import nan_median
from orthomvp.io.raster import open_raster

EDGE_POINTS = 9
"""Points along each edge of the DEM for its lon/lat extent and outline."""


def describe(
    dem: str | Path,
    image: str | Path | None = None,
    camera: str | Path | Camera | None = None,
    *,
    dem_crs: object | None = None,
    radius_values: bool = False,
    world: WorldFrame | str = "auto",
    vertical_datum: str = "auto",
    height_offset: float | None = None,
) -> dict[str, Any]:
    """A GeoJSON Feature describing the DEM at ``dem`` (read as ``dem_crs``, ``radius_values``
    and ``world`` say, as the engine reads it) and, with an ``image``, what the image sees
    through ``camera`` (default: the image itself, for RPCs in its metadata), on the heights
    its camera needs (``vertical_datum``, ``height_offset``: :mod:`orthomvp.geometry.datum`;
    the DEM's own height range as the file holds them).

    ``properties["dem"]``: path, size (cols, rows), CRS name (the file's, vertical part
    included), kind, body (ellipsoid name and semi-axes, metres), height convention, vertical
    datum (None without one), post spacing (x, y) in CRS units and metres on the ground,
    extent (lon_min, lat_min, lon_max, lat_max, degrees) and height range.
    ``properties["image"]`` (with an image): path, size, bands, camera model, GSD (median,
    min, max, metres per pixel on the horizontal plane), emission angles (min, max, degrees
    off the local vertical), the time range (seconds, line scanners; else None) and the grid
    an ``ortho`` would use by default (:func:`orthomvp.engine.grid_choice.choose_grid`):
    size, resolution, bounds and its share of the DEM's extent. The geometry is the image's
    footprint (the convex hull of the posts it sees), or the DEM's outline without an image;
    lon/lat degrees, counter-clockwise."""
    views = []
    if image is not None:
        views = [image_source(image, image if camera is None else camera)]
    if views:
        heights = HeightOptions(vertical_datum, height_offset)
        source, views = read_source(dem, views, dem_crs, radius_values, world, False, heights)
    else:
        frame = WorldFrame.BODY if world == "auto" else WorldFrame(world)
        source = scan_dem(dem, dem_crs, radius_values, frame)
        source.preview.check_convention()  # heights against radii, as read_source does
    properties: dict[str, Any] = {"dem": _dem_properties(source, dem_crs)}
    ring = _dem_outline(source)
    if views:
        view = views[0]
        print_ = image_footprint(source, view)
        grid = choose_grid(source, views, footprints=[print_])
        properties["image"] = _image_properties(source, view, print_, grid)
        if print_.window is not None:
            lon, lat = to_lonlat(source, print_.outline[:, 0], print_.outline[:, 1])
            ring = np.stack([lon, lat], axis=-1)
        else:
            ring = None
    geometry = None if ring is None else {"type": "Polygon", "coordinates": [_closed(ring)]}
    return {"type": "Feature", "geometry": geometry, "properties": properties}


def _dem_properties(dem: DemSource, dem_crs: object | None) -> dict[str, Any]:
    crs = as_pyproj(dem.crs)
    vertical = None
    name = crs.name
    if dem_crs is None:
        from pyproj import CRS

        with open_raster(dem.path) as src:
            whole = CRS.from_wkt(src.crs.to_wkt())
        name = whole.name
        if whole.is_compound and len(whole.sub_crs_list) > 1:
            vertical = whole.sub_crs_list[1].name
    a, b = dem.preview.radii
    per_unit, unit = unit_scale(crs, a)
    ellipsoid = dem.preview.geodetic_crs.ellipsoid
    if dem.radius_values:
        heights = "radius from the body's centre"
    elif dem.shift is not None:  # converted (or offset) for the cameras
        held = f"{_datum(vertical)} heights" if vertical is not None else "the file's heights"
        heights = f"height above the reference ellipsoid (from {held}, shifted for the cameras)"
    elif vertical is not None:
        heights = f"height above {_datum(vertical)} (the vertical datum)"
    else:
        heights = "height above the reference ellipsoid"
    rows, cols = dem.shape
    spacing = (abs(dem.transform.a), abs(dem.transform.e))
    lon, lat = _dem_outline(dem).T
    return {
        "path": str(dem.path),
        "size": [cols, rows],
        "crs": name,
        "kind": "geographic" if crs.is_geographic else "projected",
        "units": unit,
        "body": {"ellipsoid": ellipsoid.name, "semi_major_m": a, "semi_minor_m": b},
        "heights": heights,
        "vertical_datum": vertical,
        "post_spacing": list(spacing),
        "post_spacing_m": _ground(dem, None, spacing, per_unit, crs),
        "extent_lonlat": [float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())],
        "height_range": [dem.h_min, dem.h_max],
        "world": dem.world.value,
    }


def _ground(
    dem: DemSource,
    grid: Any | None,
    spacing: tuple[float, float],
    per_unit: float,
    crs: Any,
) -> list[float]:
    """Metres on the ground between neighbouring posts (x, y) of the output ``grid`` (None:
    the DEM's own) of post ``spacing`` (CRS units): on a geographic ``crs`` measured at its
    centre (:meth:`~orthomvp.engine.grid.DemSource.ground_spacing`; a degree of longitude is
    cos(latitude) of one of latitude), elsewhere nominal (``per_unit`` metres a unit,
    :func:`~orthomvp.engine.units.unit_scale`)."""
    if not crs.is_geographic or dem.world != WorldFrame.BODY:
        return [s * per_unit for s in spacing]
    if grid is None:
        return list(dem.ground_spacing())
    return list(dem.ground_spacing(grid_to_dem(grid, dem), grid.shape))


def _datum(vertical: str) -> str:
    """A vertical CRS's name without its trailing " height" ("EGM2008 height" -> "EGM2008"),
    for phrases that say "height" or "heights" themselves."""
    return vertical.removesuffix(" height")


def _image_properties(dem: DemSource, view: Any, footprint: Any, grid: Any) -> dict[str, Any]:
    out: dict[str, Any] = {
        "path": str(view.path),
        "size": [view.width, view.height],
        "bands": view.bands,
        "camera": type(view.camera).__name__,
        "sees_dem": footprint.window is not None,
    }
    if footprint.window is None:
        return out
    gsd, emission = footprint.gsd, footprint.emission
    rows, cols = grid.shape
    per_unit, unit = unit_scale(as_pyproj(grid.crs), dem.preview.radii[0])
    t = grid.transform
    out.update(
        {
            "gsd_m": {
                "median": float(nan_median(gsd)),
                "min": float(np.nanmin(gsd)),
                "max": float(np.nanmax(gsd)),
            },
            "emission_deg": [float(np.nanmin(emission)), float(np.nanmax(emission))],
            "time_s": None if footprint.time is None else list(footprint.time),
            "dem_window": list(footprint.window),
            "grid": {
                "size": [cols, rows],
                "res": [t.a, -t.e],
                "res_m": _ground(dem, grid, (t.a, -t.e), per_unit, grid.crs),
                "units": unit,
                "bounds": [t.c, t.f + rows * t.e, t.c + cols * t.a, t.f],
                "dem_share": _share(grid, dem),
            },
        }
    )
    return out


def _share(grid: Any, dem: DemSource) -> float:
    """The grid's area as a share of the DEM's (both in the DEM's CRS)."""
    rows, cols = grid.shape
    area = abs(grid.transform.a * grid.transform.e) * rows * cols
    whole = abs(dem.transform.a * dem.transform.e) * dem.shape[0] * dem.shape[1]
    return float(area / whole)


def _dem_outline(dem: DemSource) -> np.ndarray:
    """The DEM's outer post edges in lon/lat degrees, (n, 2), :data:`EDGE_POINTS` a side."""
    rows, cols = dem.shape
    s = np.linspace(0, 1, EDGE_POINTS)[:-1]
    c = np.concatenate([s * cols, np.full_like(s, cols), (1 - s) * cols, np.zeros_like(s)]) - 0.5
    r = np.concatenate([np.zeros_like(s), s * rows, np.full_like(s, rows), (1 - s) * rows]) - 0.5
    lon, lat = to_lonlat(dem, c, r)
    return np.stack([lon, lat], axis=-1)


def _closed(ring: np.ndarray) -> list[list[float]]:
    """A GeoJSON linear ring: counter-clockwise (right-hand rule), first point repeated."""
    x, y = ring[:, 0], ring[:, 1]
    area = np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    if area < 0:
        ring = ring[::-1]
    points = [[float(a), float(b)] for a, b in ring]
    return [*points, points[0]]
