"""Vertical datums: a DEM's heights converted to the heights its cameras need.

The rule, by the cameras' world frame (:class:`~orthomvp.codes.WorldFrame`):

- ``body``: body-fixed cameras (RPCs, CSM ISDs, ISIS cubes, body-fixed or Earth-centred
  ``.tsai`` and OpenSfM cameras) want heights above the reference ellipsoid (or sphere) of the
  DEM's horizontal CRS; RPCs want heights above WGS84's, the ellipsoid of a WGS84 DEM. A DEM
  whose CRS has a vertical part (a compound CRS: "WGS84 + EGM2008 height", EGM96, a lunar or
  Martian geoid) has its heights converted by PROJ's transformation from that CRS to its
  geodetic 3D CRS, which needs the geoid's grid; without the grid this refuses (naming it and
  how to get it) instead of PROJ's "ballpark" that leaves heights unchanged.
- ``map``: cameras in the DEM's projected CRS (Orthority's format, ``.tsai`` in map
  coordinates) live in the DEM's own CRS, its vertical part included: their z is a height in
  the DEM's vertical datum (Orthority's convention when the world CRS has no vertical system of
  its own), so the DEM's heights are used as they are and no grid is needed.
- ``height_offset`` (metres) is added to the DEM's heights in place of the conversion, in either
  frame (for an RPC on orthometric heights: the local geoid undulation N, ellipsoidal =
  orthometric + N); ``vertical_datum="ignore"`` uses the heights as they are.

The undulation is evaluated by PROJ on a lattice of the DEM's posts every ``step`` posts and
interpolated bilinearly between them, ``step`` chosen by :func:`choose_step` so that the error
stays within :data:`TOLERANCE` (1 cm). Lattice nodes sit at multiples of ``step`` of the whole
DEM's posts, so every window of the DEM gets the same value at the same post. Measured on
1024 x 1024-post windows of EGM96 heights (four random windows each, against PROJ at every
post, which takes 300-380 ms): 1" posts in the Andes, step 8, 31 ms, error 1.2 mm; 1 m posts in
the Alps, step 64, 13 ms; 3" posts in the Himalaya and Indonesia, step 2, 110-140 ms, 2.3 mm;
30" posts in the Andes, step 1 (PROJ at every post).

pyproj's wheels search their own data folder only (and the user's, where ``projsync`` and
``pyproj sync`` put grids), not ``PROJ_DATA`` nor the system's PROJ folders where Debian's
``proj-data`` puts ``egm96_15.gtx``: those are added to its search path (:data:`GRID_DIRS`) when
a vertical datum is first met.
"""

from __future__ import annotations

import functools
import math
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from affine import Affine

from orthomvp.codes import WorldFrame
from orthomvp.errors import InputError
from orthomvp.geometry.crs import cheap_per_thread, is_pyproj

if TYPE_CHECKING:
    from pyproj import CRS, Transformer

VERTICAL_DATUMS = ("auto", "ignore")
"""What ``vertical_datum`` may say: convert the DEM's heights when its CRS has a vertical part
and the cameras need it (see the module docstring), or use them as they are."""

TOLERANCE = 0.01
"""Metres: the error allowed in the interpolated undulation against PROJ's own
(:func:`choose_step`)."""

COARSE = 64
"""Posts between the nodes of :func:`choose_step`'s coarse lattice, at least."""

LATTICE = 512
"""Nodes a side of :func:`choose_step`'s coarse lattice, at most."""

GRID_DIRS = ("/usr/local/share/proj", "/usr/share/proj")
"""System PROJ data folders searched for grids besides pyproj's own, ``PROJ_DATA`` (or
``PROJ_LIB``) and ``sys.prefix/share/proj``."""

Window = tuple[int, int, int, int]
"""(row0, row1, col0, col1), half-open, in posts."""


