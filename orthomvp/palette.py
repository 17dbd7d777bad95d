"""The colours of visibility codes, shared by figures, exported meshes and 3D snapshots.

Codes as in :mod:`orthomvp.visibility`: 0 outside the image / no data, 1 visible, 2 occluded,
3 facing away. Occluded posts are green, as in the occlusion poster's figure 4.
"""

from __future__ import annotations

VIS_RGB: dict[int, tuple[int, int, int]] = {
    0: (90, 115, 190),  # outside / no data: blue
    1: (215, 215, 210),  # visible: light grey
    2: (20, 200, 40),  # occluded: green
    3: (235, 115, 30),  # facing away: orange
}
"""RGB uint8 of each visibility code."""
VIS_LABELS = ("outside / no data", "visible", "occluded", "facing away")
