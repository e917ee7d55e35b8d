"""Tests of voxnero/synth/shapes.py: exact intersections, normals, SDFs and GT meshes.

Independent references: float64 numpy quadratic/quartic root solving (``numpy.roots``) for the
ray parameters, central finite differences of the SDF for normals, Open3D distance queries for
the meshes.
"""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.synth.shapes import HIT_EPS, Sphere, Torus, Union, tilt_matrix


def _rays(n: int, seed: int, dist: float = 4.0, spread: float = 1.0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    o = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=-1)
    o = o * dist
    target = (torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 1) * spread
    d = torch.nn.functional.normalize(target - o, dim=-1)
    return o.to(dtype), d.to(dtype)


def _torus_roots(o: np.ndarray, d: np.ndarray, torus: Torus) -> float:
    """Smallest positive real root of the torus quartic along one ray (float64, numpy.roots)."""
    rot = tilt_matrix(torus.tilt_deg)
    p, q = rot.T @ o, rot.T @ d
    R, r = torus.major_radius, torus.minor_radius
    # (|p + t q|² + R² − r²)² − 4R²((px + t qx)² + (py + t qy)²) = 0, |q| = 1
    b = 2 * p @ q
    c = p @ p + R * R - r * r
    coeffs = np.polysub(np.polymul([1.0, b, c], [1.0, b, c]),
                        4 * R * R * np.array([q[0] ** 2 + q[1] ** 2,
                                              2 * (p[0] * q[0] + p[1] * q[1]),
                                              p[0] ** 2 + p[1] ** 2]))
    roots = np.roots(coeffs)
    real = roots[(np.abs(roots.imag) < 1e-7) & (roots.real > 0)].real
    return float(real.min()) if real.size else math.inf


def test_sphere_intersection_matches_quadratic():
    s = Sphere((0.1, -0.2, 0.05), 0.7)
    o, d = _rays(2000, 0)
    t, hit = s.intersect(o, d)
    c = np.array(s.center)
    for k in range(0, 2000, 5):
        oc = o[k].double().numpy() - c
        dd = d[k].double().numpy()
        disc = (dd @ oc) ** 2 - (oc @ oc - s.radius ** 2)
        if disc < 0:
            assert not hit[k]
        else:
            assert hit[k]
            assert abs(t[k].item() - (-(dd @ oc) - math.sqrt(disc))) < 1e-5  # float32 rays
    x = o[hit] + t[hit, None] * d[hit]
    assert s.sdf(x).abs().max() < 2e-6
    assert 0.3 < hit.float().mean() < 0.9  # the ray set exercises both hits and misses


def test_sphere_from_inside_and_behind():
    s = Sphere((0.0, 0.0, 0.0), 1.0)
    o = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 3.0], [0.0, 0.0, 3.0]])
    d = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    t, hit = s.intersect(o, d)
    assert hit.tolist() == [True, False, True]
    assert t[0].item() == pytest.approx(1.0) and t[2].item() == pytest.approx(2.0)
    # leaving the surface along the normal: no self-hit
    t2, hit2 = s.intersect(torch.tensor([[1.0 + 1e-4, 0, 0]]), torch.tensor([[1.0, 0, 0]]))
    assert not hit2.any()


@pytest.mark.parametrize("tilt", [0.0, 30.0, 75.0])
def test_torus_intersection_matches_quartic_and_sdf(tilt):
    torus = Torus(0.62, 0.26, tilt)
    o, d = _rays(3000, 1)
    t, hit = torus.intersect(o, d)
    x = o[hit] + t[hit, None] * d[hit]
    assert torus.sdf(x).abs().max() < 1e-4
    assert torus.sdf(x.double()).abs().max() < 1e-4  # SDF evaluated independently in float64
    assert 0.2 < hit.float().mean() < 0.8
    disagree = 0
    for k in range(0, 3000, 10):
        t_ref = _torus_roots(o[k].double().numpy(), d[k].double().numpy(), torus)
        if math.isfinite(t_ref) != bool(hit[k]):
            disagree += 1  # only rays grazing the silhouette may disagree
            continue
        if hit[k]:
            assert abs(t[k].item() - t_ref) < 1e-3, (k, t[k].item(), t_ref)
    assert disagree <= 1


