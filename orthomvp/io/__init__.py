"""Files in and out. Rasters of any common format read through held datasets and windows, and
GeoTIFFs written (:mod:`.raster`); ISIS3 cubes and their labels (:mod:`.isis`); memory and disk
preflight (:mod:`.preflight`). Every output goes through an atomic output set (:mod:`.outputs`),
so that a failure or a signal never leaves a half-written file: signals are held around its
steps (:mod:`.signals`) and a failed write is one error naming the output (:mod:`.write_errors`)."""
