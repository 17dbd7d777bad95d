"""``orthomvp info``: what a DEM is (CRS, body, heights, posts, extent) and what an image sees
of it (footprint, GSD, emission angles, time range, the default output grid), for a human, or
as GeoJSON with ``--json`` (:func:`orthomvp.engine.info.describe`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from orthomvp.cli.command import Command
from orthomvp.cli.options import CAMERA_HELP, PATH, DemInput, dem_argument, dem_options


@click.command(cls=Command, short_help="what a DEM is, and what an image sees of it")
@dem_argument
@click.argument(
    "image",
    type=PATH,
    required=False,
    metavar="[IMAGE]",
    help="an image: any raster GDAL reads, or an ISIS3 .cub (gives the image size)",
)
@click.argument(
    "camera",
    type=PATH,
    required=False,
    metavar="[CAMERA]",
    help=f"its {CAMERA_HELP}; default: the image's own RPCs",
)
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="print a GeoJSON Feature: the footprint polygon (lon/lat degrees; the DEM's outline "
    "without an image) and everything else in its properties",
)
@dem_options
def info(dem: DemInput, image: Path | None, camera: Path | None, as_json: bool) -> None:
    """Describe DEM: CRS, body, height convention and vertical datum, size, post spacing and
    extent. With IMAGE (and its CAMERA; without one, the image's own RPCs): its footprint on
    the DEM, ground sample distance, emission angles, time range (line scanners) and the
    output grid that ortho, visibility and mosaic would choose by default."""
    from orthomvp.engine.info import describe

    feature = describe(dem.path, image, camera, **dem.plan_options())
    if as_json:
        click.echo(json.dumps(feature, indent=1))
        return
    click.echo("\n".join(text_lines(feature)))


def text_lines(feature: dict[str, Any]) -> list[str]:
    """The human-readable description of a :func:`~orthomvp.engine.info.describe` Feature."""
    d = feature["properties"]["dem"]
    body = d["body"]
    (sx, sy), (mx, my) = d["post_spacing"], d["post_spacing_m"]
    lon0, lat0, lon1, lat1 = d["extent_lonlat"]
    lines = [
        f"DEM {d['path']}",
        f"  size:          {d['size'][0]:,} x {d['size'][1]:,} posts (columns x rows)",
        f"  CRS:           {d['crs']} ({d['kind']}, {d['units']})",
        f"  body:          {body['ellipsoid']}, semi-axes {body['semi_major_m']:,.1f} / "
        f"{body['semi_minor_m']:,.1f} m",
        f"  values:        {d['heights']}; {d['height_range'][0]:,.1f} to "
        f"{d['height_range'][1]:,.1f} m",
        f"  vertical datum: {d['vertical_datum'] or _no_datum(d['heights'])}",
        f"  post spacing:  {sx:.6g} x {sy:.6g} {d['units']} ({mx:.3g} x {my:.3g} m)",
        f"  extent:        longitude {lon0:.5f} to {lon1:.5f}, latitude {lat0:.5f} to {lat1:.5f}"
        " (degrees)",
    ]
    image = feature["properties"].get("image")
    if image is None:
        return lines
    lines += [
        f"image {image['path']}: {image['size'][0]:,} x {image['size'][1]:,} pixels, "
        f"{image['bands']} band(s), {image['camera']}"
    ]
    if not image["sees_dem"]:
        return [*lines, "  footprint:     the image sees none of the DEM"]
    gsd, (e0, e1) = image["gsd_m"], image["emission_deg"]
    ring = feature["geometry"]["coordinates"][0][:-1]
    corners = ", ".join(f"({lon:.5f}, {lat:.5f})" for lon, lat in ring[:8])
    more = f", ... ({len(ring)} vertices; --json for all)" if len(ring) > 8 else ""
    grid = image["grid"]
    left, bottom, right, top = grid["bounds"]
    lines += [
        f"  footprint:     lon/lat {corners}{more}",
        f"  GSD:           median {gsd['median']:.3g} m, min {gsd['min']:.3g}, max "
        f"{gsd['max']:.3g} (per pixel, on the horizontal)",
        f"  emission:      {e0:.1f} to {e1:.1f} degrees off the vertical",
    ]
    if image["time_s"] is not None:
        t0, t1 = image["time_s"]
        lines.append(f"  time:          {t0:.4f} to {t1:.4f} s from the centre time")
    (rx, ry), (gx, gy) = grid["res"], grid["res_m"]
    units = f"{rx:.6g} {grid['units']}" if rx == ry else f"{rx:.6g} x {ry:.6g} {grid['units']}"
    metres = f"{gx:.3g} m" if f"{gx:.3g}" == f"{gy:.3g}" else f"{gx:.3g} x {gy:.3g} m"
    lines += [
        f"  default grid:  {grid['size'][0]:,} x {grid['size'][1]:,} posts of "
        f"{units} ({metres}), "
        f"{100 * grid['dem_share']:.1f}% of the DEM's extent",
        f"                 bounds {left:.10g} {bottom:.10g} {right:.10g} {top:.10g} "
        "(left bottom right top)",
    ]
    return lines


def _no_datum(heights: str) -> str:
    """The vertical datum line of a DEM without one: heights above the ellipsoid, or radii."""
    return "none (radii)" if heights.startswith("radius") else "none (heights above the ellipsoid)"
