"""Camera file formats, one module each: ``tsai`` (ASP/VW ``.tsai`` text and binary
``.pinhole``), ``opensfm`` (OpenSfM's ``reconstruction.json``, ODM's ``shots.geojson`` and
``cameras.json``), ``orthority`` (Orthority's interior and exterior parameter files), ``json``
(orthomvp's own JSON), ``csm`` (USGS CSM ISDs and model states) and ``rpc`` (RPC cameras:
GeoTIFF metadata, ``_RPC.TXT``, ``.RPB``, Orthority's RPC YAML).

Each module lists what it reads in ``FORMATS``, a tuple of
:class:`~orthomvp.camera.formats._common.CameraFormat` entries, which :mod:`orthomvp.camera`'s
registry collects. Format modules import :mod:`orthomvp.camera.model`,
:mod:`orthomvp.camera.distortion`, :mod:`orthomvp.camera.rpc` and :mod:`._common`, never
:mod:`orthomvp.camera` itself.
"""