def check_options(vertical_datum: str, height_offset: float | None) -> None:
    """InputError for a ``vertical_datum`` not in :data:`VERTICAL_DATUMS`, a non-finite
    ``height_offset``, or both an offset and ``"ignore"``."""
    if vertical_datum not in VERTICAL_DATUMS:
        raise InputError(
            f"vertical datum must be one of {', '.join(VERTICAL_DATUMS)}, not {vertical_datum!r}"
        )
    if height_offset is not None:
        if isinstance(height_offset, bool) or not isinstance(height_offset, (int, float)):
            raise InputError(f"height offset must be a number of metres, got {height_offset!r}")
        if not math.isfinite(height_offset):
            raise InputError(f"height offset must be finite, got {height_offset}")
        if vertical_datum == "ignore":
            raise InputError("give a height offset or ignore the vertical datum, not both")


@dataclass(frozen=True)
class HeightOptions:
    """How a DEM's heights become the cameras' (see the module docstring): ``vertical_datum``
    one of :data:`VERTICAL_DATUMS`, ``height_offset`` metres or None; checked
    (:func:`check_options`)."""

    vertical_datum: str = "auto"
    height_offset: float | None = None

    def __post_init__(self) -> None:
        check_options(self.vertical_datum, self.height_offset)


def vertical_part(crs: object) -> CRS | None:
    """The vertical CRS of a compound CRS (a pyproj CRS, a file's as rasterio reads it, or
    anything pyproj reads); None for a CRS without one (heights above its ellipsoid)."""
    if crs is None:
        return None
    if not is_pyproj(crs):
        if hasattr(crs, "to_wkt") and not crs.to_wkt().startswith(("COMPD_CS", "COMPOUNDCRS")):
            return None  # a file's CRS that is not compound, told without pyproj
        crs = whole_crs(crs, "CRS")
    if not crs.is_compound:
        return None
    vertical = [sub for sub in crs.sub_crs_list if sub.is_vertical]
    return vertical[0] if vertical else None


def whole_crs(crs: object, name: str) -> CRS:
    """``crs`` as a pyproj CRS with its vertical part (pyproj's, a file's, or anything pyproj
    reads); InputError when pyproj cannot read it."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    if is_pyproj(crs):
        return crs  # type: ignore[return-value]
    try:
        return CRS.from_wkt(crs.to_wkt()) if hasattr(crs, "to_wkt") else CRS.from_user_input(crs)
    except CRSError as exc:
        raise InputError(f"{name}: cannot understand CRS {crs!r} ({exc})") from exc


def _search_dirs() -> list[str]:
    """Folders that may hold PROJ grids and that pyproj's wheel does not search."""
    env = os.environ.get("PROJ_DATA", os.environ.get("PROJ_LIB", ""))
    wanted = [*filter(None, env.split(os.pathsep)), str(Path(sys.prefix, "share", "proj"))]
    return [d for d in (*wanted, *GRID_DIRS) if Path(d).is_dir()]


@functools.cache
def _add_search_dirs() -> None:
    """Add :func:`_search_dirs` to pyproj's data path, once per process."""
    from pyproj import datadir

    have = datadir.get_data_dir().split(os.pathsep)
    extra = [d for d in _search_dirs() if d not in have]
    if extra:
        datadir.set_data_dir(os.pathsep.join([*have, *extra]))


def geoid_transformer(crs: CRS, name: str, target: CRS | None = None) -> Transformer:
    """PROJ's transformation from the compound CRS ``crs`` to ``target`` (default its geodetic
    3D CRS) that applies the vertical datum, never a "ballpark" one that leaves heights as
    they are (always_xy, made once per process); InputError naming the missing grid and how to
    get it, or saying PROJ knows no such transformation, ``name`` first."""
    return _transformer(crs.to_wkt(), name, None if target is None else target.to_wkt())


