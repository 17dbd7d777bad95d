"""The ways through the visibility test, chosen in one place: :class:`VisibilityPath`.

:func:`~orthomvp.occlusion.visibility.compute_visibility` finds each post's code in two steps,
and each step has faster ways where they apply, with the same results:

- its geometry (world point, normal, pixel, emission cosine, GSD) and first code (outside the
  image, facing away, or a ray to resolve), :class:`Geometry`: ``GENERAL`` (numpy, any camera
  and world frame; :func:`orthomvp.occlusion.post_geometry.general`), ``SEPARABLE`` (numpy,
  from the grid's row and column terms, for a frame camera without lens distortion over a grid
  in the map world frame; :func:`~orthomvp.occlusion.post_geometry.separable`) and
  ``SEPARABLE_KERNEL`` (the same formulas in one numba kernel,
  :func:`orthomvp.occlusion.post_geometry_kernel.classify_tile`). Each numpy way is the test
  oracle of the next: ``SEPARABLE`` gives ``GENERAL``'s codes, misses, emission angles and
  GSDs to the bit and its pixels to the last bits of float64 (the projection sums its terms in
  order), ``SEPARABLE_KERNEL`` gives ``SEPARABLE``'s results bit for bit (about 2.5x faster,
  after a load of about 0.3 s a process). ``LATTICE`` serves the cameras whose
  ground-to-image is costly (RPC cameras): the camera's
  pixels, rays and GSDs interpolated (bilinear, or cubic where the camera curves) from an exact
  lattice within 0.004 pixel, checked at every cell and exact where a check fails
  (:func:`orthomvp.occlusion.post_lattice.lattice`; RPC cameras in a geocentric frame through
  the RPC's numba kernels);
  ``GENERAL`` is its oracle, and the codes agree but next to class boundaries.
- its ray, :class:`Rays`: ``WHOLE_MESH`` (cast on the whole occluder mesh of the caster),
  ``PART_MESHES`` (the rays from a camera centre over the map of an
  :class:`~orthomvp.occlusion.occluders.Occluders`, cast on meshes of only the cells they pass
  over, :meth:`~orthomvp.occlusion.occluders.Occluders.cast_from`: the same hits, but for a
  ray that grazes a vertex, which either mesh may meet or miss as float32 rounds) and
  ``PROVED`` (first proved clear where the DEM's heights allow,
  :meth:`~orthomvp.occlusion.occluders.Occluders.clear`, the others as ``PART_MESHES``: the
  same codes and doubt as casting them).

A third way to a code follows from the data rather than from a choice: on a grid finer than the
DEM it was resampled from (``dem``), codes carried from the DEM's posts
(:mod:`orthomvp.occlusion.carry`).

A :class:`VisibilityPath` says the fastest ways allowed (made once per engine plan,
:attr:`orthomvp.engine.plan.Plan.visibility_path`) and, for the tiles of a larger grid, what they
share; :meth:`VisibilityPath.resolve` turns it into the ways that apply to one grid, camera and
caster (a :class:`Resolver`, which runs each tile's two steps).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from orthomvp.camera import Camera, NullDistortion, PinholeCamera
from orthomvp.codes import DOUBT, Code, WorldFrame
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.carry import DemCodes
from orthomvp.occlusion.occluders import Occluders
from orthomvp.occlusion.post_geometry import (
    PostGeometry,
    general,
    separable,
    separable_applies,
)
from orthomvp.occlusion.post_lattice import lattice, lattice_applies
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.validate import number, of_type


class Geometry(enum.Enum):
    """How each post's geometry and first code are computed (module docstring): each numpy
    way is the test oracle of the next."""

    GENERAL = "general"
    SEPARABLE = "separable"
    SEPARABLE_KERNEL = "separable-kernel"
    LATTICE = "lattice"


class Rays(enum.Enum):
    """How a post's ray is resolved (module docstring)."""

    WHOLE_MESH = "whole-mesh"
    PART_MESHES = "part-meshes"
    PROVED = "proved"


