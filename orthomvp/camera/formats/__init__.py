"""Camera file formats, one module each: ``tsai`` (ASP/VW ``.tsai`` text and binary
``.pinhole``), ``opensfm`` (OpenSfM's ``reconstruction.json``, ODM's ``shots.geojson`` and
``cameras.json``), ``orthority`` (Orthority's interior and exterior parameter files) and
``json`` (orthomvp's own JSON).

Each module lists what it reads in ``FORMATS``, a tuple of
:class:`~orthomvp.camera.formats._common.CameraFormat` entries, which :mod:`orthomvp.camera`'s
registry collects. Format modules import :mod:`orthomvp.camera.model`,
:mod:`orthomvp.camera.distortion` and :mod:`._common`, never :mod:`orthomvp.camera` itself.
"""