@functools.cache
def _transformer(wkt: str, name: str, target_wkt: str | None = None) -> Transformer:
    """:func:`geoid_transformer` of CRSs as WKT (cached by them)."""
    from pyproj import CRS
    from pyproj.transformer import TransformerGroup

    _add_search_dirs()
    crs = CRS.from_wkt(wkt)
    horizontal = crs.sub_crs_list[0]
    target = (horizontal if horizontal.is_geographic else horizontal.geodetic_crs).to_3d()
    target = target if target_wkt is None else CRS.from_wkt(target_wkt)
    with warnings.catch_warnings():  # pyproj's "best transformation is not available"
        warnings.simplefilter("ignore", UserWarning)
        group = TransformerGroup(crs, target, always_xy=True, allow_ballpark=False)
    if group.transformers:
        return cheap_per_thread(group.transformers[0])
    vertical = vertical_part(crs)
    what = f"{name}: its heights are {vertical.name!r} (a vertical datum)" if vertical else name
    to = f"heights above the {target.ellipsoid.name} ellipsoid"
    grids = [g for op in group.unavailable_operations for g in op.grids if not g.available]
    grids.sort(key=lambda g: not g.url)  # a grid PROJ can download first
    escape = "give --height-offset METRES (added to its heights) or --vertical-datum ignore"
    if grids:
        grid = grids[0].short_name
        raise InputError(
            f"{what}, and PROJ lacks the geoid grid {grid} that converts them to {to}: get it "
            f"with `projsync --file {grid}` (or `pyproj sync --file {grid}`; or let PROJ "
            f"download it, PROJ_NETWORK=ON), or {escape}"
        )
    raise InputError(f"{what}, and PROJ knows no transformation from them to {to}: {escape}")


def undulation(wkt: str, x: np.ndarray, y: np.ndarray, name: str = "DEM") -> np.ndarray:
    """What PROJ adds to a height of the compound CRS ``wkt`` at its horizontal coordinates
    ``x``, ``y`` (its units) to give the height above its ellipsoid, metres (the geoid
    undulation N); InputError where PROJ gives none (off the geoid's grid)."""
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    _, _, h = _transformer(wkt, name).transform(x, y, np.zeros(x.shape))
    h = np.asarray(h, np.float64)
    if not np.isfinite(h).all():
        raise InputError(f"{name}: PROJ gives no geoid undulation at some of its posts")
    return h


