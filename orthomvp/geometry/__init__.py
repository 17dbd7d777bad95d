"""Where things are. A DEM's grid, georeference, CRS and height convention, and its posts as
body-fixed Cartesian points (:mod:`.terrain`); the world frames cameras live in (:mod:`.world`);
small vector helpers (:mod:`.vectors`)."""
