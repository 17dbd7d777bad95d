"""``orthomvp view``: the browser viewer of a DEM, its views and the outputs over it."""

from __future__ import annotations

import socket
import threading
import warnings
import webbrowser
from pathlib import Path

import click

from orthomvp.cli.command import Command
from orthomvp.cli.options import (
    PATH,
    DemInput,
    check_outdir,
    dem_argument,
    dem_options,
    eps_option,
    levels_option,
    overwrite_option,
    quiet,
)
from orthomvp.errors import InputError, OrthoMVPWarning

LOOPBACK = ("127.0.0.1", "localhost", "::1")


def _bind(host: str, port: int) -> socket.socket:
    """A listening socket on (host, port); InputError (one line) when it cannot be had."""
    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(64)
    except OSError as exc:
        sock.close()
        raise InputError(f"cannot serve on {host} port {port}: {exc.strerror or exc}") from None
    return sock


def _pairs(ctx: click.Context, param: click.Parameter, value: tuple[Path, ...]) -> list:
    """IMAGE CAMERA pairs: none (no clicks) or at least 2 (the objective needs 2 views)."""
    if len(value) % 2:
        raise click.UsageError("needs IMAGE CAMERA pairs: got an odd number of files", ctx)
    if len(value) == 2:
        raise click.UsageError("clicks need at least 2 IMAGE CAMERA pairs (or give none)", ctx)
    return list(zip(value[::2], value[1::2], strict=True))


@click.command(cls=Command, short_help="look at a DEM, its views and outputs in the browser")
@dem_argument
@click.argument(
    "pairs",
    type=PATH,
    nargs=-1,
    callback=_pairs,
    metavar="[IMAGE CAMERA ...]",
    help="the views, each image followed by its camera (at least 2 for clicks; none: the map "
    "alone)",
)
@click.option(
    "--ortho",
    "orthos",
    type=PATH,
    multiple=True,
    metavar="FILE",
    help="an orthophoto to show (repeatable)",
)
@click.option(
    "--mosaic",
    "mosaics",
    type=PATH,
    multiple=True,
    metavar="FILE",
    help="a mosaic to show (repeatable)",
)
@click.option(
    "--source",
    "sources",
    type=PATH,
    multiple=True,
    metavar="FILE",
    help="a mosaic's source raster: which view each post came from",
)
@click.option(
    "--visibility",
    "visibilities",
    type=PATH,
    multiple=True,
    metavar="FILE",
    help="a view's visibility codes (repeatable)",
)
@click.option(
    "--fitted",
    type=PATH,
    metavar="FILE",
    help="a fitted DEM (orthomvp fit): shown shaded and as its change from DEM",
)
@click.option(
    "--uncertainty", type=PATH, metavar="FILE", help="the fit's 1-sigma height uncertainty (metres)"
)
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="address to serve on; any other than the loopback is warned about",
)
@click.option(
    "--port",
    type=click.IntRange(0, 65535),
    default=8765,
    show_default=True,
    help="port to serve on (0: any free one)",
)
@click.option("--no-browser", is_flag=True, help="print the URL but do not open a browser")
@click.option(
    "--export",
    type=PATH,
    metavar="DIR",
    help="write a static page with pre-rendered tiles into DIR instead of serving (created "
    "if absent; nothing is written on failure). A folder an earlier export wrote is refreshed "
    "whole; any other folder that holds files needs --overwrite. The page has no clicks or 3D, "
    "so IMAGE CAMERA pairs are not read (a warning says so)",
)
@overwrite_option
@levels_option("coarse-to-fine pyramid levels of a click's fit")
@eps_option
@dem_options
def view(
    dem: DemInput,
    pairs: list[tuple[Path, Path]],
    orthos: tuple[Path, ...],
    mosaics: tuple[Path, ...],
    sources: tuple[Path, ...],
    visibilities: tuple[Path, ...],
    fitted: Path | None,
    uncertainty: Path | None,
    host: str,
    port: int,
    no_browser: bool,
    export: Path | None,
    overwrite: bool,
    levels: int,
    eps: float | None,
) -> None:
    """A local web page over DEM: pan and zoom the shaded DEM and the given orthophotos,
    mosaics, source rasters, visibility codes, fitted DEM (and its change from DEM) and
    uncertainty, with a lon/lat graticule, a scale bar and a legend; hover to read every
    layer's value. With IMAGE CAMERA pairs, a click on a post shows the explorer's rplot,
    llplot, patches and fit path there (hwin, views and plot ranges set in the page) and the
    DEM around it in 3D with the cameras and their rays. The server listens on 127.0.0.1 and
    every request needs the random token in the printed URL; Ctrl-C stops it. A layer file
    that is missing or off the DEM's grid is named in the page and on stderr, and the rest is
    shown."""
    from orthomvp.optional import require

    for module in ("starlette", "uvicorn"):
        require(module, "orthomvp view (pip install 'orthomvp[view]')")
    from orthomvp.view import LayerSet

    if dem.path is None:
        raise InputError("view needs a DEM")
    if export is not None:
        from orthomvp.view.export import MARKS

        check_outdir(export, "--export", overwrite=overwrite, refresh=MARKS)
        if pairs:
            warnings.warn(
                f"--export ignores the {len(pairs)} IMAGE CAMERA pairs (not read): the static "
                "page has no clicks or 3D; view without --export serves them",
                OrthoMVPWarning,
                stacklevel=1,
            )
    layers = LayerSet(dem.path)
    for p in orthos:
        layers.add("image", [p], f"image: {p.name}")
    for p in mosaics:
        layers.add("image", [p], f"mosaic: {p.name}")
    for p in sources:
        layers.add_source(p, f"source: {p.name}")
    for p in visibilities:
        layers.add("visibility", [p], f"visibility: {p.name}")
    if fitted is not None:
        layers.add("height", [fitted], f"fitted DEM: {fitted.name}")
        layers.add("change", [fitted, dem.path], f"change: {fitted.name} - {dem.path.name}")
    if uncertainty is not None:
        layers.add("uncertainty", [uncertainty], f"uncertainty: {uncertainty.name}")
    for problem in layers.problems:
        warnings.warn(f"not shown: {problem.reason}", OrthoMVPWarning, stacklevel=1)
    if export is not None:
        from orthomvp.view import write_export

        count = write_export(layers, export, overwrite=overwrite)
        if not quiet():
            print(
                f"orthomvp: wrote {export}/index.html and {count} tiles of "
                f"{len(layers.layers)} layers"
            )
        return
    sock = _bind(host, port)
    if host not in LOOPBACK:
        warnings.warn(
            f"serving on {host}, not the loopback: anyone who can reach it and has the token "
            "in the URL can read these files",
            OrthoMVPWarning,
            stacklevel=1,
        )
    posts = _posts(dem, pairs, layers, eps, levels) if pairs else None
    _serve(layers, posts, sock, host, no_browser)


