"""Learned shading normals: the parametrisation (voxnero.material.normals)."""

from __future__ import annotations

import pytest
import torch

from tests.material.stage2_scene import sphere_geometry
from voxnero.material.normals import RefinedNormals
from voxnero.mesh.normal_filter import mesh_edges


def test_mesh_edges_of_a_tetrahedron_are_its_six_edges_once():
    tri = torch.tensor([[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])
    e = mesh_edges(tri)
    assert e.shape == (6, 2)
    assert {tuple(x) for x in e.tolist()} == {(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)}


def test_starts_at_the_mesh_normals_and_stays_unit():
    g = sphere_geometry(0.5, 12)
    rn = RefinedNormals(g.vertex_normals, g.triangles, rounds=4)
    assert torch.allclose(rn(), g.vertex_normals, atol=1e-6)
    assert float(abs(rn.angles_deg()).max()) < 1e-3
    with torch.no_grad():
        rn.theta.normal_(0, 0.3)
    assert torch.allclose(rn().norm(dim=-1), torch.ones(g.n_vertices), atol=1e-5)


def test_one_vertex_gradient_reaches_its_neighbours_only_within_the_rounds():
    """With K rounds of averaging the correction of a vertex depends on the parameters of its
    K-ring only: a loss on one vertex's normal moves parameters up to K edges away, no further."""
    g = sphere_geometry(0.5, 24)
    for k in (0, 2, 5):
        rn = RefinedNormals(g.vertex_normals, g.triangles, rounds=k)
        v0 = 100
        rn()[v0, 0].backward()
        moved = (rn.theta.grad.abs().sum(-1) > 0)
        # graph distance from v0 by breadth-first search over the edges
        e = rn.edges
        dist = torch.full((g.n_vertices,), 10**6)
        dist[v0] = 0
        for d in range(1, k + 2):
            front = (dist == d - 1)
            nb = torch.cat([e[front[e[:, 0]], 1], e[front[e[:, 1]], 0]])
            dist[nb] = torch.minimum(dist[nb], torch.full_like(nb, d))
        assert bool(moved[v0])
        assert int(dist[moved].max()) <= k
        assert bool(moved[dist == k].any())


def test_the_prior_is_the_squared_chord_of_the_angle():
    g = sphere_geometry(0.5, 12)
    rn = RefinedNormals(g.vertex_normals, g.triangles, rounds=0)
    n = g.vertex_normals.clone()
    # rotate every normal by 10 degrees about an axis perpendicular to it
    t = torch.nn.functional.normalize(torch.cross(n, torch.tensor([[0.3, 0.5, 0.8]]).expand_as(n),
                                                  dim=-1), dim=-1)
    a = torch.deg2rad(torch.tensor(10.0))
    m = torch.cos(a) * n + torch.sin(a) * t
    assert float(rn.prior(m)) == pytest.approx(2 * (1 - float(torch.cos(a))),
                                               rel=1e-4)
