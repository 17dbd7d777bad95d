"""Who sees what. The DEM as a Cartesian mesh (:mod:`.mesh`, walls at steep steps), the Embree
binding and first hits (:mod:`.embree`, :mod:`.raycast`), proofs that a post's ray meets the
surface nowhere (:mod:`.occluders`), each post's geometry as a camera sees it
(:mod:`.post_geometry`, the numpy reference, and :mod:`.post_geometry_kernel`, the fused numba
kernel it tests), codes carried from a DEM's posts to a finer grid (:mod:`.carry`), the choice
among these ways (:mod:`.paths`), and the epsilon rule that turns them into visibility codes
(:mod:`.visibility`)."""
