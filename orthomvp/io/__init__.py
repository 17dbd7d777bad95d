"""Files in and out. Rasters of any common format read through held datasets and windows, and
GeoTIFFs written (:mod:`.raster`); ISIS3 cubes and their labels (:mod:`.isis`); memory and disk
preflight (:mod:`.preflight`). Every output goes through an atomic output set, so that a failure
or a signal never leaves a half-written file."""
