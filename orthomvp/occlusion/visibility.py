"""Per-camera visibility of DEM posts: the epsilon round-trip test.

For every post: project it into the image, back-project that pixel with the camera's own ray
(lens distortion included), find the first hit on the DEM's occluder surface (the Cartesian
DEM mesh with its steep steps made walls halfway between posts,
:func:`~orthomvp.occlusion.mesh.occluder_mesh`), map the hit back to the DEM grid, and call the post
visible when the hit lands within ``eps`` posts of the post's own grid position. Codes (uint8
raster on the DEM grid) are :class:`orthomvp.codes.Code`: 0 no data / outside the image,
1 visible, 2 occluded by terrain, 3 facing away.

Epsilon is measured in DEM posts (map distance divided by the post spacing), not as a fixed
angle: a fixed angle is stricter towards the poles and ignores the resolution. See
:func:`default_eps` for the default rule and its reasoning.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from orthomvp.camera import Camera, NullDistortion, PinholeCamera, sensor_positions
from orthomvp.codes import DOUBT, Code, WorldFrame, classify
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.terrain import Terrain, perimeter
from orthomvp.geometry.world import check_cameras_above
from orthomvp.io.preflight import check_memory, count_text
from orthomvp.occlusion.mesh import occluder_mesh
from orthomvp.occlusion.occluders import Occluders
from orthomvp.occlusion.post_geometry import (
    PostGeometry,
    general,
    image_window,
    separable,
    separable_applies,
)
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.validate import number, of_type

TILE = 512
VISIBILITY_BYTES_PER_POST = 160
"""Peak memory of the visibility test per post (its per-post results, the grid's world
points and normals, resampling temporaries; about 80 measured), bytes."""
EPS_FLOOR = 3.0
EPS_GSD_FACTOR = 1.0


def default_eps(gsd_posts: np.ndarray) -> np.ndarray:
    """The default epsilon, in DEM posts, for posts whose image ground sample distance (on a
    surface perpendicular to the line of sight) is ``gsd_posts`` DEM posts:
    ``max(EPS_FLOOR, EPS_GSD_FACTOR * gsd_posts)`` = max(3, GSD). Rays are cast on
    :func:`~orthomvp.occlusion.mesh.occluder_mesh` (:func:`occluder_caster`), not on the plain mesh.

    Reasoning. A visible post is a vertex of the mesh and the test back-projects its exact
    (sub-pixel) image position, so in exact geometry its ray comes back to it. What moves the
    hit of a visible post is the DEM's own error: small bumps within a few posts of the post
    clip a grazing ray. A truly hidden post is hidden by terrain farther away: on the synthetic
    crater 99% of hidden posts have their first hit more than 10 posts away, and on a sharp
    surface model the hit lies where the ray meets the roof, a shadow's length away. The plain
    mesh spreads a vertical wall between two posts over the whole cell, a slope that casts a
    shadow half a post short of the wall's: the posts at a wall's foot are then "visible" with
    a miss of 0 whatever the epsilon (the ``city`` scene: 2.2% of the hidden ground posts within
    3 posts of a wall got a value). The occluder surface stands every step steeper than 3:1
    (71.6 degrees; walls between 0.5 m posts are 8:1 and steeper, the crater's steepest natural
    slope at 40 m posts 2.6:1) at full height from halfway between its posts, and keeps every
    post at its own height, so no post hides behind its own raised cell. On it the city's
    wall-foot posts hit the roof edge a shadow's length away. Then 3 posts (``orthomvp
    eps-study`` on the crater with 0, 5 and 10 m of DEM noise on 40 m posts, and on the city's
    2 seeds x 4 views against exact truth): city F1 1.0000 / 1.0000 (visible / hidden) away
    from class boundaries, 0 ghosts there, 0.20% of the hidden wall-foot posts get a value
    (0.87% at 4 posts, 0.02% at 2.5); crater F1 of 'hidden' 1.0000 / 0.9967 / 0.9819 (the
    former rule: 1.0000 / 0.9961 / 0.9796; 2 posts loses 0.9771 at 10 m, 1 post 0.921). The GSD
    is that of a surface facing the camera, not the tilted surface's: divided by the cosine of
    the emission angle it grew eps to 10 GSDs on the steep cells at the foot of walls and of
    crater walls, where occluders are near (crater 0.9796 with it, 0.9830 without, at 4 posts).
    It matters only for images coarser than 3 DEM posts per pixel, where one pixel cannot
    separate a post from an occluder next to it anyway.
    """
    return np.maximum(EPS_FLOOR, EPS_GSD_FACTOR * np.asarray(gsd_posts, dtype=np.float64))


def occluder_caster(terrain: Terrain, threads: int | None = None) -> RayCaster:
    """A ray caster (on ``threads``) on the occluder surface of ``terrain``
    (:func:`~orthomvp.occlusion.mesh.occluder_mesh`), which :func:`compute_visibility` casts on (see
    :func:`default_eps`)."""
    return RayCaster(occluder_mesh(terrain), threads=threads)


@dataclass
class Visibility:
    """Visibility of one camera on a DEM grid.

    ``codes`` (rows, cols) uint8 as in the module docstring; ``uv`` (rows, cols, 2) the image
    position of every post (NaN outside); ``miss`` (rows, cols) the distance in posts from each
    post to its ray's first hit (inf where the ray found nothing, NaN where not cast);
    ``emission`` (rows, cols) degrees between the surface normal and the direction to the
    camera (NaN where the post is not in the image); ``gsd`` (rows, cols) the image's ground
    sample distance at the post in metres; ``eps`` (rows, cols) the tolerance used, in posts.
    """

    codes: np.ndarray
    uv: np.ndarray
    miss: np.ndarray
    emission: np.ndarray
    gsd: np.ndarray
    eps: np.ndarray

    def counts(self) -> dict[str, int]:
        """Number of posts per code label."""
        return {code.label: int((self.codes == code).sum()) for code in Code}


def grid_tiles(shape: tuple[int, int], tile: int) -> list[tuple[slice, slice]]:
    """(row slice, column slice) of square tiles of ``tile`` posts covering a grid."""
    rows, cols = shape
    return [
        (slice(r, min(r + tile, rows)), slice(c, min(c + tile, cols)))
        for r in range(0, rows, tile)
        for c in range(0, cols, tile)
    ]


def run_tiles(
    work: Callable[[tuple[slice, slice]], None],
    shape: tuple[int, int],
    tile: int,
    desc: str,
    progress: bool = False,
    threads: int | None = None,
) -> None:
    """Call ``work`` on every tile of a grid of ``shape`` in a thread pool (numpy, OpenCV and
    Embree release the GIL), with a progress bar over tiles when asked; in the calling thread
    when there is one thread or one tile (the engine's tiles: a pool per call cost more than
    its work on the small ones)."""
    tiles = grid_tiles(shape, tile)
    workers = min(threads or os.cpu_count() or 1, len(tiles))
    with contextlib.ExitStack() as stack:
        if workers > 1:
            done = stack.enter_context(ThreadPoolExecutor(workers)).map(work, tiles)
        else:
            done = map(work, tiles)
        if progress:
            from tqdm import tqdm

            done = tqdm(done, total=len(tiles), desc=desc, unit="tile", disable=None)
        for _ in done:
            pass


FIELDS = frozenset({"emission", "gsd", "miss"})
""":func:`compute_visibility`'s optional outputs: emission angles, GSDs, and the misses with
the epsilons they were classified with."""


def compute_visibility(
    terrain: Terrain,
    camera: Camera,
    *,
    eps: float | None = None,
    caster: Occluders | RayCaster | None = None,
    progress: bool = False,
    threads: int | None = None,
    post_scale: float = 1.0,
    occlusion: bool = True,
    spacing: float | None = None,
    strict: bool = True,
    dem: Terrain | None = None,
    fast: bool = True,
    fields: frozenset[str] | None = None,
    fused: bool = False,
    prove: bool | None = None,
) -> Visibility:
    """Classify every post of ``terrain`` for ``camera`` (whose width and height must be set).

    ``eps`` in DEM posts overrides :func:`default_eps`. ``caster`` reuses the occluder surface
    of a DEM (:class:`~orthomvp.occlusion.occluders.Occluders`, meshed at its first cast) or a ray
    caster on one (:func:`occluder_caster`); without it, the occluder surface of this terrain (or of
    ``dem``) is used. When
    ``terrain`` is a resampled output grid and ``caster`` holds the original DEM, ``post_scale``
    is the size of one grid post in DEM posts, so that eps and the reported misses stay in DEM
    posts. Work is done in tiles of posts, in parallel. With ``occlusion=False`` no ray is cast:
    posts inside the image and facing the camera are all called visible (what a naive orthophoto
    assumes), and no mesh is built. ``spacing`` is one DEM post in metres for the GSD term of
    the default eps (default: this grid's post spacing at its centre over ``post_scale``; the
    tiled engine passes the whole DEM's, so that tiles agree). ``strict=False`` returns the
    codes instead of raising GeometryError when no post is seen (a tile of a larger grid).

    ``dem``: the DEM that ``terrain`` was resampled from (whose mesh ``caster`` holds). When
    the grid's posts are finer than the DEM's (``post_scale`` < 1), the DEM posts under the
    grid are classified first, and a grid post inside the image and facing the camera whose
    four surrounding DEM posts are all visible, or all occluded, takes that code without a
    ray of its own (its ``miss`` and ``eps`` stay NaN); only posts near a class boundary (or
    next to a post facing away, outside the image or without a height) are cast. The rule
    gives the per-post result away from class boundaries (an occluder would have to fit
    between four DEM posts that all see past it) and casts every post where classes meet, so
    no ghost appears at a boundary; it makes the rays cast scale with the DEM's posts, not the
    output grid's.

    ``fast``: where it applies (a frame camera without lens distortion, the map world frame, a
    DEM in the grid's CRS), compute each post's geometry from the grid's row and column terms
    (:func:`orthomvp.occlusion.post_geometry.separable`); the codes are those of the general path
    (``fast=False``), the positions agree to the last bits of float64.

    ``fields``: which of :data:`FIELDS` (``"emission"``, ``"gsd"``, ``"miss"`` with ``eps``)
    to compute besides the codes and positions (None: all); the others come back as read-only
    NaN arrays of the grid's shape.

    ``fused``: where ``fast`` applies, compute the geometry and the first codes with the numba
    kernel of :mod:`orthomvp.occlusion.post_geometry_kernel` (the same results, bit for bit; about
    2.5x faster, after a load of about 0.3 s a process).

    ``prove`` (default: unless ``fields`` holds ``"miss"``): where ``caster`` is an
    :class:`~orthomvp.occlusion.occluders.Occluders` in the map world frame and the camera a frame
    camera without lens distortion, call a post visible without casting its ray where the DEM's
    heights prove that the ray meets the surface nowhere farther than its eps minus
    :data:`~orthomvp.codes.DOUBT` posts from the post (:meth:`Occluders.clear
    <orthomvp.occlusion.occluders.Occluders.clear>`): its code is the one the cast would give, and
    the cast's miss could not make it doubtful (:func:`orthomvp.ortho.composite.doubtful`); its
    ``miss`` and ``eps`` stay NaN. On aerial images of hilly ground about 85% of the posts are
    proved so, and a tile whose posts all are is never meshed. ``prove=False`` casts every ray
    (every miss measured, as the misses' statistics and the epsilon study need).
    """
    of_type(terrain, Terrain, "terrain")
    of_type(camera, Camera, "camera", " (orthomvp.camera.read_camera)")
    if camera.width is None or camera.height is None:
        raise InputError("the camera needs its image size (width, height) for visibility")
    if eps is not None:
        eps = number(eps, "eps (DEM posts)", minimum=0, min_open=True)
    post_scale = number(post_scale, "post_scale", minimum=0, min_open=True)
    if caster is not None:
        of_type(caster, (Occluders, RayCaster), "caster")
    rows, cols = terrain.shape
    check_memory(
        f"this grid is {count_text(float(rows) * cols)} posts ({cols:,} x {rows:,})",
        float(rows) * cols * VISIBILITY_BYTES_PER_POST,
        "use a smaller or coarser DEM",
    )
    if caster is None and occlusion:
        caster = Occluders(terrain if dem is None else dem, threads=threads)
    fields = FIELDS if fields is None else frozenset(fields)
    if not fields <= FIELDS:
        raise InputError(f"visibility fields must be among {sorted(FIELDS)}, not {sorted(fields)}")
    # rays straight from the camera centre over the occluders' own map: they can be proved
    # clear, and cast on the cells they pass over
    straight = (
        isinstance(caster, Occluders)
        and caster.provable
        and terrain.world == WorldFrame.MAP
        and caster.terrain.crs == terrain.crs
        and _pinhole_ray(camera)
    )
    proving = straight and ("miss" not in fields if prove is None else bool(prove))
    step = min(abs(terrain.S[0, 0]), abs(terrain.S[1, 1])) / post_scale  # a grid post, world
    nothing = np.broadcast_to(np.nan, (rows, cols))

    def field(name: str) -> np.ndarray:
        return np.full((rows, cols), np.nan) if name in fields else nothing

    codes = np.zeros((rows, cols), np.uint8)
    miss, eps_out = field("miss"), field("miss")
    emission, gsd = field("emission"), field("gsd")
    spacing = spacing or np.mean(terrain.post_spacing()) / post_scale  # one DEM post, metres
    carry = None
    if dem is not None and occlusion and post_scale < 1:
        of_type(dem, Terrain, "dem")
        carry = _DemCodes.of(terrain, dem, camera, eps, caster, threads, spacing, fused, prove)
    fast = (
        fast
        and separable_applies(terrain, camera)
        and (carry is None or carry.dem.crs == terrain.crs)
    )

    fused = fused and fast
    if fused:
        from orthomvp.occlusion.post_geometry_kernel import classify_tile

    def work(tile: tuple[slice, slice]) -> None:
        rs, cs = tile
        if fused:
            g, t_codes, cast = classify_tile(  # into the outputs' codes and pixels
                terrain, camera, rs, cs, occlusion=occlusion, uv=uv[rs, cs],
                codes=codes[rs, cs], **({} if carry is None else carry.kernel_args()),
            )  # fmt: skip
        else:
            g = separable(terrain, camera, rs, cs) if fast else general(terrain, camera, rs, cs)
            facing = g.cos_e > 0
            cast = g.inside & facing & occlusion
            t_codes = np.where(
                g.inside, np.where(facing, Code.VISIBLE, Code.FACING_AWAY), Code.NODATA
            ).astype(np.uint8)
            if carry is not None:  # (as a mask: a code & True would drop OCCLUDED, 2 & 1 = 0)
                known = np.where(cast, carry.at(terrain, rs, cs, g), 0).astype(np.uint8)
                t_codes[known != 0] = known[known != 0]
                cast &= known == 0
        if cast.any():  # cast the rays, from the camera's centre or each pixel's origin
            pc = g.points(cast)
            cast_eps = float(eps) if eps else default_eps(g.facing_gsd[cast] / spacing)
            dist = np.full(len(pc), np.inf)
            ray = np.ones(len(pc), bool)
            if proving:  # (a hit within the reach is within eps - DOUBT, and so is one beyond)
                reach = (cast_eps - DOUBT) * step
                ray = ~(caster.clear(pc, camera.center, reach) & (reach >= spacing))
                dist[~ray] = np.nan
            if ray.any():
                r, c = np.nonzero(cast)
                dist[ray] = _misses(
                    terrain, camera, caster, g, pc, ray, (r, c), (rs, cs), spacing, straight
                )
                dist[ray] *= post_scale
            # a ray that hits nothing has nothing in its way: the post is visible
            t_codes[cast] = classify(dist, cast_eps)
            if "miss" in fields:  # (NaN where no ray is cast)
                miss[rs, cs][cast] = dist
                eps_out[rs, cs][cast] = np.where(ray, cast_eps, np.nan)
        if not fused:
            codes[rs, cs] = t_codes
            np.copyto(uv[rs, cs], g.uv, where=g.inside[..., None])  # NaN outside the image
        if "emission" in fields:  # (arccos only inside the image: it is slow)
            cos_in = np.clip(g.cos_e[g.inside], -1, 1)
            emission[rs, cs][g.inside] = np.degrees(np.arccos(cos_in))
        if "gsd" in fields:
            t_gsd = g.facing_gsd / np.maximum(g.cos_e, 0.1)
            gsd[rs, cs] = np.where(g.inside & (g.cos_e > 0), t_gsd, np.nan)

    # posts outside the image keep NODATA and NaN: only the window that can hold the image
    r0, r1, c0, c1 = image_window(terrain, camera) if fast else (0, rows, 0, cols)
    if fused:  # the kernel writes every pixel in the window: NaN only around it
        uv = np.empty((rows, cols, 2))
        for rs, cs in _around((r0, r1, c0, c1), (rows, cols)):
            uv[rs, cs] = np.nan
    else:
        uv = np.full((rows, cols, 2), np.nan)

    def in_window(tile: tuple[slice, slice]) -> None:
        rs, cs = tile
        work((slice(rs.start + r0, rs.stop + r0), slice(cs.start + c0, cs.stop + c0)))

    if r1 > r0 and c1 > c0:
        run_tiles(in_window, (r1 - r0, c1 - c0), TILE, "visibility", progress, threads)
    if strict and not (codes != Code.NODATA).any():
        raise GeometryError(_no_overlap_reason(terrain, camera))
    if strict and not np.isin(codes, (Code.VISIBLE, Code.OCCLUDED)).any():
        raise GeometryError(
            "every post in the image faces away from the camera: it looks at the surface "
            "from below (is the camera inside the body, or the DEM upside down?)"
        )
    return Visibility(codes, uv, miss, emission, gsd, eps_out)


def _misses(
    terrain: Terrain,
    camera: Camera,
    caster: Occluders | RayCaster,
    g: PostGeometry,
    pc: np.ndarray,
    ray: np.ndarray,
    at: tuple[np.ndarray, np.ndarray],
    tile: tuple[slice, slice],
    spacing: float,
    straight: bool,
) -> np.ndarray:
    """Distance in grid posts from the posts ``ray`` of those cast (world points ``pc``, rows
    and columns ``at`` in ``tile``, geometry ``g``) to their ray's first hit; inf where the
    ray meets nothing in front of the post. ``straight``: the rays run straight from the
    camera centre over the map of ``caster``, an Occluders, which casts them on the cells
    they pass over."""
    r, c = at[0][ray], at[1][ray]
    rs, cs = tile
    pc = pc[ray]
    o = camera.center if g.origins is None else g.origins[r, c]
    if _pinhole_ray(camera):
        d = pc - o  # the pinhole's own ray through the post's pixel
    else:
        o, d = camera.ray(g.uv[r, c])  # the model's own ray through that pixel
    hits = caster.cast_from(o, pc, spacing) if straight else caster.first_hit(o, d)
    # A first hit more than one post beyond the post means that the ray slipped past the
    # post's own vertex (a crest it grazes) with nothing in front of it: no hit.
    along = np.einsum("ij,ij->i", pc - o, d) / np.linalg.norm(d, axis=1)
    front = hits.mask & (hits.distance <= along + spacing)
    dist = np.full(len(d), np.inf)
    if front.any():
        hc, hr, _ = terrain.from_world(hits.points[front])
        pcol, prow = c[front] + cs.start, r[front] + rs.start
        dist[front] = np.hypot(hc - pcol, hr - prow)
    return dist


@dataclass(frozen=True)
class _DemCodes:
    """Visibility codes of the DEM posts under a finer grid (see :func:`compute_visibility`'s
    ``dem``): ``codes`` of the DEM window whose first post is DEM post (``r0``, ``c0``)."""

    dem: Terrain
    codes: np.ndarray
    r0: int
    c0: int

    @classmethod
    def of(
        cls,
        grid: Terrain,
        dem: Terrain,
        camera: Camera,
        eps: float | None,
        caster: Occluders | RayCaster | None,
        threads: int | None,
        spacing: float,
        fused: bool,
        prove: bool,
    ) -> _DemCodes:
        """Classify the DEM posts under ``grid``, with two posts around them: the posts next
        to a grid post then have the central-difference normals of the whole DEM, so their
        codes do not depend on the window (or on how a larger grid was tiled)."""
        c, r = perimeter((0, grid.shape[0], 0, grid.shape[1]))
        dc, dr = _dem_pixels(grid, dem, c, r, grid.values[r.astype(int), c.astype(int)])
        rows, cols = dem.shape
        r0 = int(np.clip(np.floor(np.nanmin(dr, initial=np.inf)) - 2, 0, rows))
        r1 = int(np.clip(np.floor(np.nanmax(dr, initial=-np.inf)) + 4, 0, rows))
        c0 = int(np.clip(np.floor(np.nanmin(dc, initial=np.inf)) - 2, 0, cols))
        c1 = int(np.clip(np.floor(np.nanmax(dc, initial=-np.inf)) + 4, 0, cols))
        codes = np.zeros((max(r1 - r0, 0), max(c1 - c0, 0)), np.uint8)
        if min(codes.shape) >= 2:
            sub = dem.crop(r0, r1, c0, c1)
            codes = compute_visibility(
                sub, camera, eps=eps, caster=caster, threads=threads, spacing=spacing,
                strict=False, fused=fused, fields=frozenset(), prove=prove,
            ).codes  # fmt: skip
        return cls(dem, codes, r0, c0)

    def kernel_args(self) -> dict[str, object]:
        """The codes as :func:`orthomvp.occlusion.post_geometry_kernel.classify_tile` takes them."""
        return {"dem_codes": self.codes, "dem": self.dem, "dem_first": (self.r0, self.c0)}

    def at(self, grid: Terrain, rs: slice, cs: slice, g: PostGeometry) -> np.ndarray:
        """Codes carried to the grid posts of tile (``rs``, ``cs``) whose geometry is ``g``:
        VISIBLE or OCCLUDED where all four surrounding DEM posts agree on it, else 0."""
        if grid.crs == self.dem.crs:
            # neither grid is rotated (Terrain refuses it), so DEM columns follow from grid
            # columns alone and rows from rows: Terrain.pixel_to_crs and crs_to_pixel without
            # their zero terms (adding zero is exact: the same values)
            S, Si = grid.S, np.linalg.inv(self.dem.S)
            c = np.arange(cs.start, cs.stop, dtype=np.float64)[None, :]
            r = np.arange(rs.start, rs.stop, dtype=np.float64)[:, None]
            dc = Si[0, 0] * (S[0, 0] * c + S[0, 2]) + Si[0, 2]
            dr = Si[1, 1] * (S[1, 1] * r + S[1, 2]) + Si[1, 2]
        else:
            r, c = np.mgrid[rs, cs].astype(np.float64)
            dc, dr = _dem_pixels(grid, self.dem, c, r, p=g.points(np.ones(c.shape, bool)))
        rows, cols = self.codes.shape
        with np.errstate(invalid="ignore"):
            i, j = np.floor(dr) - self.r0, np.floor(dc) - self.c0
            ok = (i >= 0) & (i < rows - 1) & (j >= 0) & (j < cols - 1)
        # the four DEM posts around each grid post, gathered from the flat codes
        at = np.where(ok, i * cols + j, 0).astype(np.intp)
        flat = self.codes.ravel()
        first = flat[at]
        agree = ok & ((first == Code.VISIBLE) | (first == Code.OCCLUDED))
        for step in (1, cols, cols + 1):
            agree &= flat[at + step] == first
        return np.where(agree, first, 0).astype(np.uint8)


def _dem_pixels(
    grid: Terrain,
    dem: Terrain,
    c: np.ndarray,
    r: np.ndarray,
    values: np.ndarray | None = None,
    p: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """DEM pixel positions (c, r) of grid posts (``c``, ``r``): through the CRS when both
    grids share it, else through their world points ``p`` (or those of ``values``)."""
    if grid.crs == dem.crs:
        return dem.crs_to_pixel(*grid.pixel_to_crs(c, r))
    if p is None:
        p = grid.to_world(c, r, values)
    dc, dr, _ = dem.from_world(p)
    return dc, dr


def _around(window: tuple[int, int, int, int], shape: tuple[int, int]) -> list:
    """The (row slice, column slice) blocks of a grid of ``shape`` around ``window`` (r0, r1,
    c0, c1): the rows above and below it, and beside it the columns left and right."""
    r0, r1, c0, c1 = window
    rows, cols = shape
    return [
        (slice(0, r0), slice(0, cols)),
        (slice(r1, rows), slice(0, cols)),
        (slice(r0, r1), slice(0, c0)),
        (slice(r0, r1), slice(c1, cols)),
    ]


def _pinhole_ray(camera: Camera) -> bool:
    """Whether the ray through a post's pixel is the line from the camera centre to the post
    (a pinhole without lens distortion), so that no ray needs computing."""
    return isinstance(camera, PinholeCamera) and isinstance(camera.distortion, NullDistortion)


def _no_overlap_reason(terrain: Terrain, camera: Camera) -> str:
    """Why no post of the DEM can be seen by the camera, in one line."""
    sensor = sensor_positions(camera)
    try:
        check_cameras_above(terrain, sensor)
    except GeometryError as exc:
        return str(exc)
    c, r = terrain.grid()
    p = terrain.to_world(c, r, terrain.values)[terrain.valid]
    uv, depth = camera.project(p)
    if not (depth > 0).any():
        return "the camera looks away from the DEM: every post is behind it"
    centre = p.mean(axis=0)
    up = terrain.up_vectors(centre)
    if (np.dot(sensor - centre, up) < 0).all():
        return "the camera is below the surface of the DEM"
    return (
        f"the image ({camera.width} x {camera.height} px) does not cover the DEM: its posts "
        f"project to columns {np.nanmin(uv[..., 0]):.0f}..{np.nanmax(uv[..., 0]):.0f}, rows "
        f"{np.nanmin(uv[..., 1]):.0f}..{np.nanmax(uv[..., 1]):.0f}"
    )
