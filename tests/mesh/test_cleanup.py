"""Tests of voxnero/mesh/cleanup.py: components, repairs, smoothing."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from voxnero.mesh.cleanup import clean_mesh, max_triangles_per_edge, triangle_components
from voxnero.mesh.extract import extract_mesh

BIG_C, BIG_R = np.array([0.0, 0.1, -0.1]), 0.5
SMALL_C, SMALL_R = np.array([0.75, 0.75, 0.7]), 0.12


def two_blobs(n=48):
    x = np.linspace(-1, 1, n)
    Z, Y, X = np.meshgrid(x, x, x, indexing="ij")
    P = np.stack([X, Y, Z], -1)
    d_big = np.linalg.norm(P - BIG_C, axis=-1) - BIG_R
    d_small = np.linalg.norm(P - SMALL_C, axis=-1) - SMALL_R
    return extract_mesh(np.minimum(d_big, d_small), [[-1, -1, -1], [1, 1, 1]])


def n_components(mesh) -> int:
    labels, _, _ = mesh.cluster_connected_triangles()
    return len(set(np.asarray(labels).tolist()))


def test_largest_component_removes_floating_blob():
    raw = two_blobs()
    assert n_components(raw) == 2
    m = clean_mesh(raw)
    assert n_components(m) == 1
    v = np.asarray(m.vertices)
    assert np.abs(np.linalg.norm(v - BIG_C, axis=1) - BIG_R).max() < 2e-3
    assert m.has_vertex_normals() and len(m.vertex_normals) == len(m.vertices)
    assert len(raw.triangles) > len(m.triangles)  # input untouched, output smaller


@pytest.mark.parametrize("keep, blobs", [("largest", 1), (1, 1), (2, 2), (5, 2), ("all", 2),
                                         (0.2, 1), (0.001, 2), (1.0, 1)])
def test_keep_rules(keep, blobs):
    assert n_components(clean_mesh(two_blobs(32), keep=keep)) == blobs


@pytest.mark.parametrize("keep", [0, -1, 0.0, 1.5, True, "biggest"])
def test_bad_keep(keep):
    with pytest.raises(ValueError):
        clean_mesh(two_blobs(24), keep=keep)


def test_repairs_duplicates_degenerates_and_unreferenced():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0],  # 3 duplicates 0
                  [5, 5, 5]], dtype=float)                      # 4 unreferenced
    t = np.array([[0, 1, 2], [3, 1, 2], [0, 1, 2], [0, 0, 1]])  # dup (after merge) ×2, degenerate
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
    m = clean_mesh(mesh, keep="all")
    assert len(m.vertices) == 3 and len(m.triangles) == 1
    assert np.allclose(np.asarray(m.vertex_normals), [0, 0, 1])


def test_taubin_smooths_without_shrinking():
    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=0.5, resolution=40)
    rng = np.random.default_rng(0)
    v = np.asarray(sphere.vertices)
    noisy = o3d.geometry.TriangleMesh(sphere)
    noisy.vertices = o3d.utility.Vector3dVector(v + rng.normal(0, 0.01, v.shape))
    r_noisy = np.linalg.norm(np.asarray(clean_mesh(noisy).vertices), axis=1)
    r_smooth = np.linalg.norm(np.asarray(clean_mesh(noisy, taubin_iters=10).vertices), axis=1)
    assert r_smooth.std() < 0.5 * r_noisy.std()
    assert abs(r_smooth.mean() - 0.5) < 0.01  # Taubin's λ/μ pair barely shrinks


def test_components_agree_with_open3d():
    m = two_blobs(40)
    labels, areas = triangle_components(np.asarray(m.vertices), np.asarray(m.triangles))
    ref_labels, _, ref_areas = m.cluster_connected_triangles()  # Open3D: edge-connected
    ref_labels, ref_areas = np.asarray(ref_labels), np.asarray(ref_areas)
    assert len(areas) == len(ref_areas) == 2
    # same partition (labels may be numbered differently) and the same areas
    pairs = set(zip(labels.tolist(), ref_labels.tolist(), strict=True))
    assert len(pairs) == 2
    for a, b in pairs:
        assert areas[a] == pytest.approx(ref_areas[b], rel=1e-9)
    assert areas.sum() == pytest.approx(m.get_surface_area(), rel=1e-9)


def test_non_manifold_edge_is_repaired():
    # three triangles on the edge (0, 1): a fan that no surface can have
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1.0]], dtype=float)
    t = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    assert max_triangles_per_edge(t, len(v)) == 3
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
    m = clean_mesh(mesh, keep="all")
    assert max_triangles_per_edge(np.asarray(m.triangles), len(m.vertices)) <= 2
    assert len(m.triangles) == 2
    # a closed marching-cubes surface is manifold: every edge has exactly two triangles
    closed = two_blobs(24)
    assert max_triangles_per_edge(np.asarray(closed.triangles), len(closed.vertices)) == 2


def test_empty_mesh_rejected():
    with pytest.raises(ValueError, match="no triangles"):
        clean_mesh(o3d.geometry.TriangleMesh())