@dataclass(frozen=True)
class VisibilityPath:
    """The fastest ways :func:`~orthomvp.occlusion.visibility.compute_visibility` may take (each
    falls back to the next slower one where it does not apply; module docstring), and what the
    tiles of a larger grid share.

    ``geometry``: a :class:`Geometry` or its value (default ``SEPARABLE``: numpy, nothing to
    load). ``rays``: a :class:`Rays` or its value; None: ``PROVED`` unless the misses are asked
    for (a proved post's ``miss`` and ``eps`` stay NaN), else ``PART_MESHES`` (every miss
    measured, as the misses' statistics and the epsilon study need). ``PROVED`` and
    ``PART_MESHES`` apply where the caster is an :class:`~orthomvp.occlusion.occluders.Occluders`
    over the grid's map (map world frame, the grid's CRS) and the camera a frame camera without
    lens distortion; elsewhere rays are cast on the whole mesh.

    For a tile of a larger grid: ``spacing`` is one DEM post in metres for the GSD term of the
    default eps, so that tiles agree (default: the grid's post spacing at its centre over its
    ``post_scale``); ``strict=False`` returns the codes instead of raising GeometryError when
    no post is seen.
    """

    geometry: Geometry = Geometry.SEPARABLE
    rays: Rays | None = None
    spacing: float | None = None
    strict: bool = True

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "geometry", Geometry(self.geometry))
            if self.rays is not None:
                object.__setattr__(self, "rays", Rays(self.rays))
        except ValueError as exc:
            raise InputError(
                f"visibility path: {exc} (geometry: {', '.join(g.value for g in Geometry)}; "
                f"rays: {', '.join(r.value for r in Rays)})"
            ) from None
        if self.spacing is not None:
            number(self.spacing, "spacing (metres)", minimum=0, min_open=True)
        of_type(self.strict, bool, "strict")

    def resolve(
        self,
        terrain: Terrain,
        camera: Camera,
        caster: Occluders | RayCaster | None,
        *,
        fields: frozenset[str],
        carry_from: Terrain | None,
        spacing: float,
        step: float,
    ) -> Resolver:
        """The ways that apply to ``terrain`` seen by ``camera`` with rays cast by ``caster``,
        outputs ``fields`` (of :data:`~orthomvp.occlusion.visibility.FIELDS`), codes carried
        from the DEM ``carry_from`` (or None); ``spacing`` one DEM post in metres, ``step``
        one DEM post in world units."""
        geometry = self.geometry
        if geometry is not Geometry.GENERAL and lattice_applies(terrain, camera):
            geometry = Geometry.LATTICE  # (whatever faster way is allowed: none serves these)
        elif (
            geometry is Geometry.LATTICE
            or not separable_applies(terrain, camera)
            or (carry_from is not None and carry_from.crs != terrain.crs)
        ):
            geometry = Geometry.GENERAL
        # rays straight from the camera centre over the occluders' own map: they can be
        # proved clear, and cast on the cells they pass over
        straight = (
            isinstance(caster, Occluders)
            and caster.provable
            and terrain.world == WorldFrame.MAP
            and caster.terrain.crs == terrain.crs
            and pinhole_ray(camera)
        )
        rays = self.rays or (Rays.PART_MESHES if "miss" in fields else Rays.PROVED)
        if not straight:
            rays = Rays.WHOLE_MESH
        return Resolver(geometry, rays, terrain, camera, caster, spacing, step)


