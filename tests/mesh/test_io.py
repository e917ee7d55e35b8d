"""Tests of voxnero/mesh/io.py: round trips through a non-trivial normalisation."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from voxnero.data.scene import Normalisation
from voxnero.errors import DataError
from voxnero.mesh.io import load_mesh, save_mesh

NORM = Normalisation(center=np.array([1.5, -2.0, 0.25]), scale=3.7)


def unit_mesh():
    m = o3d.geometry.TriangleMesh.create_torus(torus_radius=0.6, tube_radius=0.2)
    m.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0.3, -0.2, 0.5)), center=(0, 0, 0))
    m.compute_vertex_normals()
    return m


def test_round_trip_through_normalisation(tmp_path):
    m = unit_mesh()
    v = np.asarray(m.vertices).copy()
    p = save_mesh(tmp_path / "sub" / "mesh.ply", m, norm=NORM)
    raw = o3d.io.read_triangle_mesh(str(p))  # what other tools see: the input frame
    assert np.allclose(np.asarray(raw.vertices), v * 3.7 + np.array([1.5, -2.0, 0.25]), atol=1e-6)
    assert np.array_equal(np.asarray(raw.triangles), np.asarray(m.triangles))
    assert np.allclose(np.asarray(raw.vertex_normals), np.asarray(m.vertex_normals), atol=1e-6)
    back = load_mesh(p, norm=NORM)
    assert np.allclose(np.asarray(back.vertices), v, atol=1e-6)
    assert np.allclose(np.asarray(m.vertices), v)  # input not modified
    same = load_mesh(p)  # no norm: input frame unchanged
    assert np.allclose(np.asarray(same.vertices), np.asarray(raw.vertices))


def test_save_computes_missing_normals_and_obj(tmp_path):
    m = unit_mesh()
    m.vertex_normals = o3d.utility.Vector3dVector()
    p = save_mesh(tmp_path / "m.obj", m)
    back = load_mesh(p)
    assert back.has_vertex_normals() and len(back.triangles) == len(m.triangles)


def test_errors(tmp_path):
    with pytest.raises(DataError, match="not found"):
        load_mesh(tmp_path / "missing.ply")
    with pytest.raises(DataError, match="unsupported mesh file type"):
        save_mesh(tmp_path / "m.xyz", unit_mesh())
    bad = tmp_path / "bad.ply"
    bad.write_text("not a ply file\n")
    with pytest.raises(DataError, match="no triangles"):
        load_mesh(bad)
