"""The viewer's web application (Starlette, served by uvicorn).

Secure by default: the caller binds it to 127.0.0.1; every request needs the session's random
token, as a ``token`` query parameter (which also sets a same-site, HTTP-only cookie, as
Jupyter does) or that cookie, else 403. Only the files the user named are served, by layer id
(a registry), and the page's own static files by name from a fixed table built at start; no
path in a request opens a file, and nothing in a request is evaluated.
"""

from __future__ import annotations

import secrets

import numpy as np
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.routing import Route
from starlette.types import ASGIApp, Receive, Scope, Send

from orthomvp.errors import OrthoMVPError
from orthomvp.explore import ExploreError
from orthomvp.view.layers import LayerSet
from orthomvp.view.page import TYPES, clean, index_html, page_config, static_files
from orthomvp.view.post import Controls, Posts
from orthomvp.view.tiles import Pyramid, tile_png

COOKIE = "orthomvp_view_token"


class TokenGate:
    """ASGI middleware: 403 unless the request carries the token (query or cookie)."""

    def __init__(self, app: ASGIApp, token: str) -> None:
        self.app, self.token = app, token

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        request = Request(scope)
        given = request.query_params.get("token")
        cookie = request.cookies.get(COOKIE)
        ok = any(v is not None and secrets.compare_digest(v, self.token) for v in (given, cookie))
        if not ok:
            await Response(
                "403: this page needs the token in the URL that orthomvp view printed",
                status_code=403,
                media_type="text/plain",
            )(scope, receive, send)
            return
        if given is not None and cookie != self.token:

            async def send_cookie(message: dict) -> None:
                if message["type"] == "http.response.start":
                    header = (f"{COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict").encode()
                    message.setdefault("headers", []).append((b"set-cookie", header))
                await send(message)

            await self.app(scope, receive, send_cookie)
            return
        await self.app(scope, receive, send)


def _json(content: object, status_code: int = 200) -> JSONResponse:
    return JSONResponse(clean(content), status_code=status_code)


def _float(request: Request, name: str) -> float:
    try:
        value = float(request.query_params[name])
    except (KeyError, ValueError):
        raise OrthoMVPError(f"{name} must be a number") from None
    if not np.isfinite(value):
        raise OrthoMVPError(f"{name} must be finite")
    return value


def create_app(layers: LayerSet, token: str, posts: Posts | None = None) -> ASGIApp:
    """The application over ``layers`` (and live clicks with ``posts``), behind the token."""
    pyramid = Pyramid.of(layers)
    files = static_files()
    config = page_config(layers, pyramid, posts is not None, posts.names if posts else [])
    page = index_html(config)

    async def index(request: Request) -> Response:
        return HTMLResponse(page, headers={"Cache-Control": "no-store"})

    async def static(request: Request) -> Response:
        path = files.get(request.path_params["name"])
        if path is None:
            return Response("not found", status_code=404, media_type="text/plain")
        return Response(path.read_bytes(), media_type=TYPES[path.suffix])

    def tile(request: Request) -> Response:
        p = request.path_params
        layer = layers.layers.get(p["layer"])
        if layer is None or not pyramid.valid(p["z"], p["x"], p["y"]):
            return Response("no such tile", status_code=404, media_type="text/plain")
        return Response(
            tile_png(layers, pyramid, layer, p["z"], p["x"], p["y"]), media_type="image/png"
        )

    def point(request: Request) -> Response:
        x, y = _float(request, "x"), _float(request, "y")
        lon, lat = layers.lonlat(np.array([x]), np.array([y]))
        values = {}
        for lay in layers.layers.values():
            v = lay.value_at(x, y)
            values[lay.id] = None if v is None else lay.kind.describe(v)
        return _json({"lon": float(lon[0]), "lat": float(lat[0]), "values": values})

    def click(request: Request) -> Response:
        if posts is None:
            return _json({"error": "no views given: clicks need IMAGE CAMERA pairs"})
        q = request.query_params
        views = tuple(int(v) for v in q["views"].split(",") if v) if "views" in q else None
        controls = Controls(
            hwin=int(q.get("hwin", 10)),
            views=views,
            h_range=float(q["hrange"]) if q.get("hrange") else None,
            h_steps=int(q.get("hsteps", 61)),
            t_range=float(q.get("trange", 20)),
            t_steps=int(q.get("tsteps", 21)),
        )
        try:  # what the page says in its status line (a click off the DEM, say)
            return _json(posts.click(_float(request, "x"), _float(request, "y"), controls))
        except ExploreError as exc:
            return _json({"error": str(exc)})

    def scene(request: Request) -> Response:
        if posts is None:
            return _json({"error": "no views given: the 3D view needs IMAGE CAMERA pairs"})
        layer = layers.layers.get(request.query_params.get("layer", "L0"))
        if layer is None:
            return _json({"error": "no such layer"}, status_code=404)
        x, y = _float(request, "x"), _float(request, "y")
        return _json(posts.scene(x, y, layer))

    def guarded(fn):  # noqa: ANN001, ANN202
        def run(request: Request) -> Response:
            try:
                return fn(request)
            except (OrthoMVPError, ValueError) as exc:
                return _json({"error": str(exc)}, status_code=400)

        return run

    app = Starlette(
        routes=[
            Route("/", index),
            Route("/static/{name:path}", static),
            Route("/tiles/{layer}/{z:int}/{x:int}/{y:int}.png", guarded(tile)),
            Route("/api/point", guarded(point)),
            Route("/api/click", guarded(click)),
            Route("/api/scene", guarded(scene)),
        ]
    )
    return TokenGate(app, token)


def new_token() -> str:
    """A random URL-safe token (32 bytes of entropy)."""
    return secrets.token_urlsafe(32)
