"""Synthetic scenes with exact ground truth, independent of the code under test.

A scene (``planar``, ``crater``, ``hills``) is a tile on the Moon (a sphere, R = 1737400 m)
whose heights and albedo are analytic functions of local (x, y) metres. Images are rendered by
ray casting a mesh three times finer than the DEM, supersampled, with Lambertian shading under
a fixed sun; visibility truth comes from marching each post's segment towards the camera
against the *analytic* surface, never from the mesh used elsewhere. :class:`SmallBody` is an
analytic irregular small body with the same kind of truth.

``surface``: local frame and the lit analytic surface; ``kinds``: the kinds' heights and
albedo; ``cameras``: orbital camera placements; ``rendering``: images; ``truth``: the visibility
marcher; ``scene``: :class:`Scene` and :func:`make_scene`; ``writer``: the scene directory;
``loader``: reading it back; ``scoring``: visibility scores against truth; ``smallbody``.
"""

from orthomvp.synthetic.cameras import ViewSpec, look_at, orbital_camera
from orthomvp.synthetic.kinds import KINDS
from orthomvp.synthetic.loader import SceneData, SceneView, load_scene
from orthomvp.synthetic.scene import Scene, make_scene
from orthomvp.synthetic.scoring import away_from_boundaries, classification_scores
from orthomvp.synthetic.smallbody import SmallBody
from orthomvp.synthetic.surface import MOON_CRS, MOON_RADIUS, local_frame

__all__ = [
    "KINDS",
    "MOON_CRS",
    "MOON_RADIUS",
    "Scene",
    "SceneData",
    "SceneView",
    "SmallBody",
    "ViewSpec",
    "away_from_boundaries",
    "classification_scores",
    "load_scene",
    "local_frame",
    "look_at",
    "make_scene",
    "orbital_camera",
]
