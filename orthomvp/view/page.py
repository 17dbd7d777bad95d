"""The viewer's page without its server: the static files it loads, its configuration (the
map's frame, layers, legends and graticule) and the HTML with that configuration inlined. The
static export (:mod:`orthomvp.view.export`) and the demo's page use these without Starlette.
"""

from __future__ import annotations

import html
import json
from importlib import resources
from pathlib import Path

import numpy as np

from orthomvp import __version__
from orthomvp.view.layers import LayerSet
from orthomvp.view.tiles import Pyramid, graticule

TYPES = {
    ".js": "text/javascript",
    ".css": "text/css",
    ".png": "image/png",
    ".html": "text/html",
    ".txt": "text/plain",
    ".svg": "image/svg+xml",
}


def static_files() -> dict[str, Path]:
    """The page's static files by their name under ``static/`` (built once: requests look
    names up here and never join a path)."""
    root = resources.files("orthomvp.view") / "static"
    out = {}
    for path in Path(str(root)).rglob("*"):
        if path.is_file() and path.suffix in TYPES:
            out[path.relative_to(Path(str(root))).as_posix()] = path
    return out


def page_config(layers: LayerSet, pyramid: Pyramid, live: bool, views: list[str]) -> dict:
    """What the page needs to draw the map: layers, legends, frame, graticule, problems."""
    left, bottom, right, top = layers.bounds
    return {
        "version": __version__,
        "live": live,
        "bounds": [[bottom, left], [top, right]],
        "metresPerUnit": layers.metres_per_unit(),
        "geographic": bool(layers.crs.is_geographic),
        "crs": layers.crs.name,
        **pyramid.leaflet(),
        "layers": [
            {
                "id": lay.id,
                "title": lay.title,
                "kind": lay.kind.name,
                "legend": lay.kind.legend(lay.stats),
            }
            for lay in layers.layers.values()
        ],
        "problems": [[p.path, p.reason] for p in layers.problems],
        "graticule": graticule(layers),
        "views": views,
    }


MODULES = (
    '<script type="importmap">{"imports": {"three": '
    '"./static/vendor/three-0.159.0/three.module.min.js"}}</script>\n'
    '<script type="module" src="static/view3d.js"></script>'
)
"""The 3D view's ES modules: live pages only (browsers refuse modules from file://)."""


def clean(value: object) -> object:
    """``value`` with every non-finite float as None (JSON has no NaN)."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean(v) for v in value]
    return value


def index_html(config: dict, *, live: bool = True, title: str = "", report: str = "") -> str:
    """The page with its configuration inlined (JSON inside a script element); ``title``
    (default "orthomvp view") and ``report``, HTML after the map (an export's)."""
    text = (resources.files("orthomvp.view") / "static" / "index.html").read_text()
    blob = json.dumps(clean(config)).replace("</", "<\\/")
    text = text.replace("{{STATIC}}", "static/").replace("{{MODULES}}", MODULES if live else "")
    text = text.replace("{{TITLE}}", html.escape(title or "orthomvp view"))
    text = text.replace("{{REPORT}}", f'<section id="report">{report}</section>' if report else "")
    return text.replace("{{CONFIG}}", blob)
