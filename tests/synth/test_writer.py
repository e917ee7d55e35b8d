"""Tests of voxnero/synth/writer.py: PLY and transforms as the dev scenes' readers expect."""

from __future__ import annotations

import json
import math

import numpy as np
import open3d as o3d

from voxnero.synth.camera_rig import fibonacci_dirs, look_at_opencv
from voxnero.synth.shapes import Sphere, Torus, Union
from voxnero.synth.writer import write_mesh, write_transforms


def test_ply_reads_back_in_open3d_exactly(tmp_path):
    v, f, n = Union([Sphere((0.1, 0.0, -0.2), 0.3), Torus(0.5, 0.1, 20.0)]).mesh_arrays()
    write_mesh(tmp_path / "m.ply", v, f, n)
    m = o3d.io.read_triangle_mesh(str(tmp_path / "m.ply"))
    assert np.array_equal(np.asarray(m.vertices), v)
    assert np.array_equal(np.asarray(m.triangles), f)
    assert m.has_vertex_normals() and np.array_equal(np.asarray(m.vertex_normals), n)


def test_transforms_hold_opengl_poses_and_intrinsics(tmp_path):
    c2w_cv = look_at_opencv(4.0 * fibonacci_dirs(5))
    write_transforms(tmp_path, "test", c2w_cv, 80, 80, 110.0)
    doc = json.loads((tmp_path / "transforms_test.json").read_text())
    gl = np.array([fr["transform_matrix"] for fr in doc["frames"]])
    assert np.allclose(gl, c2w_cv @ np.diag([1.0, -1.0, -1.0, 1.0]))
    assert doc["camera_angle_x"] == math.atan(40 / 110.0) * 2
    assert doc["frames"][4]["file_path"] == "./test/r_004"