@dataclass(frozen=True, eq=False)
class Resolver:
    """The ways (``geometry``, ``rays``) that apply to grid ``terrain`` seen by ``camera`` with
    rays cast by ``caster`` (:meth:`VisibilityPath.resolve`), and each tile's two steps:
    :meth:`first_codes`, then :meth:`misses` for the posts left. ``spacing``: one DEM post in
    metres; ``step``: one DEM post in world units."""

    geometry: Geometry
    rays: Rays
    terrain: Terrain
    camera: Camera
    caster: Occluders | RayCaster | None
    spacing: float
    step: float

    def first_codes(
        self,
        tile: tuple[slice, slice],
        *,
        occlusion: bool,
        carry: DemCodes | None,
        codes: np.ndarray,
        uv: np.ndarray,
    ) -> tuple[PostGeometry, np.ndarray, np.ndarray]:
        """The geometry of the posts of ``tile`` (row slice, column slice), their first codes
        written into ``codes`` (the grid's uint8 codes; NODATA outside the image, FACING_AWAY,
        VISIBLE, or the codes ``carry`` gives) and their pixels into ``uv`` (the grid's (rows,
        cols, 2), where inside the image), and where rays are still to resolve (bool; none
        without ``occlusion``). Returns the geometry, the tile's view of ``codes`` and that
        mask."""
        rs, cs = tile
        terrain, camera = self.terrain, self.camera
        if self.geometry is Geometry.SEPARABLE_KERNEL:
            from orthomvp.occlusion.post_geometry_kernel import classify_tile

            return classify_tile(  # into the outputs' codes and pixels
                terrain, camera, rs, cs, occlusion=occlusion, uv=uv[rs, cs],
                codes=codes[rs, cs], **({} if carry is None else carry.kernel_args()),
            )  # fmt: skip
        if self.geometry is Geometry.SEPARABLE:
            g = separable(terrain, camera, rs, cs)
        elif self.geometry is Geometry.LATTICE:
            g = lattice(terrain, camera, rs, cs)
        else:
            g = general(terrain, camera, rs, cs)
        facing = g.cos_e > 0
        cast = g.inside & facing & occlusion
        t_codes = np.where(
            g.inside, np.where(facing, Code.VISIBLE, Code.FACING_AWAY), Code.NODATA
        ).astype(np.uint8)
        if carry is not None:  # (as a mask: a code & True would drop OCCLUDED, 2 & 1 = 0)
            known = np.where(cast, carry.at(terrain, rs, cs, g), 0).astype(np.uint8)
            t_codes[known != 0] = known[known != 0]
            cast &= known == 0
        codes[rs, cs] = t_codes
        np.copyto(uv[rs, cs], g.uv, where=g.inside[..., None])  # NaN outside the image
        return g, codes[rs, cs], cast

    def misses(
        self,
        g: PostGeometry,
        cast: np.ndarray,
        tile: tuple[slice, slice],
        eps: float | np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The rays of the posts ``cast`` (rows, cols) of ``tile`` (geometry ``g``, epsilons
        ``eps`` in DEM posts): the distance in grid posts from each to its ray's first hit (inf
        where the ray meets nothing in front of the post, NaN where proved clear) and where a
        ray was cast (bool)."""
        pc = g.points(cast)
        dist = np.full(len(pc), np.inf)
        ray = np.ones(len(pc), bool)
        if self.rays is Rays.PROVED:  # (a hit within the reach is within eps - DOUBT, and so
            # is one beyond)
            reach = (eps - DOUBT) * self.step
            ray = ~(self.caster.clear(pc, self.camera.center, reach) & (reach >= self.spacing))
            dist[~ray] = np.nan
        if ray.any():
            dist[ray] = self._first_hits(g, pc, ray, np.nonzero(cast), tile)
        return dist, ray

    def _first_hits(
        self,
        g: PostGeometry,
        pc: np.ndarray,
        ray: np.ndarray,
        at: tuple[np.ndarray, np.ndarray],
        tile: tuple[slice, slice],
    ) -> np.ndarray:
        """Distance in grid posts from the posts ``ray`` of those cast (world points ``pc``,
        rows and columns ``at`` in ``tile``, geometry ``g``) to their ray's first hit; inf
        where the ray meets nothing in front of the post."""
        camera, spacing = self.camera, self.spacing
        r, c = at[0][ray], at[1][ray]
        rs, cs = tile
        pc = pc[ray]
        o = camera.center if g.origins is None else g.origins[r, c]
        if pinhole_ray(camera):
            d = pc - o  # the pinhole's own ray through the post's pixel
        elif g.directions is not None:  # the model's own ray, with the geometry
            d = g.directions[r, c]
        else:
            o, d = camera.ray(g.uv[r, c])  # the model's own ray through that pixel
        if self.rays is Rays.WHOLE_MESH:
            hits = self.caster.first_hit(o, d, invalid="miss")
        else:
            hits = self.caster.cast_from(o, pc, spacing)
        # A first hit more than one post beyond the post means that the ray slipped past the
        # post's own vertex (a crest it grazes) with nothing in front of it: no hit.
        along = np.einsum("ij,ij->i", pc - o, d) / np.linalg.norm(d, axis=1)
        front = hits.mask & (hits.distance <= along + spacing)
        dist = np.full(len(d), np.inf)
        if front.any():
            hc, hr, _ = self.terrain.from_world(hits.points[front])
            pcol, prow = c[front] + cs.start, r[front] + rs.start
            dist[front] = np.hypot(hc - pcol, hr - prow)
        return dist


def pinhole_ray(camera: Camera) -> bool:
    """Whether the ray through a post's pixel is the line from the camera centre to the post
    (a pinhole without lens distortion), so that no ray needs computing."""
    return isinstance(camera, PinholeCamera) and isinstance(camera.distortion, NullDistortion)
