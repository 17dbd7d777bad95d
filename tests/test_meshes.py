"""The reference shape models in meshes/ still match the scenes they were made from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from orthomvp.synth import make_scene

MESHES = Path(__file__).resolve().parents[1] / "meshes"


def test_crater_truth_matches_the_analytic_scene() -> None:
    mesh = trimesh.load(MESHES / "crater-truth.ply", process=False)
    assert len(mesh.vertices) == 96 * 96 and len(mesh.faces) == 2 * 95 * 95
    scene = make_scene("crater", size=96, spacing=50.0)
    world = scene.terrain.world_points().reshape(-1, 3)
    origin = np.array([1557054.143, 97936.496, 764328.194])
    # PLY stores float32 local coordinates: a few millimetres at kilometre offsets
    np.testing.assert_allclose(mesh.vertices + origin, world, atol=0.01)
    colours = mesh.visual.vertex_colors[:, :3].astype(float)
    assert colours.std() > 20  # the radiance texture is there
