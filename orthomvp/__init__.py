"""orthomvp: occlusion-aware orthorectification and multi-view DEM refinement."""

__version__ = "0.1.0"
