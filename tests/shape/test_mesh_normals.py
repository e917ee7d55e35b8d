"""The stage-1 mesh's vertex normals are the SDF field's (voxnero.shape.run_files.extract)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from voxnero.shape.config import ShapeConfig
from voxnero.shape.renderer import ShapeModel, Switches
from voxnero.shape.run_files import extract


def _angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), (a * b).sum(1)))


@pytest.mark.parametrize("res", [32, 48])
def test_field_normals_of_a_sphere_grid_beat_the_triangles(res):
    """The initial grid is a sphere's SDF: the true normal at a vertex is radial. The field's
    central differences must be within 0.3° on average (a sphere's SDF is smooth across cells)
    and nearer the truth than the marching-cubes triangles' area-weighted normals, which the
    mesh carried before."""
    model = ShapeModel(ShapeConfig(), Switches(indirect=False, occlusion=False), res=res)
    mesh = extract(model, 2 * res)
    v = np.asarray(mesh.vertices)
    ours = _angles_deg(np.asarray(mesh.vertex_normals), v)
    tri = o3d.geometry.TriangleMesh(mesh)
    tri.compute_vertex_normals()
    theirs = _angles_deg(np.asarray(tri.vertex_normals), v)
    assert ours.mean() < 0.3, ours.mean()
    assert ours.mean() < theirs.mean(), (ours.mean(), theirs.mean())
