"""``orthomvp view``: a local web page over a DEM, its views and the outputs of ``ortho``,
``mosaic``, ``visibility`` and ``fit`` (the mvpgui successor in the browser).

``kinds``: what each kind of layer means (colours, legend, readout); ``layers``: the registry of
the files the user named; ``tiles``: the tile pyramid in the DEM's frame and the graticule;
``post``: a clicked post's explorer plots and 3D scene; ``server``: the Starlette application
behind a token; ``page``: the page's files, configuration and HTML; ``export``: the static page
(which, like everything here but ``server``, needs no Starlette). The page's scripts (Leaflet,
three.js) are vendored under ``static/``.
"""

from typing import TYPE_CHECKING

from orthomvp._lazy import lazy_exports

_HOMES = {
    "Controls": "orthomvp.view.post",
    "LayerSet": "orthomvp.view.layers",
    "Posts": "orthomvp.view.post",
    "create_app": "orthomvp.view.server",
    "new_token": "orthomvp.view.server",
    "write_export": "orthomvp.view.export",
}
__all__ = ["Controls", "LayerSet", "Posts", "create_app", "new_token", "write_export"]

if TYPE_CHECKING:
    from orthomvp.view.export import write_export
    from orthomvp.view.layers import LayerSet
    from orthomvp.view.post import Controls, Posts
    from orthomvp.view.server import create_app, new_token

__getattr__, __dir__ = lazy_exports(__name__, _HOMES)
