"""``orthomvp view``: a local web page over a DEM, its views and the outputs of ``ortho``,
``mosaic``, ``visibility`` and ``fit`` (the mvpgui successor in the browser).

``kinds``: what each kind of layer means (colours, legend, readout); ``layers``: the registry of
the files the user named; ``tiles``: the tile pyramid in the DEM's frame and the graticule;
``post``: a clicked post's explorer plots and 3D scene; ``server``: the Starlette application
behind a token; ``export``: the static page. The page's scripts (Leaflet, three.js) are vendored
under ``static/``.
"""

from orthomvp.view.export import write_export
from orthomvp.view.layers import LayerSet
from orthomvp.view.post import Controls, Posts
from orthomvp.view.server import create_app, new_token

__all__ = ["Controls", "LayerSet", "Posts", "create_app", "new_token", "write_export"]
