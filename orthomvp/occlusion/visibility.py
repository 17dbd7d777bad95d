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
from dataclasses import dataclass, replace

import numpy as np

from orthomvp.camera import Camera, sensor_positions
from orthomvp.codes import Code, classify
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.world import check_cameras_above
from orthomvp.io.preflight import check_memory, count_text
from orthomvp.occlusion.carry import DemCodes, dem_window
from orthomvp.occlusion.mesh import occluder_mesh
from orthomvp.occlusion.occluders import Occluders
from orthomvp.occlusion.paths import Geometry, VisibilityPath
from orthomvp.occlusion.post_geometry import image_window
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


CHECK_POSTS = 25
"""Posts whose image positions :func:`check_visibility_of` compares with a fresh projection."""
CHECK_PIXELS = 0.5
"""Largest difference, in pixels, between a given visibility's image position of a post and
the camera's own projection of it: the positions of another camera or another DEM miss by
far more (the same ones agree to rounding)."""


def check_visibility_of(visibility: Visibility, terrain: Terrain, camera: Camera) -> None:
    """InputError unless ``visibility`` was computed for ``terrain``'s grid (its shape) and
    ``camera`` on these heights: the image positions of up to :data:`CHECK_POSTS` posts, spread
    over those it holds, must be the camera's projections of the posts within
    :data:`CHECK_PIXELS`. Catches a visibility of another camera, DEM or grid."""
    if visibility.codes.shape != terrain.shape or visibility.uv.shape != (*terrain.shape, 2):
        raise InputError(
            f"visibility is of a {visibility.codes.shape[0]} x {visibility.codes.shape[1]} grid, "
            f"the terrain is {terrain.shape[0]} x {terrain.shape[1]}: give the visibility of "
            "this terrain and camera"
        )
    held = np.flatnonzero(np.isfinite(visibility.uv).all(axis=-1) & terrain.valid)
    if not held.size:
        return
    pick = held[np.linspace(0, held.size - 1, min(CHECK_POSTS, held.size)).astype(np.int64)]
    r, c = np.unravel_index(pick, terrain.shape)
    p = terrain.to_world(c.astype(np.float64), r.astype(np.float64), terrain.values[r, c])
    uv, _ = camera.project(p)
    given = visibility.uv[r, c]
    off = np.linalg.norm(uv - given, axis=-1)
    worst = int(np.argmax(np.where(np.isfinite(off), off, np.inf)))
    if not off[worst] <= CHECK_PIXELS:
        raise InputError(
            f"visibility is not of this camera and terrain: at post (row {r[worst]}, column "
            f"{c[worst]}) it holds the image position ({given[worst, 0]:.1f}, "
            f"{given[worst, 1]:.1f}), the camera projects the post to ({uv[worst, 0]:.1f}, "
            f"{uv[worst, 1]:.1f}); give the visibility computed for them, or none"
        )


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
    occlusion: bool = True,
    fields: frozenset[str] | None = None,
    dem: Terrain | None = None,
    post_scale: float = 1.0,
    progress: bool = False,
    threads: int | None = None,
    path: VisibilityPath | None = None,
) -> Visibility:
    """Classify every post of ``terrain`` for ``camera`` (whose width and height must be set).

    ``eps`` in DEM posts overrides :func:`default_eps`. ``caster`` reuses the occluder surface
    of a DEM (:class:`~orthomvp.occlusion.occluders.Occluders`, meshed at its first cast) or a ray
    caster on one (:func:`occluder_caster`); without it, the occluder surface of this terrain (or of
    ``dem``) is used. With ``occlusion=False`` no ray is cast: posts inside the image and facing
    the camera are all called visible (what a naive orthophoto assumes), and no mesh is built.
    ``fields``: which of :data:`FIELDS` (``"emission"``, ``"gsd"``, ``"miss"`` with ``eps``) to
    compute besides the codes and positions (None: all); the others come back as read-only NaN
    arrays of the grid's shape. Work is done in tiles of posts, in parallel on ``threads``.

    When ``terrain`` is an output grid resampled from the DEM ``dem`` (whose occluder surface
    ``caster`` holds), ``post_scale`` is the size of one grid post in DEM posts, so that eps and
    the reported misses stay in DEM posts. When the grid's posts are finer than the DEM's
    (``post_scale`` < 1), the DEM posts under the grid are classified first, and a grid post
    inside the image and facing the camera whose four surrounding DEM posts are all visible, or
    all occluded, takes that code without a ray of its own (its ``miss`` and ``eps`` stay NaN;
    :mod:`orthomvp.occlusion.carry`); only posts near a class boundary (or next to a post facing
    away, outside the image or without a height) are cast. The rule gives the per-post result
    away from class boundaries (an occluder would have to fit between four DEM posts that all
    see past it) and casts every post where classes meet, so no ghost appears at a boundary; it
    makes the rays cast scale with the DEM's posts, not the output grid's.

    ``path``: the fastest ways allowed to compute each post's geometry and resolve its ray, and
    what the tiles of a larger grid share (:class:`~orthomvp.occlusion.paths.VisibilityPath`;
    default: the numpy separable geometry where it applies, rays proved clear unless ``fields``
    holds ``"miss"``). Every way gives the same codes.
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
    if dem is not None:
        of_type(dem, Terrain, "dem")
    path = VisibilityPath() if path is None else of_type(path, VisibilityPath, "path")
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
    step = min(abs(terrain.S[0, 0]), abs(terrain.S[1, 1])) / post_scale  # a DEM post, world
    spacing = path.spacing or np.mean(terrain.post_spacing()) / post_scale  # a DEM post, metres
    carrying = dem is not None and occlusion and post_scale < 1
    resolver = path.resolve(
        terrain, camera, caster, fields=fields, carry_from=dem if carrying else None,
        spacing=spacing, step=step,
    )  # fmt: skip
    nothing = np.broadcast_to(np.nan, (rows, cols))

    def field(name: str) -> np.ndarray:
        return np.full((rows, cols), np.nan) if name in fields else nothing

    codes = np.zeros((rows, cols), np.uint8)
    miss, eps_out = field("miss"), field("miss")
    emission, gsd = field("emission"), field("gsd")
    carry = None
    if carrying:
        carry = _dem_codes(terrain, dem, camera, eps, caster, threads, path, spacing)

    def work(tile: tuple[slice, slice]) -> None:
        g, t_codes, cast = resolver.first_codes(
            tile, occlusion=occlusion, carry=carry, codes=codes, uv=uv
        )
        rs, cs = tile
        if cast.any():  # cast the rays, from the camera's centre or each pixel's origin
            cast_eps = float(eps) if eps else default_eps(g.facing_gsd[cast] / spacing)
            dist, ray = resolver.misses(g, cast, tile, cast_eps)
            dist[ray] *= post_scale
            # a ray that hits nothing has nothing in its way: the post is visible
            t_codes[cast] = classify(dist, cast_eps)
            if "miss" in fields:  # (NaN where no ray is cast)
                miss[rs, cs][cast] = dist
                eps_out[rs, cs][cast] = np.where(ray, cast_eps, np.nan)
        if "emission" in fields:  # (arccos only inside the image: it is slow)
            cos_in = np.clip(g.cos_e[g.inside], -1, 1)
            emission[rs, cs][g.inside] = np.degrees(np.arccos(cos_in))
        if "gsd" in fields:
            t_gsd = g.facing_gsd / np.maximum(g.cos_e, 0.1)
            gsd[rs, cs] = np.where(g.inside & (g.cos_e > 0), t_gsd, np.nan)

    # posts outside the image keep NODATA and NaN: only the window that can hold the image
    separable = resolver.geometry in (Geometry.SEPARABLE, Geometry.SEPARABLE_KERNEL)
    r0, r1, c0, c1 = image_window(terrain, camera) if separable else (0, rows, 0, cols)
    if resolver.geometry is Geometry.SEPARABLE_KERNEL:  # it writes every pixel in the window:
        uv = np.empty((rows, cols, 2))  # NaN only around it
        for rs, cs in _around((r0, r1, c0, c1), (rows, cols)):
            uv[rs, cs] = np.nan
    else:
        uv = np.full((rows, cols, 2), np.nan)

    def in_window(tile: tuple[slice, slice]) -> None:
        rs, cs = tile
        work((slice(rs.start + r0, rs.stop + r0), slice(cs.start + c0, cs.stop + c0)))

    if r1 > r0 and c1 > c0:
        run_tiles(in_window, (r1 - r0, c1 - c0), TILE, "visibility", progress, threads)
    if path.strict and not (codes != Code.NODATA).any():
        raise GeometryError(_no_overlap_reason(terrain, camera))
    if path.strict and not np.isin(codes, (Code.VISIBLE, Code.OCCLUDED)).any():
        raise GeometryError(
            "every post in the image faces away from the camera: it looks at the surface "
            "from below (is the camera inside the body, or the DEM upside down?)"
        )
    return Visibility(codes, uv, miss, emission, gsd, eps_out)


def _dem_codes(
    grid: Terrain,
    dem: Terrain,
    camera: Camera,
    eps: float | None,
    caster: Occluders | RayCaster | None,
    threads: int | None,
    path: VisibilityPath,
    spacing: float,
) -> DemCodes:
    """The codes of the DEM posts under ``grid`` (:func:`~orthomvp.occlusion.carry.dem_window`),
    on ``path`` with the grid's ``spacing``, as :func:`compute_visibility` carries them."""
    r0, r1, c0, c1 = dem_window(grid, dem)
    codes = np.zeros((max(r1 - r0, 0), max(c1 - c0, 0)), np.uint8)
    if min(codes.shape) >= 2:
        codes = compute_visibility(
            dem.crop(r0, r1, c0, c1), camera, eps=eps, caster=caster, threads=threads,
            fields=frozenset(), path=replace(path, spacing=spacing, strict=False),
        ).codes  # fmt: skip
    return DemCodes(dem, codes, r0, c0)


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