def test_torus_special_rays():
    torus = Torus(0.62, 0.26, 0.0)
    o = torch.tensor([[0.0, 0.0, 4.0], [4.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.62, 0.0, 4.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
    t, hit = torus.intersect(o, d)
    assert hit.tolist() == [False, True, True, True]  # through the hole: miss
    assert t[1].item() == pytest.approx(4.0 - 0.88, abs=1e-4)
    assert t[2].item() == pytest.approx(0.62 - 0.26, abs=1e-4)  # from the centre outward
    assert t[3].item() == pytest.approx(4.0 - 0.26, abs=1e-4)  # onto the top of the tube


@settings(max_examples=60, deadline=None)
@given(theta=st.floats(0.0, math.pi), phi=st.floats(-math.pi, math.pi),
       ox=st.floats(-0.95, 0.95), oy=st.floats(-0.95, 0.95),
       tilt=st.sampled_from([0.0, 30.0, 90.0]))
def test_torus_hits_are_on_the_surface_and_first(theta, phi, ox, oy, tilt):
    """Any ray (incl. grazing ones): a reported hit is on the surface and nothing is skipped."""
    torus = Torus(0.62, 0.26, tilt)
    d = torch.tensor([[math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi),
                       math.cos(theta)]], dtype=torch.float64)
    # origin on a plane through (ox, oy) offset 3 back along the direction
    o = torch.tensor([[ox, oy, 0.0]], dtype=torch.float64) - 3.0 * d
    t, hit = torus.intersect(o, d)
    t_end = t[0].item() if hit[0] else 6.0
    ts = torch.linspace(0, t_end, 4000, dtype=torch.float64)[:-1]
    sd = torus.sdf(o + ts[:, None] * d)
    assert sd.min() > -1e-9  # never crossed the surface before the reported hit
    if hit[0]:
        assert abs(torus.sdf(o + t[:, None] * d).item()) <= HIT_EPS
    else:
        assert sd.min() > 0 or math.isclose(sd.min().item(), 0.0, abs_tol=1e-4)


@pytest.mark.parametrize("shape", [Sphere((0.2, 0.1, -0.1), 0.5), Torus(0.62, 0.26, 30.0),
                                   Torus(0.5, 0.2, -50.0)])
def test_normals_equal_sdf_gradient(shape):
    g = torch.Generator().manual_seed(3)
    x = (torch.rand(500, 3, generator=g, dtype=torch.float64) * 2 - 1) * 0.9
    n = shape.normal(x)
    h = 1e-6
    grad = torch.stack([(shape.sdf(x + h * e) - shape.sdf(x - h * e)) / (2 * h)
                        for e in torch.eye(3, dtype=torch.float64)], -1)
    assert (n - grad).abs().max() < 1e-6
    assert (n.norm(dim=-1) - 1).abs().max() < 1e-9


@pytest.mark.parametrize("shape", [Sphere((0.0, 0.0, 0.1), 0.8), Torus(0.62, 0.26, 30.0)])
def test_mesh_matches_analytic_surface(shape):
    mesh = shape.mesh()
    v = torch.as_tensor(np.asarray(mesh.vertices))
    assert shape.sdf(v).abs().max() < 1e-9  # vertices exactly on the surface
    nrm = torch.as_tensor(np.asarray(mesh.vertex_normals))
    assert (nrm - shape.normal(v)).abs().max() < 1e-9
    # mesh -> surface: points sampled on the triangles stay within the chord error
    o3d.utility.random.seed(0)
    pts = torch.as_tensor(np.asarray(mesh.sample_points_uniformly(20000).points))
    dev = shape.sdf(pts).abs()
    assert dev.max() < 5e-4
    # surface -> mesh: exact ray hits lie on the mesh
    o, d = _rays(4000, 2, dtype=torch.float64)
    t, hit = shape.intersect(o, d)
    x = (o[hit] + t[hit, None] * d[hit]).float().numpy()
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    dist = rs.compute_distance(o3d.core.Tensor(x)).numpy()
    assert dist.max() < 5e-4
    chamfer = 0.5 * (dev.mean().item() + dist.mean())
    assert chamfer < 2e-4  # ≪ 0.005, the accuracy the evaluation needs
    # closed, consistently wound: every directed edge appears once and its reverse once
    tri = np.asarray(mesh.triangles)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    nv = len(mesh.vertices)
    key, rev = edges[:, 0] * nv + edges[:, 1], edges[:, 1] * nv + edges[:, 0]
    assert np.unique(key).size == key.size and np.isin(rev, key).all()
    # outward winding and volume: divergence theorem against the closed form
    vv = np.asarray(mesh.vertices)[tri]
    volume = np.einsum("ij,ij->i", vv[:, 0], np.cross(vv[:, 1], vv[:, 2])).sum() / 6
    exact = (4 / 3 * math.pi * shape.radius ** 3 if isinstance(shape, Sphere)
             else 2 * math.pi ** 2 * shape.major_radius * shape.minor_radius ** 2)
    assert volume == pytest.approx(exact, rel=2e-3)


def test_union_reports_nearest_object_and_its_normal():
    u = Union([Sphere((-0.5, 0, 0), 0.3), Sphere((0.5, 0, 0), 0.3)])
    o = torch.tensor([[-4.0, 0, 0], [4.0, 0, 0], [0.0, 4, 0]])
    d = torch.tensor([[1.0, 0, 0], [-1.0, 0, 0], [0.0, -1, 0]])
    t, hit, obj = u.intersect(o, d)
    assert hit.tolist() == [True, True, False] and obj.tolist() == [0, 1, -1]
    assert t[:2].tolist() == pytest.approx([3.2, 3.2])
    x = o[:2] + t[:2, None] * d[:2]
    assert torch.allclose(u.normal(x, obj[:2]), torch.tensor([[-1.0, 0, 0], [1.0, 0, 0]]))
    assert u.sdf(torch.tensor([[0.0, 0, 0]])).item() == pytest.approx(0.2)
    assert u.bounding_radius() == pytest.approx(0.8)
    assert len(u.mesh().triangles) == 2 * len(Sphere().mesh().triangles)
