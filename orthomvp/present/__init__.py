"""Presentation: colours of rasters on the DEM grid (``colours``), mesh export (``export``),
offscreen 3D snapshots (``snapshot``, camera placement and glyphs in ``viewpoint``), matplotlib
figures (``figures``) and the demo's web page (``webpage``). Import the modules themselves:
this package imports none of them, so that each heavy dependency loads only where it is used.
"""
