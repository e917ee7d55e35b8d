"""Tests of voxnero/eval/views.py: masks, batched rays, ray-cast results."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from voxnero.cameras.rays import image_rays
from voxnero.eval.views import MeshCaster, full_coverage, iter_view_rays, partial_coverage


def test_coverage_from_8bit_and_fraction_masks():
    m8 = np.array([[0, 1, 128, 254, 255]], dtype=np.uint8)
    assert full_coverage(m8).tolist() == [[False, False, False, False, True]]
    assert partial_coverage(m8).tolist() == [[False, True, True, True, False]]
    frac = torch.from_numpy(m8.astype(np.float32) / 255)  # what voxnero.data loads
    assert (full_coverage(frac) == full_coverage(m8)).all()
    assert (partial_coverage(frac) == partial_coverage(m8)).all()


def test_batched_rays_equal_per_view_rays(geo):
    cams = geo.ring_cameras(5, size=24)
    seen = []
    for v, o, d, fwd in iter_view_rays(cams, max_rays=2 * 24 * 24):  # batches of 2 views
        o_ref, d_ref = image_rays(cams, v)
        assert np.allclose(o, o_ref.numpy(), atol=1e-6) and np.allclose(d, d_ref.numpy(), atol=1e-6)
        # the ray through the image centre is the viewing axis (24 px: between 4 pixel centres)
        centre = d[11:13, 11:13].mean((0, 1))
        assert np.allclose(centre / np.linalg.norm(centre), fwd, atol=1e-6)
        seen.append(v)
    assert seen == [0, 1, 2, 3, 4]


def test_barycentric_convention_reproduces_hit_points(geo):
    cams = geo.ring_cameras(1, size=64)
    mesh = geo.icosphere(np.array([0.05, -0.1, 0.08]), 0.5, 3)
    caster = MeshCaster(mesh)
    _, o, d, _ = next(iter_view_rays(cams))
    res = caster.cast(o, d)
    hit = np.isfinite(res["t"])
    assert 0.05 < hit.mean() < 0.5
    tri = np.asarray(mesh.triangles)[res["tri"][hit]]
    v = np.asarray(mesh.vertices)
    u, w = res["uv"][hit][:, :1], res["uv"][hit][:, 1:]
    p_bary = (1 - u - w) * v[tri[:, 0]] + u * v[tri[:, 1]] + w * v[tri[:, 2]]
    p_ray = o[hit] + d[hit] * res["t"][hit][:, None]
    assert np.abs(p_bary - p_ray).max() < 1e-5
    assert (res["tri"][~hit] == -1).all()
    # face normals face the camera on a closed outward mesh
    assert (np.einsum("ij,ij->i", res["face_normal"][hit], d[hit]) < 0).all()


def test_empty_mesh_rejected():
    import open3d as o3d

    with pytest.raises(ValueError, match="no triangles"):
        MeshCaster(o3d.geometry.TriangleMesh())