def _posts(dem: DemInput, pairs: list[tuple[Path, Path]], layers, eps, levels):  # noqa: ANN001, ANN202
    from orthomvp.camera import load_view
    from orthomvp.view import Posts

    if not quiet():
        print("orthomvp: loading the images...", flush=True)
    views = [load_view(image, camera) for image, camera in pairs]
    source = _dem_source(dem, [v[1] for v in views])
    names = [image.name for image, _ in pairs]
    return Posts(
        layers, source, [v[0] for v in views], [v[1] for v in views], names, eps=eps, levels=levels
    )


def _dem_source(dem: DemInput, cameras: list):  # noqa: ANN202
    """The DEM as :meth:`DemInput.read` takes it (the world frame its cameras fit, every camera
    above it, map-frame heights checked), scanned once in blocks and then read in windows
    (:class:`~orthomvp.engine.grid.DemSource`): a click reads its block, not the DEM."""
    from dataclasses import replace

    from orthomvp.camera import camera_centres
    from orthomvp.camera.rpc import check_map_frame_heights
    from orthomvp.codes import WorldFrame
    from orthomvp.engine.grid import scan_dem, with_world
    from orthomvp.geometry.datum import HeightOptions
    from orthomvp.geometry.world import check_cameras_above, detect_world

    heights = HeightOptions(dem.vertical_datum, dem.height_offset)
    source = scan_dem(dem.path, dem.crs, dem.radius_values, heights=heights)
    centres, views = camera_centres(cameras)
    world = (
        detect_world(source.preview, centres, views)
        if dem.world == "auto"
        else WorldFrame(dem.world)
    )
    preview = replace(source.preview, world=world)
    preview.check_convention()  # heights against radii, before the cameras are judged by them
    check_cameras_above(preview, centres, views, spare=len(cameras) > 1)  # (as the file holds)
    if dem.height_offset is None and dem.vertical_datum == "auto":
        named = [(f"camera {k + 1}", camera) for k, camera in enumerate(cameras)]
        check_map_frame_heights(named, world, dem.crs or source.file_crs, as_read=True)
    return with_world(source, world)


def _serve(layers, posts, sock: socket.socket, host: str, no_browser: bool) -> None:  # noqa: ANN001
    import uvicorn

    from orthomvp.view import create_app, new_token

    token = new_token()
    port = sock.getsockname()[1]
    shown = f"[{host}]" if ":" in host else host
    url = f"http://{shown}:{port}/?token={token}"
    app = create_app(layers, token, posts)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="off"))
    print(f"orthomvp: view at {url} (Ctrl-C stops it)", flush=True)
    if posts is not None:
        threading.Thread(target=posts.warm, daemon=True).start()
    if not no_browser:
        threading.Timer(0.5, webbrowser.open, args=(url,)).start()
    try:
        server.run(sockets=[sock])
    finally:  # Ctrl-C ends it as every command: status 130 (uvicorn re-raises the signal)
        sock.close()
        layers.close()