@dataclass(frozen=True)
class HeightShift:
    """Metres added to a DEM's values to give the heights its cameras need: ``offset`` plus,
    when ``wkt`` (the DEM's compound CRS) is given, the geoid undulation at each post,
    evaluated by PROJ every ``step`` posts of the DEM whose pixel-corner transform is
    ``transform`` and interpolated bilinearly (see the module docstring). Picklable: PROJ's
    transformation is made again in each process."""

    offset: float = 0.0
    wkt: str | None = None
    transform: Affine = Affine.identity()
    step: int = 1
    name: str = "DEM"

    def at(self, c: np.ndarray, r: np.ndarray) -> np.ndarray:
        """The shift (metres) at DEM pixel positions ``(c, r)`` (arrays that broadcast)."""
        c, r = np.broadcast_arrays(np.asarray(c, np.float64), np.asarray(r, np.float64))
        if self.wkt is None:
            return np.full(c.shape, self.offset)
        s = self.step
        fc, fr = c / s, r / s
        i0, j0 = np.floor(fr.min()), np.floor(fc.min())
        rows = np.arange(i0, np.floor(fr.max()) + 2)
        cols = np.arange(j0, np.floor(fc.max()) + 2)
        nodes = self._nodes(cols * s, rows * s)
        i = np.clip(np.floor(fr) - i0, 0, len(rows) - 2).astype(np.int64)
        j = np.clip(np.floor(fc) - j0, 0, len(cols) - 2).astype(np.int64)
        u, v = fc - j0 - j, fr - i0 - i
        top = nodes[i, j] + u * (nodes[i, j + 1] - nodes[i, j])
        bottom = nodes[i + 1, j] + u * (nodes[i + 1, j + 1] - nodes[i + 1, j])
        return self.offset + top + v * (bottom - top)

    def window(self, window: Window) -> np.ndarray:
        """The shift (metres) at every post of ``window`` of the DEM, (rows, cols): what
        :meth:`at` gives there (to rounding), interpolated along rows, then along columns."""
        r0, r1, c0, c1 = window
        if self.wkt is None:
            return np.full((r1 - r0, c1 - c0), self.offset)
        if self.step == 1:
            return self.offset + self._nodes(np.arange(c0, c1), np.arange(r0, r1))
        s = self.step
        rows = np.arange(r0 // s, (r1 - 1) // s + 2)
        cols = np.arange(c0 // s, (c1 - 1) // s + 2)
        nodes = self._nodes(cols * s, rows * s)
        i, v = np.divmod(np.arange(r0, r1), s)
        j, u = np.divmod(np.arange(c0, c1), s)
        i, j, v, u = i - rows[0], j - cols[0], v / s, u / s
        along = nodes[i] + v[:, None] * (nodes[i + 1] - nodes[i])  # (window rows, lattice cols)
        return self.offset + along[:, j] + u * (along[:, j + 1] - along[:, j])

    def exact(self, c: np.ndarray, r: np.ndarray) -> np.ndarray:
        """The shift at DEM pixel positions ``(c, r)`` from PROJ itself (no lattice)."""
        if self.wkt is None:
            return np.full(np.broadcast(c, r).shape, self.offset)
        x, y = (self.transform @ Affine.translation(0.5, 0.5)) @ (np.asarray(c), np.asarray(r))
        return self.offset + undulation(self.wkt, x, y, self.name)

    def _nodes(self, c: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Undulation (len(r), len(c)) at DEM posts ``c`` x ``r`` (a grid)."""
        cc, rr = np.meshgrid(c, r)
        return self.exact(cc, rr) - self.offset


def choose_step(shift: HeightShift, shape: tuple[int, int]) -> int:
    """The lattice step (posts) for a DEM of ``shape`` (rows, cols) posts: the undulation on
    a coarse lattice over the whole DEM (at most :data:`LATTICE` nodes a side, every
    :data:`COARSE` posts or more) bounds the interpolation error by its largest second
    differences (a quarter of them along rows plus along columns: a geoid grid that PROJ
    interpolates bilinearly has slope jumps on its own grid lines, where the error of a
    lattice cell that straddles one is a quarter of the jump times the cell; smooth parts do
    better), an error that falls with the step; the step is halved until it is within
    :data:`TOLERANCE`."""
    rows, cols = shape
    coarse = max(COARSE, -(-max(rows, cols) // LATTICE))
    coarse = max(1, min(coarse, min(rows, cols) // 2))  # three nodes a side at least
    nodes = shift._nodes(np.arange(0, cols + coarse, coarse), np.arange(0, rows + coarse, coarse))
    bound = sum(np.abs(np.diff(nodes, 2, axis=k)).max(initial=0.0) for k in (0, 1)) / 4
    step = coarse
    while step > 1 and bound * step / coarse > TOLERANCE:
        step //= 2
    return step


def height_shift(
    crs: object,
    transform: Affine,
    shape: tuple[int, int],
    *,
    world: WorldFrame | str,
    heights: HeightOptions = HeightOptions(),
    radius_values: bool = False,
    name: str = "DEM",
) -> HeightShift | None:
    """What to add to the heights of a DEM with CRS ``crs`` (its whole CRS, the vertical part
    included; pyproj's, a file's as rasterio reads it, or anything pyproj reads), pixel-corner
    ``transform`` and ``shape`` for cameras in ``world``, as ``heights`` says (see the module
    docstring): None when nothing, and for ``radius_values`` (distances from the body's centre,
    in no vertical datum) unless an offset is given. InputError when the conversion needs a
    grid PROJ lacks."""
    vertical_datum, height_offset = heights.vertical_datum, heights.height_offset
    if height_offset is not None:
        return HeightShift(float(height_offset), name=name) if height_offset else None
    if vertical_datum == "ignore" or radius_values or WorldFrame(world) == WorldFrame.MAP:
        return None
    vertical = vertical_part(whole_crs(crs, name))
    if vertical is None:
        return None
    wkt = whole_crs(crs, name).to_wkt()
    _transformer(wkt, name)  # refuses now, with the grid's name, when PROJ lacks it
    shift = HeightShift(0.0, wkt, transform, 1, name)
    return HeightShift(0.0, wkt, transform, choose_step(shift, shape), name)
