"""The choice of path through the visibility test (:mod:`orthomvp.occlusion.paths`): what each
:class:`VisibilityPath` resolves to where its faster ways do not apply, and that the engine makes
one per plan and hands that one to every tile. That every path gives the same results is tested
beside each fast way and its oracle (test_post_geometry, test_occluders, test_carry)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pyproj import CRS

from orthomvp.camera.distortion import TsaiDistortion
from orthomvp.codes import WorldFrame
from orthomvp.engine import Outputs, plan_ortho, run_plan
from orthomvp.engine.check import run_check
from orthomvp.engine.check_plan import plan_check
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.mesh import occluder_mesh
from orthomvp.occlusion.occluders import Occluders
from orthomvp.occlusion.paths import Geometry, Rays, VisibilityPath
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.ortho.composite import MosaicOptions
from orthomvp.synthetic import make_scene
from tests.test_occluders import camera_at, map_terrain, rough

FAST = VisibilityPath(geometry=Geometry.SEPARABLE_KERNEL, rays=Rays.PROVED)


def _resolve(path: VisibilityPath, terrain, camera, caster, fields=frozenset(), dem=None):  # noqa: ANN001, ANN202
    return path.resolve(
        terrain, camera, caster, fields=fields, carry_from=dem, spacing=2.0, step=2.0
    )


def test_the_fastest_ways_apply_only_where_they_can() -> None:
    """Map frame, frame camera without distortion, an Occluders on the grid's map: the fastest
    ways; a lens, a body-fixed grid, a DEM in another CRS each fall back to the general
    geometry, and a plain ray caster or a lens to the whole mesh; by default rays are proved
    unless the misses are asked for."""
    t = map_terrain(rough(2, (30, 40)))
    cam = camera_at(t, 60.0, 20.0)
    occluders = Occluders(t)
    got = _resolve(FAST, t, cam, occluders)
    assert (got.geometry, got.rays) == (Geometry.SEPARABLE_KERNEL, Rays.PROVED)
    bent = replace(cam, distortion=TsaiDistortion(k1=1e-3, k2=0.0, p1=0.0, p2=0.0))
    got = _resolve(FAST, t, bent, occluders)
    assert (got.geometry, got.rays) == (Geometry.GENERAL, Rays.WHOLE_MESH)
    got = _resolve(FAST, t, cam, RayCaster(occluder_mesh(t)))
    assert (got.geometry, got.rays) == (Geometry.SEPARABLE_KERNEL, Rays.WHOLE_MESH)
    crater = make_scene("crater", size=16, spacing=80.0)
    body = crater.terrain  # body-fixed: heights not along z, nothing proved
    got = _resolve(FAST, body, crater.cameras["nadir"], Occluders(body))
    assert (got.geometry, got.rays) == (Geometry.GENERAL, Rays.WHOLE_MESH)
    elsewhere = Terrain(t.values, t.transform, CRS.from_epsg(32634), world=WorldFrame.MAP)
    got = _resolve(FAST, t, cam, occluders, dem=elsewhere)  # codes carried from it
    assert (got.geometry, got.rays) == (Geometry.GENERAL, Rays.PROVED)
    got = _resolve(FAST, t, cam, Occluders(elsewhere))  # rays over another map
    assert (got.geometry, got.rays) == (Geometry.SEPARABLE_KERNEL, Rays.WHOLE_MESH)
    default = VisibilityPath()
    assert _resolve(default, t, cam, occluders).rays is Rays.PROVED
    assert _resolve(default, t, cam, occluders, frozenset({"miss"})).rays is Rays.PART_MESHES
    assert _resolve(default, t, cam, occluders).geometry is Geometry.SEPARABLE


def test_a_path_refuses_what_it_does_not_know() -> None:
    assert VisibilityPath(geometry="general", rays="whole-mesh") == VisibilityPath(
        geometry=Geometry.GENERAL, rays=Rays.WHOLE_MESH
    )
    for kw, words in (
        ({"geometry": "fast"}, "'fast' is not a valid Geometry"),
        ({"rays": "cast"}, "'cast' is not a valid Rays"),
        ({"spacing": 0.0}, "spacing (metres)"),
        ({"strict": 0}, "strict must be a bool"),
    ):
        with pytest.raises(InputError) as info:
            VisibilityPath(**kw)
        assert words in str(info.value)
    t = map_terrain(rough(2, (30, 40)))
    with pytest.raises(InputError, match="path must be a VisibilityPath"):
        compute_visibility(t, camera_at(t, 60.0, 20.0), path="kernel")


@pytest.mark.parametrize("kind", ["ortho", "mosaic", "check"])
def test_the_engine_hands_one_path_per_plan_to_every_tile(
    kind: str, city_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every tile's visibility runs on the plan's own path (the same object; a mosaic's plan
    is surveyed into a new one before it runs): for an
    orthophoto and a mosaic rays proved clear (the mosaic's geometry by the kernel when it runs
    the kernels), for the check every ray on the whole mesh."""
    import orthomvp.engine.plan as plan_module
    import orthomvp.engine.tile as tile_module

    paths = []
    original = tile_module.compute_visibility

    def recording(*args: object, **kw: object) -> object:
        paths.append(kw["path"])
        return original(*args, **kw)

    monkeypatch.setattr(tile_module, "compute_visibility", recording)
    summary = json.loads((city_dir / "scene.json").read_text())
    views = [(city_dir / v["image"], city_dir / v["camera"]) for v in summary["views"].values()]
    dem = city_dir / summary["dem"]
    if kind == "check":
        plan = plan_check(dem, views, tile=32, progress=False)
        run_check(plan, threads=1, progress=False)
        want = VisibilityPath(rays=Rays.WHOLE_MESH, spacing=plan.base.spacing, strict=False)
    else:
        mosaic = MosaicOptions() if kind == "mosaic" else None
        monkeypatch.setattr(plan_module, "FUSED_POSTS", 1)  # a mosaic runs the kernels
        plan = plan_ortho(dem, views[: 4 if mosaic else 1], tile=32, progress=False, mosaic=mosaic)
        run_plan(plan, Outputs(ortho=tmp_path / "o.tif"), threads=1, progress=False)
        geometry = Geometry.SEPARABLE_KERNEL if mosaic else Geometry.SEPARABLE
        want = VisibilityPath(geometry, Rays.PROVED, spacing=plan.spacing, strict=False)
    assert plan.visibility_path == want
    assert len(paths) >= 4 and all(p == want for p in paths)
    if kind == "mosaic":  # (run on the plan surveyed for its blend width, and on a coarse one)
        assert len({id(p) for p in paths}) <= 2
    else:
        assert all(p is plan.visibility_path for p in paths)
    assert np.isfinite(plan.visibility_path.spacing)
